"""ATO core: Ke 2010 pre-work tables and the MAX-MIN ant system."""

from __future__ import annotations

import itertools
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from metro_atc.core.ato.envelope import MODE_ACCEL, MODE_COAST, RunModel
from metro_atc.core.ato.mmas import MmasParams, MmasResult, evaluate_tours, solve_mmas
from metro_atc.core.ato.mmas_polish import polish_tour
from metro_atc.core.ato.sections import SectionTables, build_section_tables
from metro_atc.core.ato.tour_kernel import TourSimulator
from metro_atc.core.line.vehicle import TAIPEI_MRT_6CAR, Track

MMAS_REF_NPZ = Path(__file__).parent / "data" / "mmas_numpy_ref.npz"
"""Inputs and outputs of the former numpy ant construction and a colony run on it (recorded
before that path was dropped; test/record_planner_refs.py in the history of this file)."""
TOURS_REF_NPZ = Path(__file__).parent / "data" / "tours_numpy_ref.npz"
"""Inputs and outputs of the former numpy exact tour simulation (recorded likewise)."""


def _small_tables() -> tuple[RunModel, SectionTables]:
    track = Track(np.array([-1e12, 200.0]), np.array([0.0, -0.01]),
                  np.array([-1e12]), np.array([60.0 / 3.6]))
    run = RunModel(TAIPEI_MRT_6CAR, track, 0.0, 600.0)
    tab = build_section_tables(run, n_sections=4, codes_mps=np.array([30.0, 50.0]) / 3.6)
    return run, tab


def _brute_force(tab: SectionTables, t_max: float) -> tuple[float, int]:
    """Enumerate every (mode, code) tour; return the best feasible energy and the count."""
    opts = list(itertools.product(range(3), range(2)))
    tours = np.array(list(itertools.product(range(len(opts)), repeat=4)))
    modes = np.array([[opts[k][0] for k in row] for row in tours])
    codes = np.array([[opts[k][1] for k in row] for row in tours])
    t, e, _ = evaluate_tours(tab, modes, codes)
    ok = t <= t_max
    return float(np.min(e[ok])), int(len(tours))


@pytest.mark.parametrize("local_search", [False, True])
def test_mmas_finds_enumerable_optimum(local_search: bool) -> None:
    """On 4 sections x 3 modes x 2 codes (6^4 = 1296 tours) MMAS finds the brute-force optimum."""
    run, tab = _small_tables()
    t_fast = float(evaluate_tours(tab, np.zeros((1, 4), dtype=np.int64),
                                  np.ones((1, 4), dtype=np.int64))[0][0])
    t_max = t_fast + 8.0
    best, n = _brute_force(tab, t_max)
    assert n == 1296
    res = solve_mmas(tab, t_max, MmasParams(local_search=local_search, seed=3))
    assert res.table_time_s <= t_max + 1e-9
    assert res.table_energy_j == pytest.approx(best, rel=1e-9)


def test_mmas_respects_running_time_and_beats_flat_out() -> None:
    """The online stage meets the average-speed bound and saves energy against flat-out."""
    run = RunModel(TAIPEI_MRT_6CAR, Track.flat(80 / 3.6), 0.0, 1200.0)
    tab = build_section_tables(run, n_sections=12)
    flat_m = np.zeros((1, 12), dtype=np.int64)
    flat_c = np.full((1, 12), tab.n_codes - 1, dtype=np.int64)
    t_fo, e_fo, _, _, _ = TourSimulator(tab).run(flat_m, tab.codes_mps[flat_c])
    t_max = float(t_fo[0]) * 1.1
    res = solve_mmas(tab, t_max, MmasParams(n_iterations=30, seed=1))
    assert res.feasible
    assert res.time_s <= t_max + 1e-6
    assert res.energy_j < 0.85 * e_fo[0]
    assert np.any(res.modes == MODE_COAST) and res.modes[0] == MODE_ACCEL


def test_tables_match_exact_simulation() -> None:
    """Interpolated pre-work tables reproduce the exact section simulation of a tour."""
    run = RunModel(TAIPEI_MRT_6CAR, Track.flat(80 / 3.6), 0.0, 1000.0)
    tab = build_section_tables(run, n_sections=20)
    rng = np.random.default_rng(0)
    modes = rng.integers(0, 3, (8, 20))
    modes[:, 0] = MODE_ACCEL
    codes = rng.integers(0, tab.n_codes, (8, 20))
    t_tab, e_tab, _ = evaluate_tours(tab, modes, codes)
    t_ex, e_ex, _, st, _ = TourSimulator(tab).run(modes, tab.codes_mps[codes])
    ok = ~st
    np.testing.assert_allclose(e_tab[ok], e_ex[ok], rtol=0.02)
    np.testing.assert_allclose(t_tab[ok], t_ex[ok], rtol=0.01)


def test_paper_defaults() -> None:
    """MMAS defaults are Ke 2010's (50 ants, 100 iterations, [0.2, 2], rho, lambda, deltas)."""
    p = MmasParams()
    assert (p.n_ants, p.n_iterations, p.tau_min, p.tau_max, p.rho, p.lam, p.reinit_after,
            p.delta_ib, p.delta_bsf) == (50, 100, 0.2, 2.0, 0.1, 0.5, 19, 0.28, 0.5)


# ----------------------------------------------------------------- exact kernel
def _graded_run(davis_b_zero: bool = False) -> RunModel:
    """600 m with a steep descent, a climb and a 45 km/h restriction (every branch).

    davis_b_zero: the train without the linear resistance term (as the TTOBench trains:
    the kernel's coasting step then skips an arctangent).
    """
    track = Track(np.array([-1e12, 150.0, 350.0]), np.array([0.0, -0.03, 0.025]),
                  np.array([-1e12, 250.0, 400.0]), np.array([70 / 3.6, 45 / 3.6, 70 / 3.6]))
    train = replace(TAIPEI_MRT_6CAR, davis_b_n_per_mps=0.0) if davis_b_zero else \
        TAIPEI_MRT_6CAR
    return RunModel(train, track, 0.0, 600.0)


@pytest.mark.parametrize("davis_b_zero", [False, True])
def test_tour_kernel_equals_recorded_numpy_tours(davis_b_zero: bool) -> None:
    """The compiled kernel reproduces the former numpy exact simulation (its recorded
    output) to round-off.

    Random modes and continuous commands (including commands below the speeds reached, so
    accelerate sections latch and coast sections brake at their code) on grades of both
    signs and a restriction; trains with and without the Davis b term.
    """
    run = _graded_run(davis_b_zero)
    tab = build_section_tables(run, n_sections=12)
    sim = TourSimulator(tab)
    rng = np.random.default_rng(5)
    modes = rng.integers(0, 3, (30, 12))
    modes[:, 0] = MODE_ACCEL
    speeds = rng.uniform(15.0, 75.0, (30, 12)) / 3.6
    t_k, e_k, end_k, st_k, hist_k = sim.run(modes, speeds, record=True)
    ref = np.load(TOURS_REF_NPZ)
    key = "b0_" if davis_b_zero else "b_"
    assert np.array_equal(ref[key + "modes"], modes)
    assert np.array_equal(ref[key + "speeds"], speeds)
    t_n, e_n, end_n, st_n, hist_n = (ref[key + q]
                                     for q in ("t", "e", "end", "stalled", "hist"))
    np.testing.assert_allclose(end_k, end_n, rtol=1e-12, atol=1e-9)
    assert np.array_equal(st_k, st_n)
    ok = ~st_n
    assert ok.sum() >= 10
    np.testing.assert_allclose(t_k[ok], t_n[ok], rtol=1e-12)
    np.testing.assert_allclose(e_k, e_n, rtol=1e-12, atol=1e-6)
    np.testing.assert_allclose(hist_k, hist_n, rtol=1e-12, atol=1e-9)
    # prefix sharing: restarting at section 5 from a tour's own history gives the same result
    h = sim.history(modes[0], speeds[0], sim.equal_bounds())
    t_r, e_r, _, _, _ = sim.run(modes[:1], speeds[:1], first=np.array([5]), base=h)
    if ok[0]:
        assert t_r[0] == pytest.approx(t_n[0], rel=1e-12)
        assert e_r[0] == pytest.approx(e_n[0], rel=1e-12)


def test_polish_moves_boundaries_and_keeps_the_bound() -> None:
    """The exact local search never worsens a tour and keeps it within the time bound."""
    run = _graded_run()
    tab = build_section_tables(run, n_sections=12)
    sim = TourSimulator(tab)
    modes = np.full(12, MODE_COAST)
    modes[:3] = MODE_ACCEL
    speeds = np.full(12, tab.codes_mps[-1])
    t0, e0, _, _, _ = sim.run(modes[None], speeds[None])
    t_max = float(t0[0]) + 3.0
    pt = polish_tour(sim, modes, speeds, t_max)
    assert pt.time_s <= t_max + 1e-9
    assert pt.energy_j < e0[0]
    h = sim.history(pt.modes, pt.speeds_mps, pt.bounds)
    assert h[2, -1] == pytest.approx(pt.energy_j, rel=1e-12)
    assert np.all(np.diff(pt.bounds) >= 1)


def _metro_run(kind: str, seed: int, i: int) -> RunModel:
    from metro_atc.core.bridge import ato_limits_for, track_for, train_for
    if kind == "tto":
        from metro_atc.bench.ttobench import metro_scenario
        scn = metro_scenario()
    else:
        from metro_atc.core.linegen import load_generated
        scn = load_generated(seed)
    train = train_for(scn)
    pos = [st.position_m for st in scn.line.stations]
    return RunModel(train, track_for(scn), pos[i], pos[i + 1], ato_limits_for(train))


def _reference_kwh(i: int, factor: float) -> tuple[float, float]:
    """(target time [s], LP optimum [kWh]) shipped for TTOBench interstation i at factor."""
    import json
    from pathlib import Path

    import metro_atc
    path = Path(metro_atc.__file__).parent / "data" / "ttobench" / "reference_energies.json"
    vals = json.loads(path.read_text(encoding="utf-8"))["values"]
    row = [v for v in vals if v["interstation"] == i and abs(v["factor"] - factor) < 1e-9][0]
    return float(row["target_s"]), float(row["energy_kwh"])


_TTO_CASES = [(2, 1.05), (2, 1.10), (2, 1.20), (0, 1.05), (1, 1.20), (10, 1.05), (9, 1.10),
              (9, 1.20)]


@pytest.mark.parametrize("i,factor", _TTO_CASES)
def test_mmas_within_one_percent_of_the_ttobench_optimum(i: int, factor: float) -> None:
    """MMAS (paper parameters, seed 1) <= 1.01 x the shipped LP optimum
    of the TTOBench metro run (downhill 3 906 -> 6 272 m, the first and the worst runs), running
    time within 0.5 s of the target.
    """
    run = _metro_run("tto", 0, i)
    target, opt_kwh = _reference_kwh(i, factor)
    res = solve_mmas(build_section_tables(run), target, MmasParams(seed=1))
    assert res.feasible
    assert abs(res.time_s - target) <= 0.5
    assert res.energy_j / 3.6e6 <= 1.01 * opt_kwh


def test_mmas_within_one_percent_on_a_generated_line() -> None:
    """The same on a generated line (``linegen`` seed 7, run 1, 1.05 x flat-out), LP solved."""
    from metro_atc.core.ato import coasting
    from metro_atc.core.ato.oracle import solve_oracle
    run = _metro_run("gen", 7, 1)
    target = 1.05 * coasting.fotp(run, np.inf).time_s
    res = solve_mmas(build_section_tables(run), target, MmasParams(seed=1))
    opt = solve_oracle(run, target, 2.0)
    assert res.feasible
    assert abs(res.time_s - target) <= 0.5
    assert res.energy_j <= 1.01 * opt.energy_j


def test_seeds_give_different_colonies() -> None:
    """The seed drives the colony: different seeds, different sampled tours and histories.

    Plain ant system (no local search) on the 600 m graded run: the best-so-far history of
    seed 1 is reproduced by seed 1 and differs from seeds 2 and 3.
    """
    run = _graded_run()
    tab = build_section_tables(run, n_sections=12)
    t_fast = float(evaluate_tours(tab, np.zeros((1, 12), dtype=np.int64),
                                  np.full((1, 12), tab.n_codes - 1, dtype=np.int64))[0][0])

    def colony(sd: int) -> MmasResult:
        return solve_mmas(tab, t_fast * 1.15,
                          MmasParams(seed=sd, n_iterations=15, local_search=False))

    runs = {sd: colony(sd) for sd in (1, 2, 3)}
    again = colony(1)
    assert np.array_equal(again.history, runs[1].history)
    for sd in (2, 3):
        assert not np.array_equal(runs[sd].history, runs[1].history)


def test_tour_kernel_rejoin_and_first_changed_section() -> None:
    """Candidates stopped where they rejoin the base tour equal their full simulation.

    Single-section changes of a base tour (command, mode, moved bound) on a graded run:
    many rejoin the base bit for bit at a later section (speed-code caps); the shortcut
    (base's remaining time and energy) must agree with the full run to round-off.
    """
    run = _graded_run()
    tab = build_section_tables(run, n_sections=12)
    sim = TourSimulator(tab)
    rng = np.random.default_rng(7)
    modes = rng.integers(0, 3, 12)
    modes[0] = MODE_ACCEL
    speeds = rng.choice(tab.codes_mps, 12)
    bounds = sim.equal_bounds()
    h = sim.history(modes, speeds, bounds)
    n = 60
    cm = np.repeat(modes[None], n, axis=0)
    cv = np.repeat(speeds[None], n, axis=0)
    cb = np.repeat(bounds[None], n, axis=0)
    sec = rng.integers(1, 11, n)
    rows = np.arange(n)
    kind = rows % 3
    cv[rows[kind == 0], sec[kind == 0]] = rng.choice(tab.codes_mps, int(np.sum(kind == 0)))
    cm[rows[kind == 1], sec[kind == 1]] = (modes[sec[kind == 1]] + 1) % 3
    cb[rows[kind == 2], sec[kind == 2]] += rng.choice([-3, 2], int(np.sum(kind == 2)))
    t_f, e_f, _, st_f, _ = sim.run(cm, cv, cb)
    t_j, e_j, _, st_j, _ = sim.run(cm, cv, cb, np.zeros(n, np.int64), h,
                                   tour=(modes, speeds, bounds))
    assert np.array_equal(st_f, st_j)
    ok = ~st_f
    assert ok.sum() >= 40
    np.testing.assert_allclose(t_j[ok], t_f[ok], rtol=1e-11)
    np.testing.assert_allclose(e_j, e_f, rtol=1e-11, atol=1e-6)
    assert np.any(e_j != e_f)  # the shortcut was taken (its round-off differs)
    # the base itself and a tour identical to it
    t_b, e_b, _, _, _ = sim.run(modes[None], speeds[None], bounds[None], np.zeros(1, np.int64),
                                h, tour=(modes, speeds, bounds))
    assert t_b[0] == pytest.approx(h[1, -1], rel=1e-12)
    assert e_b[0] == pytest.approx(h[2, -1], rel=1e-12)


def test_table_evaluation_equals_section_lookups() -> None:
    """Compiled table evaluation = :meth:`SectionTables.lookup` section by section."""
    run = _graded_run()
    tab = build_section_tables(run, n_sections=12)
    rng = np.random.default_rng(3)
    modes = rng.integers(0, 3, (40, 12))
    codes = rng.integers(0, tab.n_codes, (40, 12))
    t, en, e_end = evaluate_tours(tab, modes, codes)
    e = np.zeros(40)
    t_ref = np.zeros(40)
    en_ref = np.zeros(40)
    for i in range(12):
        e, dt, de = tab.lookup(i, modes[:, i], codes[:, i], e)
        t_ref += dt
        en_ref += de
    np.testing.assert_allclose(t, t_ref, rtol=1e-13)
    np.testing.assert_allclose(en, en_ref, rtol=1e-13)
    np.testing.assert_allclose(e_end, e, rtol=1e-13)


# ------------------------------------------------- compiled colony, pruning (CPU)
def test_colony_kernel_equals_recorded_numpy_construction() -> None:
    """Compiled ant construction = the former numpy one's recorded output (same uniforms:
    same tours, same figures).
    """
    from metro_atc.core.ato.mmas_kernel import construct_ants
    ref = np.load(MMAS_REF_NPZ)
    run = _graded_run()
    tab = build_section_tables(run, n_sections=12)
    n_s, n_k = tab.n_sections, ref["u"].shape[2]
    m = np.empty((n_k, n_s), dtype=np.int64)
    c = np.empty((n_k, n_s), dtype=np.int64)
    t, en = np.empty(n_k), np.empty(n_k)
    construct_ants(ref["cum_m"], ref["cum_c"], ref["u"], tab.packed, 1.0 / tab.h_e,
                   int(tab.e_grid.size), m, c, t, en)
    assert np.array_equal(m, ref["ants_modes"]) and np.array_equal(c, ref["ants_codes"])
    np.testing.assert_allclose(t, ref["ants_t"], rtol=1e-12)
    np.testing.assert_allclose(en, ref["ants_e"], rtol=1e-12)
    # every mode and several codes drawn; codes only where allowed; figures = table lookups
    assert set(np.unique(m)) == {0, 1, 2} and np.unique(c).size >= 3
    assert np.all(tab.code_allowed[np.arange(n_s)[None, :], c])
    t_ref, en_ref, _ = evaluate_tours(tab, m, c)
    np.testing.assert_allclose(t, t_ref, rtol=1e-12)
    np.testing.assert_allclose(en, en_ref, rtol=1e-12)


def test_table_prefix_equals_section_lookups() -> None:
    """State of a tour at every section start = the look-ups of the sections before."""
    from metro_atc.core.ato.mmas_kernel import table_prefix
    run = _graded_run()
    tab = build_section_tables(run, n_sections=12)
    rng = np.random.default_rng(4)
    modes = rng.integers(0, 3, 12)
    codes = rng.integers(0, tab.n_codes, 12)
    e_p, t_p, en_p = np.empty(12), np.empty(12), np.empty(12)
    table_prefix(tab.packed, tab.h_e, int(tab.e_grid.size), tab.n_codes, modes, codes,
                 e_p, t_p, en_p)
    e, t, en = np.zeros(1), np.zeros(1), np.zeros(1)
    for i in range(12):
        assert (e_p[i], t_p[i], en_p[i]) == (e[0], t[0], en[0])
        e, dt, de = tab.lookup(i, modes[i:i + 1], codes[i:i + 1], e)
        t, en = t + dt, en + de


def test_tour_kernel_pruning_is_exact() -> None:
    """Pruned tours are past the cuts; the others are simulated bit for bit as without.

    Also the time lower bound to the stop is below every simulated tour's remaining time.
    """
    run = _graded_run()
    tab = build_section_tables(run, n_sections=12)
    sim = TourSimulator(tab)
    rng = np.random.default_rng(9)
    k = 200
    modes = rng.integers(0, 3, (k, 12))
    modes[:, 0] = MODE_ACCEL
    speeds = rng.uniform(25.0, 75.0, (k, 12)) / 3.6
    t_f, e_f, _, st_f, _ = sim.run(modes, speeds)
    ok = ~st_f
    t_cut = float(np.median(t_f[ok]))
    e_cut = float(np.median(e_f[ok]))
    t_p, e_p, _, st_p, _ = sim.run(modes, speeds, t_cut=t_cut, e_cut=e_cut)
    cut = ~np.isfinite(e_p)
    assert 0.2 * k < np.sum(cut) < k
    assert np.all((t_f[cut] > t_cut) | (e_f[cut] > e_cut) | st_f[cut])
    assert np.array_equal(t_p[~cut], t_f[~cut]) and np.array_equal(e_p[~cut], e_f[~cut])
    assert np.array_equal(st_p[~cut], st_f[~cut]) and not np.any(st_p[cut])
    lb = sim.time_lower_bound()
    for q in np.nonzero(ok)[0][:40]:
        h = sim.history(modes[q], speeds[q], sim.equal_bounds())
        assert np.all(h[1, -1] - h[1] >= lb - 1e-9)
        assert lb[0] > 0.5 * h[1, -1]


def test_colony_equals_the_recorded_numpy_colony() -> None:
    """The colony (compiled construction) runs the same as the former numpy construction
    did: recorded modes and codes exactly, best-so-far history to round-off (the tables'
    coasting entries come from the compiled strategy step since its numpy twin went: the
    last bits differ, 1e-13 relative in the history; relative 1e-9 as the plant's goldens).
    """
    ref = np.load(MMAS_REF_NPZ)
    run = _graded_run()
    tab = build_section_tables(run, n_sections=12)
    t_fast = float(evaluate_tours(tab, np.zeros((1, 12), dtype=np.int64),
                                  np.full((1, 12), tab.n_codes - 1, dtype=np.int64))[0][0])
    par = MmasParams(seed=2, n_iterations=15, local_search=False)
    a = solve_mmas(tab, t_fast * 1.15, par)
    np.testing.assert_allclose(np.asarray(a.history), ref["colony_history"], rtol=1e-9)
    assert np.array_equal(a.modes, ref["colony_modes"])
    assert np.array_equal(a.codes, ref["colony_codes"])


def test_shares_section_equals_the_float_product() -> None:
    """The word-wise overlap of the move pairs equals ``c @ c.T > 0`` (any section count)."""
    from metro_atc.core.ato.mmas_polish import shares_section
    rng = np.random.default_rng(4)
    for n_s in (1, 7, 50, 63, 64, 65, 129):
        for k in (1, 2, 9, 200):
            c = rng.random((k, n_s)) < rng.uniform(0.0, 0.2)
            f = c.astype(np.float64)
            assert np.array_equal(shares_section(c), (f @ f.T) > 0)


def test_same_runs_simulated_once_give_every_candidate() -> None:
    """Grouped candidates: the representatives' figures equal every candidate's, bit for bit.

    Acceleration-phase candidates; those whose commands are above every speed they reach
    run the same and are grouped.
    """
    from metro_atc.core.ato.mmas_polish import same_runs
    run = _graded_run()
    tab = build_section_tables(run, n_sections=12)
    sim = TourSimulator(tab)
    rng = np.random.default_rng(11)
    tour_m = rng.integers(0, 3, 12)
    tour_m[0] = MODE_ACCEL
    tour_v = rng.uniform(30.0, 70.0, 12) / 3.6
    tb = sim.equal_bounds()
    hist = sim.history(tour_m, tour_v, tb)
    ends, cmds = np.meshgrid(np.arange(6), np.arange(20.0, 75.0, 5.0) / 3.6, indexing="ij")
    ends, cmds = ends.ravel(), cmds.ravel()
    upto = np.arange(12)[None, :] <= ends[:, None]
    cm = np.where(upto, MODE_ACCEL, tour_m[None, :])
    cv = np.where(upto, cmds[:, None], tour_v[None, :])
    cb = np.repeat(tb[None, :], ends.size, axis=0)
    first = np.minimum(ends + 1, 11)
    # the state after the acceleration phase, as _starts gives it
    acc_h = {c: sim.history(np.full(12, MODE_ACCEL), np.full(12, c), tb) for c in cmds}
    e0, t0, en0 = (np.array([acc_h[cmds[k]][q, tb[first[k]]] for k in range(ends.size)])
                   for q in range(3))
    rep, inv = same_runs(cm, cv, cb, first, (e0, t0, en0))
    assert rep.size < 0.9 * ends.size  # unreached commands grouped
    kw = {"tour": (tour_m, tour_v, tb)}
    t_a, e_a, _, s_a, _ = sim.run(cm, cv, cb, first, hist, start=(e0, t0, en0), **kw)
    t_r, e_r, _, s_r, _ = sim.run(cm[rep], cv[rep], cb[rep], first[rep], hist,
                                  start=(e0[rep], t0[rep], en0[rep]), **kw)
    assert np.array_equal(t_r[inv], t_a) and np.array_equal(e_r[inv], e_a)
    assert np.array_equal(s_r[inv], s_a)


def test_changed_tours_from_the_prefix_equal_full_evaluation() -> None:
    """Tours changed from a base tour, evaluated from their first change: bit for bit."""
    from metro_atc.core.ato.mmas import evaluate_changed, tour_prefix
    run = _graded_run()
    tab = build_section_tables(run, n_sections=12)
    rng = np.random.default_rng(13)
    base_m = rng.integers(0, 3, 12)
    base_c = rng.integers(0, tab.n_codes, 12)
    cm = np.repeat(base_m[None, :], 300, axis=0)
    cc = np.repeat(base_c[None, :], 300, axis=0)
    for k in range(1, 300):  # row 0: the base tour itself
        sec = rng.choice(12, size=rng.integers(1, 4), replace=False)
        cm[k, sec] = rng.integers(0, 3, sec.size)
        cc[k, sec] = rng.integers(0, tab.n_codes, sec.size)
    t_f, e_f, _ = evaluate_tours(tab, cm, cc)
    t_c, e_c = evaluate_changed(tab, base_m, base_c, tour_prefix(tab, base_m, base_c), cm, cc)
    assert np.array_equal(t_c, t_f) and np.array_equal(e_c, e_f)
