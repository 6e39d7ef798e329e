"""TSR-approach minima metric: hunting counted, explained minima kept apart.

Synthetic speed traces along a 1 km approach: the permanent limit, the stations, the end of
movement authority and the breakdown are given per sample, as ``closed_loop`` reads them
from the plant.
"""

from __future__ import annotations

import math

import numpy as np

from metro_atc.core.tsr_hunting import (FORCED, HUNT_HYSTERESIS_MPS, PERMANENT, STATION,
                                        SpeedMinima, explain)

KMH = 1.0 / 3.6


def _run(x: np.ndarray, v: np.ndarray, perm: np.ndarray, stations: tuple[float, ...] = (),
         broken: np.ndarray | None = None, eoa: np.ndarray | None = None) -> SpeedMinima:
    m = SpeedMinima()
    st = np.asarray(stations + (math.inf,), dtype=float)
    for k in range(x.size):
        m.feed(float(v[k]), explain(float(v[k]), float(perm[k]),
                                    float(np.min(np.abs(st - x[k]))),
                                    bool(broken[k]) if broken is not None else False,
                                    float(eoa[k] - x[k]) if eoa is not None else math.inf))
    return m.close()


def _profile(x: np.ndarray, pts: list[tuple[float, float]]) -> np.ndarray:
    """Piecewise-linear speed [m/s] through (chainage [m], speed [km/h]) points."""
    xs, vs = zip(*pts)
    return np.interp(x, xs, np.asarray(vs) * KMH)


X = np.arange(0.0, 1400.0, 1.0)
"""Approach window (TSR 30 km/h from 800 m to 1 100 m, rear out at 1 240 m) [m]."""
TSR = 30.0


def _perm(x: np.ndarray, lower: tuple[float, float, float] | None = None) -> np.ndarray:
    """80 km/h permanent limit, with an optional (start, end, km/h) lower one."""
    p = np.full(x.size, 80.0 * KMH)
    if lower is not None:
        p[(x >= lower[0]) & (x < lower[1])] = lower[2] * KMH
    return p


def test_one_smooth_approach_is_one_minimum() -> None:
    v = _profile(X, [(0, 60), (600, 60), (790, TSR - 2), (1240, TSR - 2), (1400, 60)])
    m = _run(X, v, _perm(X))
    assert (m.minima, m.hunting) == (1, 1)


def test_stop_start_hunting_is_counted() -> None:
    # the speed sawing between ~5 and 28 km/h in the zone (as observed before the fix)
    pts = [(0, 60), (600, 60), (790, 28)]
    for k in range(5):
        pts += [(830 + 80 * k, 5), (870 + 80 * k, 28)]
    pts += [(1400, 60)]
    v = _profile(X, pts)
    m = _run(X, v, _perm(X))
    assert m.minima == 5 and m.hunting == 5 and not m.causes


def test_noise_below_the_hysteresis_is_not_a_minimum() -> None:
    v = _profile(X, [(0, 60), (600, 60), (790, 28), (1240, 28), (1400, 60)])
    rng = np.random.default_rng(0)
    v = v + rng.uniform(-0.45, 0.45, X.size) * HUNT_HYSTERESIS_MPS
    assert _run(X, v, _perm(X)).hunting == 1


def test_lower_permanent_limit_in_the_window_is_no_hunting() -> None:
    # gen_0006_inc: a 40 km/h limit inside the window (36 km/h), up to 52, then the TSR
    perm = _perm(X, (300.0, 450.0, 40.0))
    v = _profile(X, [(0, 60), (250, 36), (460, 36), (600, 52), (790, TSR - 2),
                     (1240, TSR - 2), (1400, 60)])
    m = _run(X, v, perm)
    assert (m.minima, m.hunting) == (2, 1)
    assert m.causes == {PERMANENT: 1}


def test_a_dip_well_below_a_permanent_limit_is_still_hunting() -> None:
    perm = _perm(X, (300.0, 450.0, 40.0))
    v = _profile(X, [(0, 60), (250, 20), (460, 20), (600, 52), (790, TSR - 2),
                     (1240, TSR - 2), (1400, 60)])
    assert _run(X, v, perm).hunting == 2


def test_station_stop_in_the_zone_is_no_hunting() -> None:
    # a platform inside the zone: braking for the TSR runs into the stop (one minimum, the
    # station's), then the train leaves at the TSR speed
    v = _profile(X, [(0, 60), (600, 60), (790, TSR - 2), (900, 10), (1000, 0), (1001, 0),
                     (1100, TSR - 2), (1240, TSR - 2), (1400, 60)])
    m = _run(X, v, _perm(X), stations=(1000.0,))
    assert m.causes == {STATION: 1}
    assert (m.minima, m.hunting) == (1, 0)
    # the same standstill away from any platform is hunting
    m = _run(X, v, _perm(X), stations=(1300.0,))
    assert (m.minima, m.hunting) == (1, 1) and not m.causes


def test_broken_down_train_is_a_forced_stop() -> None:
    # gen_0018_inc: the broken-down train stops inside the window, then brakes for the TSR
    v = _profile(X, [(0, 60), (300, 0), (300.5, 0), (600, 50), (790, TSR - 2),
                     (1240, TSR - 2), (1400, 60)])
    broken = (X >= 250.0) & (X <= 300.0)
    m = _run(X, v, _perm(X), broken=broken)
    assert m.causes == {FORCED: 1}
    assert (m.minima, m.hunting) == (2, 1)


def test_train_held_behind_the_broken_down_one_is_forced() -> None:
    # the end of its authority (the stopped train's rear) at 320 m until it leaves
    v = _profile(X, [(0, 60), (300, 0), (300.5, 0), (600, 50), (790, TSR - 2),
                     (1240, TSR - 2), (1400, 60)])
    eoa = np.where(X <= 300.5, 320.0, math.inf)
    m = _run(X, v, _perm(X), eoa=eoa)
    assert m.causes == {FORCED: 1}
    assert m.hunting == 1
    # the same stop with the authority far ahead is hunting
    assert _run(X, v, _perm(X), eoa=np.full(X.size, 5000.0)).hunting == 2


def test_explain_thresholds() -> None:
    assert explain(10.0, 11.1, 1e3, False, math.inf) == PERMANENT
    assert explain(5.0, 11.1, 1e3, False, math.inf) == ""
    assert explain(0.0, 11.1, 0.5, False, math.inf) == STATION
    assert explain(0.0, 11.1, 5.0, False, math.inf) == ""
    assert explain(0.0, 11.1, 5.0, True, math.inf) == FORCED
    assert explain(10.0, 22.0, 1e3, False, 100.0 + 40.0) == FORCED  # 100 m to stop at 0.5
    assert explain(10.0, 22.0, 1e3, False, 100.0 + 60.0) == ""
