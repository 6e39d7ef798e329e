"""The compiled strategy simulation against frozen reference numbers on generated lines.

:func:`metro_atc.core.ato.coasting.simulate_switching` runs ECTP's and ACTP's strategies
through :mod:`metro_atc.core.ato.switching_kernel`.  ``test/data/ato_switching_golden.npz``
holds the outputs of the numpy reference it had (one array step per distance step, the
vectorised numpy strategy step since replaced by
:func:`metro_atc.core.ato.step_kernel.strategy_step`) for the inputs below, taken
before that reference was dropped; the kernel repeats its operations in the same order, so
the tolerance is float round-off (relative 1e-9, as the plant's golden traces), stall flags
identical.  The inputs are regenerated here (the same seeds): a changed generator fails too.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from metro_atc.core.ato import coasting
from metro_atc.core.ato.envelope import RunModel
from metro_atc.core.ato.onboard import envelope_limits
from metro_atc.core.bridge import timetable_for, track_for, train_for
from metro_atc.core.line.vehicle import TAIPEI_MRT_6CAR, Track
from metro_atc.core.linegen import load_generated

RTOL = 1e-9
GOLDEN = Path(__file__).resolve().parent / "data" / "ato_switching_golden.npz"


@pytest.fixture(scope="module")
def golden() -> dict[str, np.ndarray]:
    """The frozen reference numbers."""
    with np.load(GOLDEN) as z:
        return {k: z[k] for k in z.files}


def _runs(seed: int) -> list[RunModel]:
    scn = load_generated(seed)
    train, track = train_for(scn), track_for(scn)
    limits = envelope_limits(scn, train)
    pos = np.asarray(timetable_for(scn).station_positions_m, dtype=float)
    out = [RunModel(train, track, float(a), float(b), limits)
           for a, b in zip(pos[:-1], pos[1:])]
    out.append(RunModel(train, track, float(pos[-1]), float(pos[-2]), limits))  # backwards
    return out


def _strategies(run: RunModel, h: float, rng: np.random.Generator
                ) -> tuple[np.ndarray, np.ndarray]:
    """Coasting points: random, on grid points, within 1e-9 m of them, at 0 and past L."""
    n = max(1, int(np.ceil(run.length_m / h)))
    step = run.length_m / n
    k = rng.integers(0, n, 3)
    yc = np.concatenate((rng.uniform(0.0, run.length_m, 4), k * step, k * step + 5e-10,
                         [0.0, run.length_m + 1.0]))
    return yc, rng.uniform(0.3, 1.0, yc.size)


def _same(a: coasting.SwitchingRun, g: dict[str, np.ndarray], key: str) -> None:
    """``a`` equals the golden run ``key`` to round-off (stall flags and infinities exact)."""
    t, en, stalled, v = g[key + "_t"], g[key + "_e"], g[key + "_st"], g[key + "_v"]
    np.testing.assert_array_equal(a.stalled, stalled)
    assert np.array_equal(np.isfinite(a.time_s), np.isfinite(t))
    fin = np.isfinite(t)
    np.testing.assert_allclose(a.time_s[fin], t[fin], rtol=RTOL)
    np.testing.assert_allclose(a.energy_j, en, rtol=RTOL, atol=RTOL * float(np.max(np.abs(en))))
    assert a.v.shape == v.shape
    np.testing.assert_allclose(a.v, v, rtol=RTOL, atol=RTOL * 100.0)


@pytest.mark.parametrize("seed", [0, 12, 46])
def test_kernel_equals_reference_on_generated_lines(seed: int,
                                                    golden: dict[str, np.ndarray]) -> None:
    """Every interstation of a generated line (12: high-speed stock, 46: steep grades)."""
    rng = np.random.default_rng(seed)
    steep = 0
    runs = _runs(seed)
    assert f"gen{seed}_{len(runs)}_t" not in golden and f"gen{seed}_{len(runs) - 1}_t" in golden
    for i, run in enumerate(runs):
        h = max(16.0, run.length_m / 100.0)
        yc, dl = _strategies(run, h, rng)
        key = f"gen{seed}_{i}"
        np.testing.assert_array_equal(yc, golden[key + "_yc"])
        np.testing.assert_array_equal(dl, golden[key + "_dl"])
        a = coasting.simulate_switching(run, yc, dl, h, record=True)
        np.testing.assert_array_equal(a.s_grid, coasting.step_table(run, h).s)
        _same(a, golden, key)
        tab = coasting.step_table(run, h)
        steep += int(np.any(run.train.davis_a_n + tab.fg < 0.0))  # c0 < 0: the tanh branch
    if seed == 46:
        assert steep > 0, "no descent steep enough for the tanh form of the coasting law"


def test_kernel_equals_reference_with_stalls_and_limits(golden: dict[str, np.ndarray]) -> None:
    """A climb that stalls early coasting trains and a low limit that clamps the coast."""
    track = Track(np.array([-1e12, 300.0, 900.0]), np.array([0.0, 0.04, -0.035]),
                  np.array([-1e12, 1000.0, 1300.0]), np.array([80.0, 40.0, 80.0]) / 3.6)
    run = RunModel(TAIPEI_MRT_6CAR, track, 0.0, 1900.0)
    h = 4.0
    yc = np.array([0.0, 50.0, 120.0, 301.0, 700.0, 1000.0, 1250.0, 1901.0])
    dl = np.full(yc.size, coasting.LEVEL_II)
    a = coasting.simulate_switching(run, yc, dl, h, record=True)
    assert np.any(a.stalled) and not np.all(a.stalled)
    _same(a, golden, "stall")
    # without recording: the same times and energies, no history
    c = coasting.simulate_switching(run, yc, dl, h)
    np.testing.assert_array_equal(c.energy_j, a.energy_j)
    assert c.v.size == 0


def test_ectp_and_actp_equal_the_reference(golden: dict[str, np.ndarray]) -> None:
    """Whole planners: the reference's coasting point, level, time, energy and profile."""
    run = _runs(46)[3]
    h = 4.0
    t_min = coasting.fotp(run, math.inf, h).time_s
    ap = coasting.ActpParams(iterations=20, n_delta=4, n_coast=9)
    for name, res in (("ectp", coasting.ectp(run, 1.1 * t_min, h_m=h)),
                      ("actp", coasting.actp(run, 1.1 * t_min, params=ap, h_m=h))):
        np.testing.assert_allclose([res.coast_point_s, res.delta, res.time_s, res.energy_j],
                                   golden[name + "_scalars"], rtol=RTOL)
        np.testing.assert_allclose(res.v_profile, golden[name + "_v"], rtol=RTOL,
                                   atol=RTOL * 100.0)


def test_warm_up_loads_the_kernel() -> None:
    """The node's start-up call runs the compiled kernel once."""
    scn = load_generated(0)
    train = train_for(scn)
    limits = envelope_limits(scn, train)
    coasting.warm_up_plan_kernel(train, limits)
    from metro_atc.core.ato import switching_kernel
    assert switching_kernel.simulate_kernel.signatures  # compiled (or loaded from the cache)
