"""Independent LP optimum: closed form, brute force, grid convergence; planners against it."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from metro_atc.core.ato import coasting
from metro_atc.core.ato.dp import solve_dp
from metro_atc.core.ato.envelope import OperatingLimits, RunModel
from metro_atc.core.ato.mmas import MmasParams, solve_mmas
from metro_atc.core.ato.oracle import interval_time, solve_oracle
from metro_atc.core.ato.sections import build_section_tables
from metro_atc.core.line.vehicle import TAIPEI_MRT_6CAR, Track, max_traction_force

LIMITS = OperatingLimits()


def _ideal_train(a_trac: float) -> object:
    """Flat, resistance-free train with constant traction force m a_trac (no power limit)."""
    return dataclasses.replace(TAIPEI_MRT_6CAR, rotary_allowance=0.0, davis_a_n=0.0,
                               davis_b_n_per_mps=0.0, davis_c_n_per_mps2=0.0,
                               a1_mps2=a_trac, v1_mps=1e9, v2_mps=1e9, length_m=10.0,
                               max_speed_mps=40.0)


def test_closed_form_accelerate_coast_brake() -> None:
    """Flat, no resistance: accelerate at a, coast at v*, brake at b; E = M v*^2 / 2.

    T(v*) = v*/a + (L - v*^2/(2a) - v*^2/(2b)) / v* + v*/b; the switching points are
    s1 = v*^2/(2a) and s2 = L - v*^2/(2b).
    """
    a, b, length, v_star = 0.6, LIMITS.brake_decel_mps2, 900.0, 13.0
    train = _ideal_train(a)
    run = RunModel(train, Track.flat(30.0), 0.0, length, LIMITS)
    s1 = v_star ** 2 / (2 * a)
    s2 = length - v_star ** 2 / (2 * b)
    t_target = v_star / a + (s2 - s1) / v_star + v_star / b
    res = solve_oracle(run, t_target, ds_m=2.5)
    assert res.status == "optimal"
    e_closed = 0.5 * train.mass_kg * v_star ** 2
    assert res.energy_j == pytest.approx(e_closed, rel=2e-3)
    assert res.time_s == pytest.approx(t_target, abs=0.01)
    s, v = res.s_grid, res.v_profile
    acc = s < s1 - 5.0
    assert np.allclose(v[acc], np.sqrt(2 * a * s[acc]), atol=0.1)       # full traction
    coast = (s > s1 + 10.0) & (s < s2 - 10.0)
    assert np.allclose(v[coast], v_star, atol=0.1)                        # coasting plateau
    brake = s > s2 + 5.0
    assert np.allclose(v[brake], np.sqrt(2 * b * (length - s[brake])), atol=0.1)
    # no traction after the first switching point
    mid = 0.5 * (s[:-1] + s[1:])
    assert np.all(res.traction_n[mid > s1 + 4.0] < 1e-3 * train.mass_kg)


def _brute_force(run: RunModel, n: int, target: float, levels: int) -> float:
    """Minimum traction energy over a lattice of node speeds (the oracle's discrete model).

    Interior nodes take ``levels`` values of E = v^2/2 in [0, envelope]; every combination
    is checked against the traction, braking, acceleration and running-time constraints.
    """
    p = run.train
    s = np.linspace(0.0, run.length_m, n + 1)
    h = np.diff(s)
    cap = run.ceiling_e(s)
    fg = run.mean_grade_force(s[:-1], s[1:])
    grids = [np.linspace(0.0, cap[k], levels) for k in range(1, n)]
    best = np.inf
    for e1 in grids[0]:
        rest = np.meshgrid(*grids[1:], indexing="ij")
        m = rest[0].size
        e = np.zeros((m, n + 1))
        e[:, 1] = e1
        for k, r in enumerate(rest):
            e[:, 2 + k] = r.ravel()
        ea, eb = e[:, :-1], e[:, 1:]
        em = 0.5 * (ea + eb)
        vm = np.sqrt(2 * em)
        f = p.effective_mass_kg * (eb - ea) / h + p.davis_a_n + p.davis_b_n_per_mps * vm \
            + 2 * p.davis_c_n_per_mps2 * em + fg
        ok = np.all(np.maximum(f, 0.0) <= max_traction_force(p, vm) + 1e-6, axis=1)
        ok &= np.all(-f <= p.effective_mass_kg * run.limits.brake_decel_mps2 + 1e-6, axis=1)
        ok &= np.all((eb - ea) / h <= run.limits.accel_max_mps2 + 1e-9, axis=1)
        ok &= np.sum(interval_time(ea, eb, h), axis=1) <= target
        en = np.where(ok, np.sum(np.maximum(f, 0.0) * h, axis=1), np.inf)
        best = min(best, float(np.min(en)))
    return best


def test_brute_force_tiny_grid() -> None:
    """On a 4-interval grid the LP optimum is below every lattice point and the lattice
    minimum approaches it as the lattice is refined (50 -> 150 levels per node).

    Real train (Davis terms, constant-voltage/power traction, rotating mass) on a graded
    track; the lattice enumerates up to 150^3 node-speed combinations of the same model.
    """
    track = Track(np.array([-1e12, 150.0]), np.array([0.012, -0.02]),
                  np.array([-1e12]), np.array([70 / 3.6]))
    run = RunModel(TAIPEI_MRT_6CAR, track, 0.0, 400.0, LIMITS)
    n, target = 4, 50.0
    res = solve_oracle(run, target, ds_m=100.0)
    assert res.status == "optimal" and res.s_grid.size == n + 1
    coarse = _brute_force(run, n, target, 50)
    fine = _brute_force(run, n, target, 150)
    assert np.isfinite(coarse) and fine <= coarse
    assert res.energy_j <= fine * (1 + 1e-6)
    # the lattice error shrinks with the spacing (3x finer: at least halved)
    assert fine - res.energy_j < 0.5 * (coarse - res.energy_j)


def test_grid_convergence_and_infeasible() -> None:
    """Refining the grid changes the optimum by less each time; an impossible time is reported."""
    track = Track(np.array([-1e12, 150.0, 400.0]), np.array([0.0, -0.03, 0.01]),
                  np.array([-1e12, 250.0]), np.array([80 / 3.6, 60 / 3.6]))
    run = RunModel(TAIPEI_MRT_6CAR, track, 0.0, 550.0, LIMITS)
    t_fo = coasting.fotp(run, np.inf).time_s
    # (coarse grids under-resolve the envelope between nodes; from 4 m on it converges)
    e = [solve_oracle(run, 1.1 * t_fo, ds).energy_j for ds in (4.0, 2.0, 1.0)]
    assert abs(e[2] - e[1]) < abs(e[1] - e[0])
    assert abs(e[2] - e[1]) / e[2] < 1e-4
    assert solve_oracle(run, 0.8 * t_fo, 8.0).status == "infeasible"
    with pytest.raises(ValueError):
        solve_oracle(run, -1.0)


def _generated_runs(n: int, seed: int) -> list[RunModel]:
    """Random tracks: grades within +-40 per mille, limits 50-80 km/h, length 0.5-1.2 km."""
    rng = np.random.default_rng(seed)
    runs = []
    for _ in range(n):
        length = float(rng.uniform(500.0, 1200.0))
        n_g = int(rng.integers(2, 5))
        g_starts = np.concatenate(([-1e12], np.sort(rng.uniform(0, length, n_g - 1))))
        grades = rng.uniform(-0.04, 0.04, n_g)
        l_starts = np.array([-1e12, float(rng.uniform(0.2, 0.6) * length)])
        limits = rng.choice([50.0, 60.0, 70.0, 80.0], 2) / 3.6
        runs.append(RunModel(TAIPEI_MRT_6CAR, Track(g_starts, grades, l_starts, limits),
                             0.0, length, LIMITS))
    return runs


@pytest.mark.parametrize("seed", [11, 12, 13])
def test_dp_close_to_oracle_on_generated_tracks(seed: int) -> None:
    """DP within 0.5 % of the optimum and within 0.5 s of the running time."""
    run = _generated_runs(1, seed)[0]
    target = 1.1 * coasting.fotp(run, np.inf).time_s
    opt = solve_oracle(run, target, 2.0)
    dp = solve_dp(run, target)
    assert opt.status == "optimal"
    # nothing beats the optimum beyond discretisation: both average the grade over their
    # steps (DP sub-steps 5 m, oracle 2 m), which can save at most m g |grade step| x step
    # at every grade change
    steps = np.abs(np.diff(run.track.grades))
    smoothing_j = float(np.sum(steps)) * run.train.mass_kg * 9.80665 * (5.0 + 2.0)
    assert dp.energy_j >= opt.energy_j - smoothing_j
    assert dp.energy_j <= opt.energy_j * 1.005
    assert abs(dp.time_s - target) <= 0.5


def test_mmas_seeds_give_different_colonies() -> None:
    """The ant colonies depend on the seed (plain ant system: different best tours)."""
    run = _generated_runs(1, 21)[0]
    target = 1.1 * coasting.fotp(run, np.inf).time_s
    tab = build_section_tables(run, n_sections=20)
    tours = []
    for sd in (1, 2, 3):
        r = solve_mmas(tab, target, MmasParams(seed=sd, n_ants=10, n_iterations=5,
                                               local_search=False))
        tours.append((tuple(r.modes), tuple(r.codes)))
    assert len(set(tours)) > 1
