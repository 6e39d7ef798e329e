"""Tests of the paper's vehicle, tyre tables and diagnostic observer (Lin 2010b)."""
from __future__ import annotations

import numpy as np
import pytest

from metro_atc.core.brake import diagnosis as dg
from metro_atc.core.brake import paper_vehicle as pv

P = pv.PaperVehicleParams()


def test_table_i_data() -> None:
    """Table I values; static loads carry the weight."""
    table_i = (1862.0, 2888.0, 1.18, 2.776, 1.1, 0.38)
    assert (P.mass, P.iz, P.lf, P.wheelbase, P.j_w, P.mu_b) == table_i
    assert P.static_loads().sum() == pytest.approx(P.mass * pv.G)
    assert pv.N_X == 26


def test_tyre_table_equals_magic_formula_on_grid_and_eq6_scaling() -> None:
    """Table = MF on grid points; eq. 6: F(mu) = mu/mu_bar * F_table(slip * mu_bar / mu)."""
    tab = pv.TyreTable(P)
    fz = tab.fz[4]
    k = tab.kappa[50]
    fx, fy = tab.forces(np.array([k]), np.array([tab.alpha[30]]), np.array([fz]),
                        np.array([P.mu_bar]))
    assert fx[0] == pytest.approx(float(pv.mf_long(np.array(k), np.array(fz), P)), rel=1e-12)
    assert fy[0] == pytest.approx(float(pv.mf_lat(np.array(tab.alpha[30]), np.array(fz), P)),
                                  rel=1e-12)
    mu = 0.3
    kq = np.array([0.01, 0.03, 0.1])
    fxs, _ = tab.forces(kq, np.zeros(3), np.full(3, 4000.0), np.full(3, mu))
    ref, _ = tab.forces(kq / mu, np.zeros(3), np.full(3, 4000.0), np.full(3, 1.0))
    assert np.allclose(fxs, mu * ref)
    # similarity keeps the slip stiffness: same initial slope on both surfaces
    s0, _ = tab.forces(np.array([1e-4]), np.zeros(1), np.array([4000.0]), np.array([mu]))
    s1, _ = tab.forces(np.array([1e-4]), np.zeros(1), np.array([4000.0]), np.array([1.0]))
    assert s0[0] == pytest.approx(s1[0], rel=1e-3)
    # peak force is mu * Fz (load sensitivity 0 at Fz0)
    kk = np.linspace(0, 1, 2001)
    f_pk = pv.mf_long(kk, np.full_like(kk, P.fz0), P).max()
    assert f_pk == pytest.approx(P.mu_bar * P.fz0, rel=1e-3)


def test_observer_model_matches_hand_computation() -> None:
    """f (eq. 1-4, 10) and h (eq. 8) on one state, against the formulas written out."""
    fx = pv.make_fx(P, 0.01)
    hx = pv.make_hx(P)
    rng = np.random.default_rng(0)
    x = np.zeros(pv.N_X)
    x[0], x[1], x[2] = 20.0, 0.3, 0.1
    x[3:7] = 20.0 / P.r_w + rng.standard_normal(4)
    x[7] = 0.35
    x[pv.I_FORCES] = [-1500.0, -1400.0, -800.0, -700.0, 900.0, 600.0]
    x[pv.I_FORCES + 1] = 100.0
    x[pv.I_FORCES + 2] = 1000.0
    u = np.array([0.05, 3000.0, 3100.0, 1500.0, 1400.0])
    dt = 0.01
    out = fx(x[None, :], u, dt)[0]
    d = u[0]
    f1, f2, f3, f4, fyf, fyr = x[pv.I_FORCES]
    drag = 0.5 * 1.2 * P.cda * x[0] ** 2
    fxb = (f1 + f2) * np.cos(d) - 2 * fyf * np.sin(d) + f3 + f4 - drag
    fyb_f = (f1 + f2) * np.sin(d) + 2 * fyf * np.cos(d)
    assert out[0] == pytest.approx(x[0] + dt * (fxb / P.mass + x[1] * x[2]))
    assert out[1] == pytest.approx(x[1] + dt * ((fyb_f + 2 * fyr) / P.mass - x[0] * x[2]))
    mz = P.lf * fyb_f - 2 * P.lr * fyr + P.tf * (f2 - f1) * np.cos(d) + P.tr * (f4 - f3)
    assert out[2] == pytest.approx(x[2] + dt * mz / P.iz)
    w = x[3:7] - dt * (2 * 0.35 * P.r_b * u[1:5] * np.tanh(x[3:7] / P.w_eps)
                       + P.r_w * x[pv.I_FX]) / P.j_w
    assert np.allclose(out[3:7], w)
    assert out[7] == x[7]                                     # eq. 9
    i0 = pv.I_FORCES[0]
    assert out[i0] == pytest.approx(x[i0] + dt * 100.0 + 0.5 * dt * dt * 1000.0)   # eq. 10
    assert out[i0 + 1] == pytest.approx(100.0 + dt * 1000.0)
    y = hx(x[None, :], u)[0]
    assert y[0] == pytest.approx(fxb / P.mass)
    assert y[1] == pytest.approx((fyb_f + 2 * fyr) / P.mass)
    assert np.allclose(y[2:], x[2:7])


def test_plant_wheel_torque_balance() -> None:
    """Truth plant, steady straight braking: r_w Fx = -2 mu_b R_b Fc - J dw/dt (eq. 4)."""
    log = pv.simulate(P, [pv.Scenario(0, 0.85, mu_b=0.36)], t_end=2.0)
    k = slice(150, 200)                                       # 1.5-2.0 s, steady braking
    wdot = np.gradient(log.omega[0], 0.01, axis=0)[k]
    lhs = P.r_w * log.fx[0, k]
    rhs = -2 * 0.36 * P.r_b * log.fc[0, k] - P.j_w * wdot
    assert np.allclose(lhs, rhs, rtol=0.02, atol=20.0)
    # accelerometer = sum of tyre forces minus drag over the mass (straight: no steering)
    drag = 0.5 * 1.2 * P.cda * log.vx[0] ** 2
    assert np.allclose(log.ax[0], (log.fx[0].sum(1) - drag) / P.mass)
    assert log.ax[0, 150] == pytest.approx(-4.0, abs=0.3)      # A1 request 4 m/s^2


@pytest.fixture(scope="module")
def a1_runs() -> dict[str, object]:
    """A1-B1 normal and pad-fault runs through observer and reference model."""
    scen = [pv.Scenario(0, 0.85, "none", mu_b=0.37), pv.Scenario(0, 0.85, "pad")]
    log = pv.simulate(P, scen, t_end=3.0)
    meas = pv.measure(log, pv.PaperSensorNoise(), np.random.default_rng(3))
    obs = pv.run_observer(P, meas)
    ref = pv.simulate(P, [pv.Scenario(0, 0.85)] * 2, t_end=3.0, reference=True,
                      mu_b_in=obs["mu_b"])
    return {"log": log, "obs": obs, "ref": ref}


def test_mu_b_converges_normal_and_pad(a1_runs: dict) -> None:
    """mu_b_hat converges to the truth (0.37 normal, 0.1 abnormal pad) after braking."""
    mu = a1_runs["obs"]["mu_b"]
    sd = a1_runs["obs"]["std"][..., pv.I_MUB]
    assert mu[0, -1] == pytest.approx(0.37, abs=0.02)
    assert mu[1, -1] == pytest.approx(0.10, abs=0.01)
    assert np.all(np.abs(mu[0, 150:] - 0.37) < 0.04)        # from 1 s on
    assert np.all(np.abs(mu[1, 150:] - 0.10) < 0.02)
    assert sd[0, 0] > 0.05 and sd[0, -1] < 0.01               # observable once braking


def test_force_estimates_track_truth(a1_runs: dict) -> None:
    """Estimated forces track the plant's forces (RMSE well below the force level)."""
    est = a1_runs["obs"]["forces"][0]
    tru = a1_runs["log"].targets()[0]
    rmse = np.sqrt(((est - tru) ** 2).mean(axis=0))
    assert np.all(rmse[:4] < 150.0)                           # braking forces ~2000 N
    assert np.abs(tru[:, 0]).max() > 1500.0


def test_pad_fault_detected_normal_not(a1_runs: dict) -> None:
    """Decision logic: pad fault -> flaw via mu_b < 0.2; the normal run stays clean."""
    obs, ref = a1_runs["obs"], a1_runs["ref"]
    t = a1_runs["log"].t[0]
    res = dg.residuals(obs["forces"], ref.targets())
    cfg = dg.DecisionConfig(thresholds=np.full(6, 50.0), persistence_s=0.3, gate_s=0.3,
                            filter_tau_s=0.1)
    d = dg.decide(obs["mu_b"], obs["std"][..., pv.I_MUB], res, t, cfg)
    assert d.flaw.tolist() == [False, True]
    assert d.pad_flaw[1]
    assert 0.5 < d.detect_time[1] < 1.5                       # brake onset at 0.5 s
