"""One-point helpers give numpy's results bit for bit.

The ``*_at`` functions of :mod:`metro_atc.core.line.vehicle` and
:mod:`metro_atc.core.line.track` evaluate a law at one float; the compiled ATO step's
``interp1`` / ``clip1`` (:mod:`metro_atc.core.ato.control_kernel`) are numpy's ``interp`` /
``clip`` for one float.  Each is compared with the numpy function it names on many random
inputs (exact equality, not a tolerance).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from metro_atc.core.ato import control_kernel as ck
from metro_atc.core.line import track as track_mod
from metro_atc.core.line import vehicle as veh

RNG = np.random.default_rng(13)


def _same(a: float, b: Any) -> bool:
    """Bitwise-equal floats (NaN equal to NaN)."""
    b = float(b)
    return (math.isnan(a) and math.isnan(b)) or a == b


def test_kernel_interp1_matches_numpy() -> None:
    """Random knots and points: inside, on knots, at and beyond both ends, NaN."""
    for _ in range(300):
        n = int(RNG.integers(2, 40))
        xp = np.sort(RNG.uniform(-1e3, 1e3, n))
        if RNG.random() < 0.3:
            xp[int(RNG.integers(0, n - 1))] = xp[int(RNG.integers(0, n))]  # duplicates
            xp = np.sort(xp)
        fp = RNG.normal(0.0, 50.0, n)
        a = np.concatenate((xp, fp))
        xs = np.concatenate((RNG.uniform(xp[0] - 10.0, xp[-1] + 10.0, 40), xp,
                             [xp[0], xp[-1], -np.inf, np.inf, np.nan]))
        for x in xs.tolist():
            assert _same(ck.interp1(x, a, 0, n, n), np.interp(x, xp, fp)), (x, xp, fp)


def test_kernel_clip1_matches_numpy() -> None:
    """clip1 against np.clip on signed zeros, infinities, NaN and ordinary values."""
    vals = [0.0, -0.0, 1.5, -2.0, math.inf, -math.inf, math.nan, 1e-300]
    for a in vals:
        assert _same(ck.clip1(a, -1.0, 1.0), np.clip(a, -1.0, 1.0))


def test_vehicle_and_ebi_match_numpy() -> None:
    """Traction, resistance and the ATP braking curve at one point: the numpy values."""
    p = veh.TAIPEI_MRT_6CAR
    for v in np.concatenate((RNG.uniform(-5.0, 40.0, 2000), [p.v1_mps, p.v2_mps, 0.0])):
        v = float(v)
        assert veh.max_traction_accel_at(p, v) == float(veh.max_traction_accel(p, v))
        assert veh.max_traction_force_at(p, v) == float(veh.max_traction_force(p, v))
        assert veh.resistance_force_at(p, v) == float(veh.resistance_force(p, v))
    for _ in range(3000):
        d, tgt = float(RNG.uniform(-200.0, 3000.0)), float(RNG.choice([0.0, RNG.uniform(0, 25)]))
        a_w, t_r, b_g = (float(x) for x in RNG.uniform([0.0, 0.5, 0.3], [1.5, 3.0, 1.2]))
        assert _same(track_mod.ebi_speed_at(d, tgt, a_w, t_r, b_g),
                     track_mod.ebi_speed(d, tgt, a_w, t_r, b_g))
