"""ATO core: dynamic-programming reference optimum against brute force and the planners."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest

from metro_atc.core.ato import coasting
from metro_atc.core.ato.dp import (CONTROL_MODES, DPTables, _backward, _forward_table,
                                   build_dp_tables, simulate_controls, solve_dp)
from metro_atc.core.ato.envelope import RunModel
from metro_atc.core.line.vehicle import TAIPEI_MRT_6CAR, Track


def _tiny() -> tuple[RunModel, DPTables]:
    """60 m run in 4 stages, uphill then downhill, fine speed grid."""
    track = Track(np.array([-1e12, 30.0]), np.array([0.01, -0.02]),
                  np.array([-1e12]), np.array([40.0 / 3.6]))
    run = RunModel(TAIPEI_MRT_6CAR, track, 0.0, 60.0)
    return run, build_dp_tables(run, ds_m=15.0, de_m2s2=0.01, substep_m=5.0)


def _brute(run: RunModel, tab: DPTables) -> tuple[np.ndarray, np.ndarray, list[tuple]]:
    """Exact energy and time of every control sequence (4 controls ^ 4 stages = 256)."""
    seqs = list(itertools.product(range(len(CONTROL_MODES)), repeat=tab.n_stages))
    en = np.empty(len(seqs))
    tm = np.empty(len(seqs))
    for i, seq in enumerate(seqs):
        _, en[i], tm[i] = simulate_controls(run, tab, np.array(seq))
    return en, tm, seqs


@pytest.mark.parametrize("mu", [2e4, 1e5, 4e5, 2e6])
def test_dp_matches_brute_force_lagrangian(mu: float) -> None:
    """For a multiplier mu the DP minimises E + mu T like exhaustive enumeration does."""
    run, tab = _tiny()
    en, tm, _ = _brute(run, tab)
    obj = np.where(np.isfinite(tm), en + mu * tm, np.inf)
    j_val = _backward(tab, mu)[0]
    ctrl, _, _ = _forward_table(tab, mu, j_val)
    _, e_dp, t_dp = simulate_controls(run, tab, ctrl)
    assert e_dp + mu * t_dp == pytest.approx(float(np.min(obj)), rel=1e-4)


def test_dp_matches_brute_force_constrained() -> None:
    """At the running time of a Pareto (hull) point the DP energy equals the brute force one."""
    run, tab = _tiny()
    en, tm, _ = _brute(run, tab)
    ok = np.isfinite(tm)
    for mu in (5e4, 3e5):
        k = int(np.argmin(np.where(ok, en + mu * tm, np.inf)))
        target = float(tm[k]) + 1e-6
        best = float(np.min(en[ok & (tm <= target)]))
        r = solve_dp(run, target, tables=tab)
        assert r.feasible and r.time_s <= target + 0.05
        assert r.energy_j == pytest.approx(best, rel=1e-3)


def test_dp_is_a_lower_reference_for_coasting_profiles() -> None:
    """On the Blue line run the DP needs no more energy than ECTP at the same running time."""
    run = RunModel(TAIPEI_MRT_6CAR, Track.flat(80 / 3.6), 0.0, 1300.0)
    ec = coasting.ectp(run, 92.0)
    dp = solve_dp(run, ec.time_s)
    assert dp.feasible and dp.time_s <= ec.time_s + 0.05
    assert dp.energy_j <= ec.energy_j
    assert dp.compute_s < 10.0
    fast = solve_dp(run, 50.0)
    assert not fast.feasible


def test_vectorised_passes_match_single_multiplier_passes() -> None:
    """The backward pass over a batch of multipliers equals one pass per multiplier, and the
    batched forward pass (policy per candidate and stage) equals the single forward passes.
    """
    from metro_atc.core.ato.dp import _forward
    run, tab = _tiny()
    mus = np.array([2e4, 1e5, 4e5, 2e6])
    j_all = _backward(tab, mus)
    for i, mu in enumerate(mus):
        assert np.array_equal(j_all[i], _backward(tab, float(mu))[0])
    pol = np.repeat(np.arange(mus.size)[:, None], tab.n_stages, axis=1)
    fw = _forward(tab, mus, j_all, pol)
    for i, mu in enumerate(mus):
        c, e, t = _forward_table(tab, float(mu), j_all[i])
        assert np.array_equal(fw.controls[i], c)
        assert fw.energy_j[i] == pytest.approx(e) and fw.time_s[i] == pytest.approx(t)
    # a splice (policy 0 before stage k, policy 3 from k on) follows each policy's choices
    k = 2
    sp = _forward(tab, mus[[0, 3]], j_all[[0, 3]],
                  (np.arange(tab.n_stages) >= k).astype(np.int64)[None, :])
    assert np.array_equal(sp.controls[0, :k], fw.controls[0, :k])


def test_forward_multi_matches_forward_from_each_start() -> None:
    """Candidates joining the pass at their own stage behave like single passes from there."""
    from metro_atc.core.ato.dp import _forward, _forward_multi
    run, tab = _tiny()
    mus = np.array([1e5, 4e5])
    j_all = _backward(tab, mus)
    base = _forward(tab, mus[:1], j_all[:1], np.zeros((1, tab.n_stages), dtype=np.int64))
    k0 = np.array([0, 1, 2, 1])
    pol = np.array([0, 1, 0, 0])
    e0 = base.e_path[0, k0]
    fm = _forward_multi(tab, mus, j_all, pol, e0, k0)
    for c in range(k0.size):
        one = _forward(tab, mus[pol[c]:pol[c] + 1], j_all[pol[c]:pol[c] + 1],
                       np.zeros((1, tab.n_stages), dtype=np.int64), e0=e0[c:c + 1],
                       k0=int(k0[c]))
        assert np.array_equal(fm.controls[c, k0[c]:], one.controls[0, k0[c]:])
        assert fm.energy_j[c] == pytest.approx(one.energy_j[0])
        assert fm.time_s[c] == pytest.approx(one.time_s[0])


def _seed001_case2() -> RunModel:
    from metro_atc.bench.mmas import make_track
    return RunModel(TAIPEI_MRT_6CAR, make_track(2), 0.0, 2000.0)


def test_rollout_never_worse_and_meets_time(monkeypatch: pytest.MonkeyPatch) -> None:
    """The rollout polish only replaces the winner by a cheaper profile meeting the time."""
    import metro_atc.core.ato.dp as dp
    run = _seed001_case2()
    tab = build_dp_tables(run)
    with_ro = solve_dp(run, 180.0, tables=tab)
    monkeypatch.setattr(dp, "ROLLOUT_ROUNDS", 0)
    without = solve_dp(run, 180.0, tables=tab)
    assert with_ro.time_s <= 180.05 and without.time_s <= 180.05
    assert with_ro.energy_j <= without.energy_j
    # the exact simulation of the returned controls and levels reproduces the figures
    v, e, t = simulate_controls(run, tab, with_ro.controls, with_ro.levels)
    assert e == pytest.approx(with_ro.energy_j) and t == pytest.approx(with_ro.time_s)


def test_dp_within_half_percent_of_optimum_seed001_case2() -> None:
    """Acceptance on Ke 2010, case 2 (180 s): DP within 0.5 % of the LP optimum."""
    from metro_atc.core.ato.oracle import solve_oracle
    run = _seed001_case2()
    opt = solve_oracle(run, 180.0, 2.0)
    dp = solve_dp(run, 180.0)
    assert dp.time_s <= 180.0 + 0.5
    assert dp.energy_j <= 1.005 * opt.energy_j


# ------------------------------------- compiled path against the former numpy path's frozen output
REF_NPZ = Path(__file__).parent / "data" / "dp_numpy_ref.npz"
"""Inputs and outputs of the numpy exact simulation / passes / solve, recorded before that
path was dropped (test/record_planner_refs.py in the history of this file)."""


def _hilly() -> RunModel:
    """1.6 km run with a climb, a steep descent (coasting accelerates) and a restriction."""
    track = Track(np.array([-1e12, 300.0, 700.0, 1100.0]), np.array([0.0, 0.03, -0.035, 0.0]),
                  np.array([-1e12, 900.0, 1200.0]),
                  np.array([80.0 / 3.6, 45.0 / 3.6, 80.0 / 3.6]))
    return RunModel(TAIPEI_MRT_6CAR, track, 0.0, 1600.0)


RTOL = 1e-9
"""Round-off between the recorded numpy path and the compiled one (as the plant's goldens)."""


def _close(a: np.ndarray, b: np.ndarray, rtol: float = 1e-12, atol: float = 1e-9) -> None:
    """Same finite / infinite pattern, finite entries equal to round-off."""
    a, b = np.asarray(a), np.asarray(b)
    assert a.shape == b.shape
    assert np.array_equal(np.isfinite(a), np.isfinite(b))
    f = np.isfinite(a)
    np.testing.assert_allclose(a[f], b[f], rtol=rtol, atol=atol)


def test_compiled_simulation_equals_recorded_numpy() -> None:
    """The exact simulation (dp_kernel) gives the former numpy path's numbers: whole
    sequences (all controls, partial levels, runs that stall or hit the envelope) and single
    stages from arbitrary states.
    """
    import metro_atc.core.ato.dp as dp
    ref = np.load(REF_NPZ)
    run = _hilly()
    tab = build_dp_tables(run)
    got = (dp.simulate_path(run, tab, ref["sim_controls"].astype(np.int64),
                            ref["sim_levels"]),
           dp._simulate_stages(run, tab, ref["stage_k"].astype(np.int64), ref["stage_e0"],
                               ref["stage_mode"].astype(np.int64), ref["stage_level"]))
    names = (("sim_e", "sim_j", "sim_t"), ("stage_e", "stage_j", "stage_t"))
    for out, keys in zip(got, names):
        for a, key in zip(out, keys):
            _close(a, ref[key])
    assert np.any(~np.isfinite(ref["sim_t"][:, -1]))      # some sequences stall
    assert np.any(np.isfinite(ref["sim_t"][:, -1]))


def test_compiled_passes_equal_recorded_numpy() -> None:
    """Backward / forward passes (batched multipliers, per-candidate policies and start
    stages) and the whole solve equal the former numpy path's recorded output.

    Discrete results (controls) exactly, figures to round-off (relative ``RTOL``): the
    tables now come from the compiled strategy step, whose coasting entries differ from the
    former numpy step's in the last bits (it added 1e-12 to the log of every element of a
    batch holding one steep-descent element, and numpy's vectorised log / arctan differ
    from libm's by an ulp): up to 2.4e-11 m^2/s^2 in e, 1.4e-11 relative in the passes.
    """
    import metro_atc.core.ato.dp as dp
    ref = np.load(REF_NPZ)
    run = _hilly()
    tab = build_dp_tables(run)
    mus = ref["mus"]
    j_all = dp._backward(tab, mus)
    step = int(ref["j_stage_step"])
    np.testing.assert_allclose(j_all[:, ::step], ref["j_sub"], rtol=RTOL, atol=0.0)
    fw = dp._forward(tab, mus, j_all, ref["fw_policy"].astype(np.int64))
    fm = dp._forward_multi(tab, mus, j_all, ref["fm_pol"].astype(np.int64), ref["fm_e0"],
                           ref["fm_k0"].astype(np.int64))
    for f, key in ((fw, "fw"), (fm, "fm")):
        assert np.array_equal(f.controls, ref[key + "_controls"])
        _close(f.energy_j, ref[key + "_e"], rtol=RTOL, atol=0.0)
        _close(f.time_s, ref[key + "_t"], rtol=RTOL, atol=0.0)
    np.testing.assert_allclose(fw.e_path, ref["fw_path"], rtol=RTOL)
    short = RunModel(run.train, run.track, 0.0, 900.0)      # climb and descent
    res = solve_dp(short, 80.0)
    assert res.feasible and bool(ref["solve_feasible"])
    assert np.array_equal(res.controls, ref["solve_controls"])
    assert res.levels is not None
    np.testing.assert_allclose(res.levels, ref["solve_levels"], rtol=RTOL)
    assert res.energy_j == pytest.approx(float(ref["solve_e"]), rel=RTOL)
    assert res.time_s == pytest.approx(float(ref["solve_t"]), rel=RTOL)
    np.testing.assert_allclose(res.v_profile, ref["solve_v"], rtol=RTOL)
