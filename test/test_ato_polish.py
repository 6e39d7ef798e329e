"""ATO core: continuous switch-position polish, and the DP against the independent optimum.

Thresholds are the acceptance figures of the DP's optimality (DP within 0.5 % of the LP
optimum, running
time within 0.5 s), not today's measurements.  CPU time is not asserted (benchmarks only).
"""

from __future__ import annotations

import functools
import json

import numpy as np
import pytest

from metro_atc.core.ato import coasting
from metro_atc.core.ato.dp import (CONTROL_LEVELS, CONTROL_MODES, build_dp_tables,
                                   simulate_path, solve_dp)
from metro_atc.core.ato.envelope import RunModel
from metro_atc.core.ato.oracle import solve_oracle
from metro_atc.core.ato.polish import polish_sequence, regimes_of, render
from metro_atc.core.bridge import ato_limits_for, track_for, train_for
from metro_atc.core.line.vehicle import TAIPEI_MRT_6CAR, Track
from metro_atc.core.linegen import load_generated


def test_render_reproduces_the_sequence_at_integer_boundaries() -> None:
    """Regimes read off a sequence and rendered at their own boundaries give it back."""
    rng = np.random.default_rng(3)
    for _ in range(20):
        ctrl = np.repeat(rng.integers(0, 4, 6), rng.integers(1, 9, 6))
        lev = np.asarray(CONTROL_LEVELS)[ctrl]
        reg = regimes_of(ctrl, lev, CONTROL_MODES)
        c2, l2 = render(reg, reg.bounds, CONTROL_MODES)
        # control 1 (accelerate at 0.5) renders as control 0 at level 0.5: same mode + level
        m = np.asarray(CONTROL_MODES)
        assert np.array_equal(m[c2[0]], m[ctrl]) and np.allclose(l2[0], lev)


def test_fractional_boundary_scales_the_traction_level() -> None:
    """A switch from full traction to coasting 30 % into a stage = level 0.3 in that stage."""
    ctrl = np.array([0, 0, 0, 3, 3])
    reg = regimes_of(ctrl, np.asarray(CONTROL_LEVELS)[ctrl], CONTROL_MODES)
    c2, l2 = render(reg, np.array([[2.3]]), CONTROL_MODES)
    assert list(c2[0]) == [0, 0, 0, 3, 3]
    assert l2[0, 2] == pytest.approx(0.3)


def _flat_run() -> RunModel:
    return RunModel(TAIPEI_MRT_6CAR, Track.flat(80 / 3.6), 0.0, 1300.0)


def test_polish_never_worse_and_meets_time() -> None:
    """From a crude accelerate-coast sequence the polish only returns cheaper profiles that
    meet the bound, and the returned controls reproduce the figures by exact simulation.
    """
    run = _flat_run()
    tab = build_dp_tables(run)
    n = tab.n_stages
    for k_sw, target in ((40, 110.0), (60, 100.0)):
        ctrl = np.where(np.arange(n) < k_sw, 0, 3)
        lev = np.asarray(CONTROL_LEVELS)[ctrl]

        def sim(c, lv):  # noqa: ANN001, ANN202
            return simulate_path(run, tab, c, lv)

        _, cj, ct = sim(ctrl[None], lev[None])
        pol = polish_sequence(sim, CONTROL_MODES, ctrl, lev, target)
        if ct[0, -1] <= target + 0.01:
            assert pol.energy_j <= cj[0, -1] + 1e-6
        assert pol.time_s <= target + 0.01
        _, cj2, ct2 = sim(pol.controls[None], pol.levels[None])
        assert cj2[0, -1] == pytest.approx(pol.energy_j)
        assert ct2[0, -1] == pytest.approx(pol.time_s)


def test_polish_finds_the_accelerate_coast_switch_on_a_flat_run() -> None:
    """Flat track, accelerate-coast-brake: the polished switch meets the time exactly (the
    energy is monotone in the switch point, so the optimum uses all the time).
    """
    run = _flat_run()
    tab = build_dp_tables(run)
    n = tab.n_stages
    ctrl = np.where(np.arange(n) < 25, 0, 3)       # below the limit; too fast
    lev = np.asarray(CONTROL_LEVELS)[ctrl]
    _, _, ct = simulate_path(run, tab, ctrl[None], lev[None])
    target = float(ct[0, -1]) + 2.0
    pol = polish_sequence(lambda c, lv: simulate_path(run, tab, c, lv), CONTROL_MODES, ctrl,
                          lev, target, max_iterations=12)
    assert pol.improved
    assert target - 0.1 <= pol.time_s <= target + 0.01


def _generated(seed: int, i: int) -> RunModel:
    scn = load_generated(seed)
    train = train_for(scn)
    pos = [st.position_m for st in scn.line.stations]
    return RunModel(train, track_for(scn), pos[i], pos[i + 1], ato_limits_for(train))


@functools.lru_cache(maxsize=1)
def _ttobench_line() -> tuple[object, object, list[float]]:
    from metro_atc.bench.ttobench import metro_scenario
    scn = metro_scenario()
    train = train_for(scn)
    return train, track_for(scn), [st.position_m for st in scn.line.stations]


def _ttobench(i: int) -> RunModel:
    train, track, pos = _ttobench_line()
    return RunModel(train, track, pos[i], pos[i + 1], ato_limits_for(train))  # type: ignore


_CASES = [(4, 2, 1.05), (4, 2, 1.10), (4, 0, 1.10), (4, 3, 1.05), (7, 1, 1.10), (1, 1, 1.05)]
"""Generated-line runs (seed, interstation, factor x flat-out) that were hardest for the DP."""


@pytest.mark.parametrize("seed,i,factor", _CASES)
def test_dp_within_half_percent_of_the_optimum(seed: int, i: int, factor: float) -> None:
    """Acceptance on generated lines: DP energy <= 1.005 x the LP optimum (2 m
    grid), running time within 0.5 s.
    """
    run = _generated(seed, i)
    target = factor * coasting.fotp(run, np.inf).time_s
    opt = solve_oracle(run, target, 2.0)
    dp = solve_dp(run, target)
    assert abs(dp.time_s - target) <= 0.5
    assert dp.energy_j <= 1.005 * opt.energy_j


def _reference() -> list[dict[str, float]]:
    from metro_atc.bench import ttobench
    ref = json.loads((ttobench.data_dir() / ttobench.REFERENCE_FILE).read_text())
    return list(ref["values"])


@pytest.mark.parametrize("i", range(13))
def test_dp_within_half_percent_on_every_ttobench_interstation(i: int) -> None:
    """Acceptance on the TTOBench metro line, every interstation x 1.05 / 1.10 /
    1.20 of flat-out: DP <= 1.005 x the shipped LP optimum (``reference_energies.json``,
    which ``test_bench_ttobench`` ties to the oracle), running time within 0.5 s.
    """
    run = _ttobench(i)
    rows = [r for r in _reference() if r["interstation"] == i]
    assert len(rows) == 3 and rows[0]["to_m"] - rows[0]["from_m"] == pytest.approx(run.length_m)
    for row in rows:
        target = row["target_s"]          # factor x flat-out (test_bench_ttobench checks it)
        dp = solve_dp(run, target)
        assert abs(dp.time_s - target) <= 0.5
        assert dp.energy_j / 3.6e6 <= 1.005 * row["energy_kwh"]
