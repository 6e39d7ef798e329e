"""ATO core: seed 001 pre-work tables and the MAX-MIN ant system."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from metro_atc.core.ato.envelope import MODE_ACCEL, MODE_COAST, RunModel
from metro_atc.core.ato.mmas import MmasParams, evaluate_tours, solve_mmas
from metro_atc.core.ato.sections import SectionTables, build_section_tables, simulate_tours
from metro_atc.core.line.vehicle import TAIPEI_MRT_6CAR, Track


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
    t_fo, e_fo, _, _, _, _ = simulate_tours(tab, flat_m, flat_c)
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
    t_ex, e_ex, _, st, _, _ = simulate_tours(tab, modes, codes)
    ok = ~st
    np.testing.assert_allclose(e_tab[ok], e_ex[ok], rtol=0.02)
    np.testing.assert_allclose(t_tab[ok], t_ex[ok], rtol=0.01)


def test_paper_defaults() -> None:
    """MMAS defaults are seed 001's (50 ants, 100 iterations, [0.2, 2], rho, lambda, deltas)."""
    p = MmasParams()
    assert (p.n_ants, p.n_iterations, p.tau_min, p.tau_max, p.rho, p.lam, p.reinit_after,
            p.delta_ib, p.delta_bsf) == (50, 100, 0.2, 2.0, 0.1, 0.5, 19, 0.28, 0.5)
