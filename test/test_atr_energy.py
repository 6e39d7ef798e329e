"""Energy-aware ATR (Sheu 2011 abstract): energy-running-time curves, affine LQR, bench."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.optimize import minimize

from metro_atc.bench import energy_regulation
from metro_atc.core.atr.blue_line import small_line
from metro_atc.core.atr.cost import CostWeights
from metro_atc.core.atr.energy import (
    EnergyLqrRegulator, EnergyTable, affine_lqr, build_energy_table, energy_table_for,
    energy_term, fit_curve, lower_hull)
from metro_atc.core.atr.evaluation import simulate
from metro_atc.core.atr.regulators import LqrRegulator, lqr_gain
from metro_atc.core.atr.traffic import linear_model
from metro_atc.core.bridge import atr_line_for
from metro_atc.core.line.scenario import load_scenario


@pytest.fixture(scope="module")
def mini():
    """The mini scenario (3 runs with grades and a restriction), its ATR line and DP table."""
    scn = load_scenario("mini")
    line = atr_line_for(scn)
    return scn, line, energy_table_for("mini")


def _synthetic_table(line, a_j=4.0e7, b_j=4.0e8, c_s=40.0) -> EnergyTable:
    """Table of E(R) = a + b / (R - c) [J] on every run of ``line`` (no planner needed)."""
    n = line.n_stations - 1
    rg = np.linspace(line.run_min_s, line.run_max_s, 9, axis=1)
    coef = np.tile([a_j, b_j, c_s], (n, 1))
    eg = a_j + b_j / (rg - c_s)
    z = np.zeros(n)
    return EnergyTable(scenario=line.name, source="synthetic", model="hyperbolic",
                       r_grid_s=rg, e_grid_j=eg, r_fast_s=rg[:, 0].copy(),
                       r_max_s=rg[:, -1].copy(), r_lo_s=rg[:, 0].copy(),
                       r_sched_s=np.asarray(line.run_s, dtype=float), coef=coef,
                       fit_rms_j=z, fit_max_j=z, table_max_j=z)


# ------------------------------------------------------------------ curves (physics)
def test_dp_curve_is_decreasing_and_convex(mini):
    """Longer running time -> less traction energy, with diminishing returns (convex)."""
    _, line, tab = mini
    assert tab.n_runs == 3 and tab.source == "dp"
    de = np.diff(tab.e_grid_j, axis=1)
    assert np.all(de < 0.0)                                   # decreasing in R
    assert np.all(np.diff(de, axis=1) >= -1e-6 * np.abs(de[:, 1:]))   # convex (hull)
    # range: from the planner's flat-out time to the ATR maximum running time
    np.testing.assert_allclose(tab.r_max_s, line.run_max_s, rtol=1e-12)
    assert np.all(tab.r_fast_s < line.run_min_s)
    # flat-out costs at least 40 % more than running at run_max (coasting saves energy)
    assert np.all(tab.e_grid_j[:, 0] > 1.4 * tab.e_grid_j[:, -1])
    # fitted model: same physics on the fit domain and < 1 % error there
    r = np.linspace(tab.r_lo_s, tab.r_max_s, 50)
    assert np.all(tab.d_energy_j_per_s(r) < 0.0)
    assert np.all(tab.d2_energy_j_per_s2(r) > 0.0)
    assert tab.fit_max_rel < 0.01
    assert np.all(tab.r_lo_s <= line.run_min_s)


def test_dp_reference_is_not_beaten_by_seed_002_coasting(mini):
    """The DP minimum-energy curve lies below the ECTP coasting family at every time."""
    scn, line, tab = mini
    ectp = build_energy_table(scn, line, source="ectp", n_grid=11)
    for r in (line.run_min_s, line.run_s, line.run_max_s):
        e_dp = tab.tabulated_energy_j(r)
        e_co = ectp.tabulated_energy_j(r)
        assert np.all(e_dp <= e_co * (1.0 + 1e-3)), (r, e_dp, e_co)
    # the flat-out ends agree with the planners' flat-out time (Level-II is slower)
    assert np.all(ectp.r_fast_s >= tab.r_fast_s - 0.2)


def test_blue_line_long_run_curve_coarse_grid():
    """Jiangzicui -> Longshan Temple (2.6 km, under the river) on a coarse DP grid."""
    scn = load_scenario("taipei_blue")
    tab = build_energy_table(scn, source="dp", runs=[8], ds_m=20.0, de_m2s2=2.0, n_mu=24,
                             n_grid=15)
    assert tab.n_runs == 1
    assert np.all(np.diff(tab.e_grid_j[0]) < 0.0)
    assert np.all(np.diff(tab.e_grid_j[0], 2) >= -1e-6 * tab.e_grid_j[0, 0])
    # a 2.6 km metro run: some 5-40 kWh of traction energy at the wheel
    assert 5.0 < tab.e_grid_j[0, -1] / 3.6e6 < tab.e_grid_j[0, 0] / 3.6e6 < 40.0
    assert tab.fit_max_rel < 0.02


def test_fit_and_hull_helpers():
    r = np.linspace(80.0, 100.0, 21)
    e = 3.0e7 + 5.0e8 / (r - 55.0)
    coef, rms, mx = fit_curve(r, e, "hyperbolic")
    np.testing.assert_allclose(coef, [3.0e7, 5.0e8, 55.0], rtol=1e-4)
    assert mx < 1e-4 * e.min() and rms <= mx
    cq, rms_q, _ = fit_curve(r, e, "quadratic")
    assert cq[2] > 0.0 and rms_q > rms
    # a point above the chord and a dominated point are dropped
    t, eh = lower_hull(np.array([1.0, 2.0, 3.0, 4.0, 2.5]), np.array([10.0, 8.0, 3.0, 3.5, 9.0]))
    np.testing.assert_array_equal(t, [1.0, 3.0])
    np.testing.assert_array_equal(eh, [10.0, 3.0])
    with pytest.raises(ValueError, match="unknown fit model"):
        fit_curve(r, e, "cubic")


# ------------------------------------------------------------------ cost and LQR
def test_energy_term(mini):
    _, line, tab = mini
    n = line.n_stations
    assert energy_term(line, tab, np.zeros(n), 1.0) == pytest.approx(0.0, abs=1e-12)
    u = np.zeros(n)
    u[2] = 3.0                                            # run 1 -> 2 three seconds longer
    expected = (tab.energy_j(line.run_s + np.array([0.0, 3.0, 0.0]))[1]
                - tab.e_sched_j[1]) / tab.e_scale_j
    assert energy_term(line, tab, u, 2.0) == pytest.approx(2.0 * expected, rel=1e-12)
    assert expected < 0.0
    u[2] = -1000.0                                        # saturated at run_min
    assert energy_term(line, tab, u, 1.0) > 0.0


def test_zero_energy_weight_is_the_plain_lqr(mini):
    _, line, tab = mini
    w = CostWeights()
    reg = EnergyLqrRegulator(line, tab, w, w_energy=0.0)
    a, b = linear_model(line.c())
    np.testing.assert_allclose(reg.k, lqr_gain(a, b, w.q, w.r), rtol=1e-12, atol=1e-14)
    np.testing.assert_array_equal(reg.u_ff_s, np.zeros(line.n_stations))
    x = np.array([30.0, -5.0, 12.0, 0.0])
    np.testing.assert_allclose(reg.decide(x), LqrRegulator(a, b, w).decide(x), atol=1e-12)
    assert np.allclose(reg.decide(np.zeros(4)), 0.0)


def test_energy_weight_lengthens_runs_and_saves_energy_undisturbed(mini):
    """No delay, no disturbance: LQR stays on the timetable, the energy-aware LQR runs longer."""
    _, line, tab = mini
    w = CostWeights()
    n, steps = line.n_stations, 30
    x0, dist = np.zeros(n), np.zeros((steps, n))
    a, b = linear_model(line.c())
    kpi = {}
    for name, reg in (("lqr", LqrRegulator(a, b, w)),
                      ("elqr", EnergyLqrRegulator(line, tab, w, w_energy=2.0))):
        traj = simulate(line, reg, x0, dist, steps)
        r, _ = energy_regulation.realised_running_times(line, traj)
        kpi[name] = (np.mean(r[-10:] - line.run_s), np.sum(tab.energy_j(r)) / steps)
    np.testing.assert_allclose(kpi["lqr"][0], 0.0, atol=1e-9)
    assert kpi["lqr"][1] == pytest.approx(tab.e_scale_j, rel=1e-9)
    assert kpi["elqr"][0] > 0.5                          # longer running times [s]
    assert kpi["elqr"][1] < 0.99 * tab.e_scale_j          # at least 1 % less energy
    reg = EnergyLqrRegulator(line, tab, w, w_energy=2.0)
    assert np.sum(reg.u_ff_s[1:]) > 0.0 and np.sum(reg.u_ss_s[1:]) > 0.0
    assert np.all(reg.g_j_per_s[1:] < 0.0) and np.all(reg.h_j_per_s2[1:] > 0.0)
    # the curvature raises the input weight of the running-time inputs only
    assert reg.r_e[0, 0] == pytest.approx(w.r) and np.all(np.diag(reg.r_e)[1:] > w.r)
    # more weight, more offset
    reg4 = EnergyLqrRegulator(line, tab, w, w_energy=4.0)
    assert reg4.x_ss_s[-1] > reg.x_ss_s[-1] > 0.0


def _quadratic_cost(reg: EnergyLqrRegulator, a, b, x0, u_flat, horizon):
    """Scaled finite-horizon sum of 1/2 q|x|^2 + 1/2 u^T R_E u + f^T u and its gradient."""
    n = a.shape[0]
    xs = reg.weights.x_scale_s
    q = reg.weights.q
    u = u_flat.reshape(horizon, n)
    x = np.zeros((horizon + 1, n))
    x[0] = x0 / xs
    for k in range(horizon):
        x[k + 1] = a @ x[k] + b @ u[k]
    cost = 0.5 * q * np.sum(x[:-1] ** 2) + 0.5 * np.einsum("ki,ij,kj->", u, reg.r_e, u) \
        + np.sum(u @ reg.f)
    lam = np.zeros(n)                              # adjoint: dJ/dx(k+1) (no terminal cost)
    grad = np.zeros_like(u)
    for k in range(horizon - 1, -1, -1):
        grad[k] = reg.r_e @ u[k] + reg.f + b.T @ lam
        lam = q * x[k] + a.T @ lam
    return cost, grad.ravel()


def test_affine_offset_matches_brute_force_two_stations():
    """Tiny 2-station line: the feed-forward offset and steady state vs scipy.optimize."""
    line = small_line(2)
    tab = _synthetic_table(line)
    w = CostWeights()
    reg = EnergyLqrRegulator(line, tab, w, w_energy=3.0)
    a, b = linear_model(line.c())
    n, xs = 2, w.x_scale_s
    # (1) the optimal steady state: minimise the stage cost over equilibria x = A x + B u
    m = np.linalg.solve(np.eye(n) - a, b)

    def stage(u: np.ndarray) -> float:
        x = m @ u
        return float(0.5 * w.q * x @ x + 0.5 * u @ reg.r_e @ u + reg.f @ u)

    st = minimize(stage, np.zeros(n), method="Nelder-Mead",
                  options={"xatol": 1e-10, "fatol": 1e-14, "maxiter": 4000})
    np.testing.assert_allclose(reg.u_ss_s, st.x * xs, atol=1e-4)
    np.testing.assert_allclose(reg.x_ss_s, m @ st.x * xs, atol=1e-4)
    assert reg.u_ss_s[1] > 0.0                            # the run is lengthened
    # (2) long-horizon brute force from two initial states: the first optimal move is the
    # regulator's -K x0 + u_ff (end effects of the free horizon decay geometrically)
    horizon = 40
    for x0 in (np.zeros(n), np.array([45.0, -20.0])):
        res = minimize(lambda u: _quadratic_cost(reg, a, b, x0, u, horizon),
                       np.zeros(horizon * n), jac=True, method="BFGS",
                       options={"gtol": 1e-12, "maxiter": 5000})
        u_opt = res.x.reshape(horizon, n) * xs
        np.testing.assert_allclose(u_opt[0], reg.decide(x0), atol=1e-4)
        np.testing.assert_allclose(u_opt[horizon // 2], reg.u_ss_s, atol=1e-4)
    # (3) the low-level solver reproduces the plain LQR gain without a linear term
    sol = affine_lqr(a, b, np.eye(n), 0.1 * np.eye(n), np.zeros(n))
    np.testing.assert_allclose(sol.k, lqr_gain(a, b, 1.0, 0.1), atol=1e-12)
    np.testing.assert_array_equal(sol.v, np.zeros(n))


def test_regulator_validation(mini):
    _, line, tab = mini
    with pytest.raises(ValueError, match="w_energy"):
        EnergyLqrRegulator(line, tab, w_energy=-1.0)
    with pytest.raises(ValueError, match="runs"):
        EnergyLqrRegulator(small_line(3), tab)
    reg = EnergyLqrRegulator(line, tab)
    with pytest.raises(ValueError, match="stations"):
        reg.decide(np.zeros(5))
    assert reg.decide(np.zeros((2, 4))).shape == (2, 4)


# ------------------------------------------------------------------ bench
def test_energy_regulation_bench_json(capsys):
    argv = ["--json", "--scenario", "mini", "--seeds", "2", "--weights", "1,3"]
    assert energy_regulation.main(argv) == 0
    out = json.loads(capsys.readouterr().out)
    assert set(out["methods"]) == {"lqr", "elqr_w1", "elqr_w3"}
    assert out["assumptions"] and all(isinstance(s, str) for s in out["assumptions"])
    for name, row in out["methods"].items():
        for case in energy_regulation.CASES:
            r = row["cases"][case]
            for key in ("cost", "energy_kwh_per_service", "worst_terminal_delay_s",
                        "energy_saved_vs_lqr_pct"):
                assert np.isfinite(r[key]), (name, case, key)
    und = {m: out["methods"][m]["cases"]["undisturbed"] for m in out["methods"]}
    assert und["lqr"]["energy_kwh_per_service"] == pytest.approx(
        out["scheduled_energy_kwh_per_service"], rel=1e-9)
    assert 0.0 < und["elqr_w1"]["energy_saved_vs_lqr_pct"] \
        < und["elqr_w3"]["energy_saved_vs_lqr_pct"]
    assert out["table"]["n_runs"] == 3
    assert energy_regulation.main(["--scenario", "no_such_scenario"]) == 2
