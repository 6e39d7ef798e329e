"""The compiled strategy simulation (numba) against the numpy reference on generated lines.

:func:`metro_atc.core.ato.coasting.simulate_switching` runs ECTP's and ACTP's strategies
through :mod:`metro_atc.core.ato.switching_kernel` by default; the numpy path
(:func:`metro_atc.core.ato.coasting.simulate_switching_numpy`) is the reference.  The kernel
repeats the numpy operations in the same order, so the comparison tolerance is float
round-off (relative 1e-9, as the plant's golden traces), stall flags identical.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from metro_atc.core.ato import coasting
from metro_atc.core.ato.envelope import RunModel
from metro_atc.core.ato.onboard import envelope_limits
from metro_atc.core.bridge import timetable_for, track_for, train_for
from metro_atc.core.line.vehicle import TAIPEI_MRT_6CAR, Track
from metro_atc.core.linegen import load_generated

RTOL = 1e-9
needs_numba = pytest.mark.skipif(coasting.resolve_plan_kernel("auto") != "numba",
                                 reason="numba not installed")


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


def _same(a: coasting.SwitchingRun, b: coasting.SwitchingRun) -> None:
    np.testing.assert_array_equal(a.stalled, b.stalled)
    np.testing.assert_array_equal(a.s_grid, b.s_grid)
    assert np.array_equal(np.isfinite(a.time_s), np.isfinite(b.time_s))
    fin = np.isfinite(b.time_s)
    np.testing.assert_allclose(a.time_s[fin], b.time_s[fin], rtol=RTOL)
    np.testing.assert_allclose(a.energy_j, b.energy_j, rtol=RTOL,
                               atol=RTOL * float(np.max(np.abs(b.energy_j))))
    assert a.v.shape == b.v.shape
    np.testing.assert_allclose(a.v, b.v, rtol=RTOL, atol=RTOL * 100.0)


@needs_numba
@pytest.mark.parametrize("seed", [0, 12, 46])
def test_kernel_equals_numpy_on_generated_lines(seed: int) -> None:
    """Every interstation of a generated line (12: high-speed stock, 46: steep grades)."""
    rng = np.random.default_rng(seed)
    steep = 0
    for run in _runs(seed):
        h = max(16.0, run.length_m / 100.0)
        yc, dl = _strategies(run, h, rng)
        a = coasting.simulate_switching(run, yc, dl, h, record=True, kernel="numba")
        b = coasting.simulate_switching(run, yc, dl, h, record=True, kernel="numpy")
        _same(a, b)
        tab = coasting.step_table(run, h)
        steep += int(np.any(run.train.davis_a_n + tab.fg < 0.0))  # c0 < 0: the tanh branch
    if seed == 46:
        assert steep > 0, "no descent steep enough for the tanh form of seed 002 eq. 7"


@needs_numba
def test_kernel_equals_numpy_with_stalls_and_limits() -> None:
    """A climb that stalls early coasting trains and a low limit that clamps the coast."""
    track = Track(np.array([-1e12, 300.0, 900.0]), np.array([0.0, 0.04, -0.035]),
                  np.array([-1e12, 1000.0, 1300.0]), np.array([80.0, 40.0, 80.0]) / 3.6)
    run = RunModel(TAIPEI_MRT_6CAR, track, 0.0, 1900.0)
    h = 4.0
    yc = np.array([0.0, 50.0, 120.0, 301.0, 700.0, 1000.0, 1250.0, 1901.0])
    dl = np.full(yc.size, coasting.LEVEL_II)
    a = coasting.simulate_switching(run, yc, dl, h, record=True, kernel="numba")
    b = coasting.simulate_switching(run, yc, dl, h, record=True, kernel="numpy")
    assert np.any(b.stalled) and not np.all(b.stalled)
    _same(a, b)
    # without recording: the same times and energies, no history
    c = coasting.simulate_switching(run, yc, dl, h, kernel="numba")
    np.testing.assert_array_equal(c.energy_j, a.energy_j)
    assert c.v.size == 0


@needs_numba
def test_ectp_and_actp_equal_with_both_kernels(monkeypatch: pytest.MonkeyPatch) -> None:
    """Whole planners through the environment switch: the same coasting point and profile."""
    run = _runs(46)[3]
    h = 4.0
    t_min = coasting.fotp(run, math.inf, h).time_s
    ap = coasting.ActpParams(iterations=20, n_delta=4, n_coast=9)
    res = {}
    for kern in ("numba", "numpy"):
        monkeypatch.setenv(coasting.PLAN_KERNEL_ENV, kern)
        res[kern] = (coasting.ectp(run, 1.1 * t_min, h_m=h),
                     coasting.actp(run, 1.1 * t_min, params=ap, h_m=h))
    for x, y in zip(res["numba"], res["numpy"]):
        assert x.coast_point_s == pytest.approx(y.coast_point_s, rel=RTOL)
        assert x.delta == pytest.approx(y.delta, rel=RTOL)
        assert x.time_s == pytest.approx(y.time_s, rel=RTOL)
        assert x.energy_j == pytest.approx(y.energy_j, rel=RTOL)
        np.testing.assert_allclose(x.v_profile, y.v_profile, rtol=RTOL, atol=RTOL * 100.0)


def test_resolve_plan_kernel(monkeypatch: pytest.MonkeyPatch) -> None:
    """Argument over environment over auto; unknown names refused."""
    monkeypatch.setenv(coasting.PLAN_KERNEL_ENV, "numpy")
    assert coasting.resolve_plan_kernel() == "numpy"
    assert coasting.resolve_plan_kernel("numpy") == "numpy"
    monkeypatch.delenv(coasting.PLAN_KERNEL_ENV)
    assert coasting.resolve_plan_kernel() in ("numba", "numpy")
    with pytest.raises(ValueError):
        coasting.resolve_plan_kernel("fortran")


@needs_numba
def test_warm_up_loads_the_kernel_and_not_for_numpy() -> None:
    """The node's start-up call runs the compiled kernel once; the numpy path has none."""
    scn = load_generated(0)
    train = train_for(scn)
    limits = envelope_limits(scn, train)
    assert coasting.warm_up_plan_kernel(train, limits, "numba")
    assert not coasting.warm_up_plan_kernel(train, limits, "numpy")
    from metro_atc.core.ato import switching_kernel
    assert switching_kernel.simulate_kernel.signatures  # compiled (or loaded from the cache)
