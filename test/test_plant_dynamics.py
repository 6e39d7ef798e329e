"""Train dynamics of the line plant against closed forms (ACTP n.d., eq. 7-8, kinematics)."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np
import pytest

from metro_atc.core.line.adhesion import DRY, WET
from metro_atc.core.plant.line import LineSim
from metro_atc.core.line.scenario import Scenario, parse_scenario
from metro_atc.core.line.track import G, curve_resistance_per_kg
from metro_atc.core.line.vehicle import TAIPEI_MRT_6CAR, TrainParams, max_traction_accel

FLAT = """
name: flat
sources: [test]
sim: {control_period_s: 0.25, duration_s: 3000}
trains: {count: 1, preset: taipei_mrt_6car, initial_load_pax: 1000}
line:
  stations:
    - {name: A, position_m: 0}
    - {name: B, position_m: 20000}
  line_speed_kmh: 300
  gradients: GRADES
timetable:
  first_departure_s: 30
  periods: [{start_s: 0, headway_s: 600, boarding_pph: [0, 0]}]
passengers: {alight_fraction: [0, 1], min_dwell_s: 5, door_overhead_s: 5}
disturbances: {departure_delay_prob: 0, running_time_noise: 0}
signalling: {overspeed_margin_kmh: 30}
"""


def flat_sim(params: TrainParams | None = None, grades: str = "[]") -> LineSim:
    """One train on a level 20 km line, released at t = 30 s (no disturbances)."""
    scn: Scenario = parse_scenario(FLAT.replace("GRADES", grades), "flat.yaml")
    p = params or dataclasses.replace(TAIPEI_MRT_6CAR, max_speed_mps=200 / 3.6)
    return LineSim(scn, seed=0, params=p)


def run(sim: LineSim, u: float, until: Any) -> list[tuple[float, float, float]]:
    """Step with a constant command until ``until(sim)``; returns (t, x, v) after each step."""
    out = []
    for _ in range(200_000):
        if until(sim):
            break
        sim.step(np.array([u]))
        out.append((sim.t, float(sim.fleet.x[0]), float(sim.fleet.v[0])))
    return out


def released(sim: LineSim) -> bool:
    """The train has left the first platform."""
    return bool(sim.fleet.status[0] == 1 and not sim.fleet.dwelling[0])


def test_coasting_matches_seed002_eq7() -> None:
    """Coasting speed v(t) = beta + alpha tan(gamma (C_v - t)) (ACTP n.d., eq. 7-8).

    dv/dt = -(c0 + c1 v + c2 v^2) with c = Davis terms / effective mass; eq. 7 as extracted
    reads ``alpha tan(beta + gamma (C_v - t))``, which does not solve that ODE -- the
    consistent form shifts by beta outside the tangent (alpha^2 = c0/c2 - c1^2/(4 c2^2),
    beta = -c1 / (2 c2), gamma = alpha c2), eq. 8 gives C_v from v(t_c) = v_c.
    """
    sim = flat_sim()
    run(sim, 0.0, released)
    run(sim, 1.0, lambda s: s.fleet.v[0] >= 20.0)
    run(sim, 0.0, lambda s: s.fleet.a_dem[0] == 0.0)  # jerk-limited release of the traction
    p = sim.p
    meff = sim.fleet.mass[0] + sim.fleet.m_rot
    c0, c1, c2 = p.davis_a_n / meff, p.davis_b_n_per_mps / meff, p.davis_c_n_per_mps2 / meff
    alpha = math.sqrt(c0 / c2 - c1 * c1 / (4 * c2 * c2))
    beta = -c1 / (2 * c2)
    gamma = alpha * c2
    tc, vc = sim.t, float(sim.fleet.v[0])
    cv = tc + math.atan((vc - beta) / alpha) / gamma  # eq. 8
    traj = run(sim, 0.0, lambda s: s.t >= tc + 120.0)
    t = np.array([r[0] for r in traj])
    v = np.array([r[2] for r in traj])
    v_cf = beta + alpha * np.tan(gamma * (cv - t))
    assert v[-1] < vc - 2.0  # it really decelerated
    assert np.max(np.abs(v - v_cf)) < 1e-7
    # and the ACTP n.d., eq. 2 coefficients are the ones used (per unit static mass)
    assert p.davis_a_n / p.mass_kg == pytest.approx(0.020084)
    assert p.davis_c_n_per_mps2 / p.mass_kg == pytest.approx(4.774e-5)


def _frictionless() -> TrainParams:
    return dataclasses.replace(TAIPEI_MRT_6CAR, davis_a_n=0.0, davis_b_n_per_mps=0.0,
                               davis_c_n_per_mps2=0.0, max_speed_mps=200 / 3.6)


def test_constant_acceleration_run() -> None:
    """No resistance, constant-torque region: a = a1 m / M_eff exactly; x = v t + a t^2/2."""
    sim = flat_sim(_frictionless())
    run(sim, 0.0, released)
    traj = run(sim, 1.0, lambda s: s.fleet.v[0] >= 8.0)
    a_exp = sim.p.a1_mps2 * sim.fleet.mass[0] / (sim.fleet.mass[0] + sim.fleet.m_rot)
    arr = np.array(traj)
    acc = np.diff(np.concatenate([[0.0], arr[:, 2]])) / sim.control_period_s
    # the jerk limit (Ke 2010: 1.0 m/s^3) ramps the effort from the holding brake
    assert np.all(np.diff(acc) <= sim.p.max_jerk_mps3 * sim.control_period_s + 1e-9)
    first = int(np.flatnonzero(np.abs(acc - a_exp) < 1e-9)[0])
    assert first <= 10
    t, x, v = arr[first:, 0], arr[first:, 1], arr[first:, 2]
    assert np.allclose(acc[first:], a_exp, rtol=1e-12, atol=1e-12)
    pred = x[0] + v[0] * (t - t[0]) + 0.5 * a_exp * (t - t[0]) ** 2
    assert np.max(np.abs(x - pred)) < 1e-9


def test_stopping_distance_service_brake() -> None:
    """No resistance: once the full service brake is built up, s = v^2 / (2 b) exactly."""
    sim = flat_sim(_frictionless())
    run(sim, 0.0, released)
    run(sim, 1.0, lambda s: s.fleet.v[0] >= 18.0)
    run(sim, -1.0, lambda s: s.fleet.a_dem[0] <= -s.p.max_service_brake_mps2)
    x0, v0 = float(sim.fleet.x[0]), float(sim.fleet.v[0])
    run(sim, -1.0, lambda s: s.fleet.v[0] <= 0.0)
    b = sim.p.max_service_brake_mps2
    assert float(sim.fleet.x[0]) - x0 == pytest.approx(v0 * v0 / (2 * b), abs=1e-6)


def test_grade_force_and_no_rollback() -> None:
    """On a 20 per mille downhill a coasting train accelerates at (m g sin - F_r) / M_eff;
    held on a 30 per mille uphill with zero traction it never rolls back."""
    sim = flat_sim(grades="[{start_m: -1000, grade_permille: -20}]")
    run(sim, 0.0, released)
    run(sim, 0.0, lambda s: s.fleet.v[0] > 0.0 and s.fleet.a_dem[0] == 0.0)
    v0, t0 = float(sim.fleet.v[0]), sim.t
    run(sim, 0.0, lambda s: s.t >= t0 + 0.25)
    p, m = sim.p, sim.fleet.mass[0]
    v_mid = 0.5 * (v0 + float(sim.fleet.v[0]))
    a_exp = (m * G * math.sin(math.atan(0.02)) - (p.davis_a_n + p.davis_b_n_per_mps * v_mid
                                                  + p.davis_c_n_per_mps2 * v_mid ** 2)) \
        / (m + sim.fleet.m_rot)
    assert (float(sim.fleet.v[0]) - v0) / 0.25 == pytest.approx(a_exp, rel=1e-4)
    up = flat_sim(grades="[{start_m: -1000, grade_permille: 30}]")
    run(up, 0.0, released)
    x_start = float(up.fleet.x[0])
    traj = run(up, 0.0, lambda s: s.t >= 120.0)
    assert min(r[1] for r in traj) >= x_start
    assert all(r[2] >= 0.0 for r in traj)


def test_traction_curve_seed002() -> None:
    """Constant torque, constant voltage, constant power regions (ACTP n.d., eq. 3-5)."""
    p = TAIPEI_MRT_6CAR
    v = np.linspace(0.1, 25.0, 500)
    phi = max_traction_accel(p, v)
    assert np.all(phi[v <= p.v1_mps] == p.a1_mps2)
    reg2 = (v > p.v1_mps) & (v <= p.v2_mps)
    assert np.allclose(phi[reg2] * v[reg2], p.a1_mps2 * p.v1_mps)  # F v / (m v) ~ 1/v
    reg3 = v > p.v2_mps
    assert np.allclose(phi[reg3] * v[reg3] ** 2, p.a2 * p.v2_mps)  # constant power ~ 1/v^2
    assert np.all(np.diff(phi) <= 1e-12)  # continuous and non-increasing


def test_curve_resistance_roeckl() -> None:
    """Roeckl: 650 / (R - 55) N/kN for R >= 300 m, 500 / (R - 30) below."""
    assert float(curve_resistance_per_kg(400.0)) == pytest.approx(650 / 345 / 1000 * G)
    assert float(curve_resistance_per_kg(250.0)) == pytest.approx(500 / 220 / 1000 * G)


@pytest.mark.parametrize("curve", [DRY, WET])
def test_adhesion_curve(curve: Any) -> None:
    """Burckhardt slip-adhesion: peak location, inverse on the stable branch, wet < dry."""
    s = np.linspace(0.0, 1.0, 20001)
    mu = curve.mu(s)
    assert curve.slip_peak == pytest.approx(s[np.argmax(mu)], abs=1e-4)
    assert curve.mu_peak == pytest.approx(mu.max(), rel=1e-6)
    m = np.linspace(0.0, 0.99 * curve.mu_peak, 50)
    assert np.allclose(curve.mu(curve.slip_for(m)), m, atol=1e-9)
    assert WET.mu_peak < DRY.mu_peak and WET.mu_slide < WET.mu_peak


def test_rk4_resting_branch_equals_standstill_branch() -> None:
    """Trains held at rest get bit-identical results with or without a train stopping.

    The compiled motion (:func:`metro_atc.core.plant.kernel_step.motion`) skips the
    standstill branch when only trains already at rest would take it; with one moving train
    braking to rest in the same period the full branch runs for all of them.  The resting
    trains' outputs must not depend on which branch ran, on a grade (uphill and downhill)
    with various brake efforts.
    """
    from metro_atc.core.plant import kernel as kn
    from metro_atc.core.plant import kernel_step as ks
    sim = flat_sim(grades="[{start_m: -5000, grade_permille: 0}, {start_m: 1000, "
                          "grade_permille: 35}, {start_m: 3000, grade_permille: -35}]")
    p, st = sim.p, sim.stepper
    c = st.c.copy()
    cr = c.view(kn.CONSTANTS)[0]
    cr["dt"], cr["substeps"] = 0.25, 1.0
    rng = np.random.default_rng(7)
    n = 40
    x = rng.uniform(0.0, 5000.0, n)
    mass = p.mass_kg + rng.uniform(0.0, 3.0e4, n)
    meff = mass + p.rotary_allowance * p.mass_kg
    inv = 1.0 / meff
    mp = np.stack([mass, meff, inv, p.davis_b_n_per_mps * inv, p.davis_c_n_per_mps2 * inv])
    masks = np.zeros((5, n), dtype=bool)

    def motion(v: np.ndarray, f_brake: np.ndarray) -> tuple[np.ndarray, list[np.ndarray]]:
        blk = np.zeros((kn.N_OUT, n))
        e = [np.zeros(n) for _ in range(7)]
        ks.motion(c, x, v, np.zeros(n), f_brake, np.zeros(n), np.ones(n), mp, st.geo, masks,
                  np.full(n, np.inf), *e, np.zeros(n, dtype=np.int64), blk)
        return blk, e

    # held trains: brake effort above the largest downhill grade force (they stay at rest)
    f_brake = rng.uniform(2.0e5, 6.0e5, n)
    v = np.zeros(n)
    rest, e_rest = motion(v, f_brake)
    assert np.all(rest[kn.OUT.v1] == 0.0) and np.array_equal(rest[kn.OUT.x1], x)
    assert not np.any(e_rest[6])  # no stop correction
    v_mix, f_mix = v.copy(), f_brake.copy()
    v_mix[0], f_mix[0] = 0.05, 3.0e5 - p.davis_a_n  # comes to rest inside the period
    mix, e_mix = motion(v_mix, f_mix)
    assert mix[kn.OUT.v1, 0] == 0.0 and mix[kn.OUT.x1, 0] > x[0]
    for row in (kn.OUT.x1, kn.OUT.v1, kn.OUT.acc):
        np.testing.assert_array_equal(rest[row, 1:], mix[row, 1:])
    for a, b in zip(e_rest, e_mix):
        np.testing.assert_array_equal(a[1:], b[1:])
