"""ATO core: closed-form coasting (ACTP n.d., eq. 7-8), envelope, ECTP / ACTP profiles."""

from __future__ import annotations

import numpy as np
import pytest

from metro_atc.core.ato import coasting
from metro_atc.core.ato.envelope import RunModel, profile_energy_time
from metro_atc.core.ato.envelope import OperatingLimits
from metro_atc.core.ato.step_kernel import coast_coefficients, coast_step, pack_train
from metro_atc.core.ato.strategy import coast_speed
from metro_atc.core.line.vehicle import (TAIPEI_MRT_6CAR, Track, effort_force, grade_force,
                                         resistance_force, rk4_step)

P = TAIPEI_MRT_6CAR


def _blue_run(length: float = 1300.0) -> RunModel:
    return RunModel(P, Track.flat(80.0 / 3.6), 0.0, length)


def test_eq7_solves_the_coasting_ode() -> None:
    """v(t) of ACTP n.d., eq. 7-8 satisfies dv/dt = -(c0 + c1 v + c2 v^2) and v(t_c) = v_c."""
    c0, c1, c2 = coast_coefficients(pack_train(P, OperatingLimits()).view(np.recarray)[0],
                                    float(grade_force(P, 0.005)))
    t = np.linspace(3.0, 40.0, 200)
    v = coast_speed(t, 3.0, 22.0, c0, c1, c2)
    assert v[0] == pytest.approx(22.0, abs=1e-12)
    h = 1e-4
    dv = (coast_speed(t + h, 3.0, 22.0, c0, c1, c2)
          - coast_speed(t - h, 3.0, 22.0, c0, c1, c2)) / (2 * h)
    np.testing.assert_allclose(dv, -(c0 + c1 * v + c2 * v * v), rtol=1e-6, atol=1e-9)


@pytest.mark.parametrize("grade", [0.0, 0.02, -0.01, -0.04])
def test_coast_step_matches_rk4_time_integration(grade: float) -> None:
    """Closed-form coasting over 600 m equals RK4 integration of Newton's law (zero effort)."""
    c = pack_train(P, OperatingLimits()).view(np.recarray)[0]
    e = 0.5 * 21.0 ** 2
    t_cf = 0.0
    for _ in range(300):  # 300 x 2 m
        e, dt, st = coast_step(c, e, 2.0, float(grade_force(P, grade)))
        assert not st
        t_cf += dt
    x, v, t = 0.0, 21.0, 0.0
    dt_rk = 0.01
    while x < 600.0:
        x_new, v_new = rk4_step(P, x, v, 0.0, grade, dt_rk)
        if float(x_new) >= 600.0:  # linear interpolation of the crossing
            frac = (600.0 - x) / (float(x_new) - x)
            t += frac * dt_rk
            v = v + frac * (float(v_new) - v)
            break
        x, v, t = float(x_new), float(v_new), t + dt_rk
    assert np.sqrt(2 * e) == pytest.approx(v, abs=2e-4)
    assert t_cf == pytest.approx(t, abs=2e-3)


def test_envelope_braking_curve_and_train_length() -> None:
    """Envelope: v^2 = v_t^2 + 2 b d before a restriction; restriction held until the tail."""
    v_line, v_r = 80 / 3.6, 40 / 3.6
    track = Track(np.array([-1e12]), np.array([0.0]), np.array([-1e12, 800.0, 1000.0]),
                  np.array([v_line, v_r, v_line]))
    run = RunModel(P, track, 0.0, 3000.0)
    b = run.limits.brake_decel_mps2
    s = np.array([700.0, 750.0, 790.0])
    np.testing.assert_allclose(run.ceiling(s), np.sqrt(v_r ** 2 + 2 * b * (800.0 - s)),
                               rtol=1e-3)
    assert float(run.static_limit(1000.0 + P.length_m - 1.0)) == pytest.approx(v_r)
    assert float(run.static_limit(1000.0 + P.length_m + 1.0)) == pytest.approx(v_line)
    assert float(run.ceiling(3000.0)) == 0.0
    assert float(run.ceiling(2990.0)) == pytest.approx(np.sqrt(2 * b * 10.0), rel=1e-3)


def test_profile_energy_matches_work_energy_balance() -> None:
    """Energy of a constant-acceleration profile = kinetic energy + resistance work."""
    run = RunModel(P, Track.flat(30.0), 0.0, 400.0)
    s = np.linspace(0.0, 200.0, 2001)
    a = 0.5
    v = np.sqrt(2 * a * s)
    energy, t, _ = profile_energy_time(run, s, v)
    vs = np.linspace(0.0, v[-1], 20001)
    # resistance work: integral F_r(v(s)) ds with ds = v dv / a
    work_r = np.trapezoid(resistance_force(P, vs) * vs / a, vs)
    expected = 0.5 * P.effective_mass_kg * v[-1] ** 2 + work_r
    assert energy == pytest.approx(expected, rel=2e-3)
    assert t == pytest.approx(v[-1] / a, rel=1e-3)


def _replay_strategy(run: RunModel, yc: float, delta: float, dt: float = 0.02) -> float:
    """Independent time-domain RK4 replay of 'traction to y_c, coast, brake on the envelope'."""
    x, v, t = 0.0, 0.0, 0.0
    m_eff = P.effective_mass_kg
    b = run.limits.brake_decel_mps2
    braking = False
    while t < 600.0:
        ceil = float(run.ceiling(min(x, run.length_m)))
        if v <= 0.0 and x > 0.5 * run.length_m:
            break
        on_curve = ceil < float(run.static_limit(min(x, run.length_m))) - 1e-6
        braking = braking or (v >= ceil and on_curve and x > run.length_m / 2)
        if braking:   # braking curve of the stop
            f = -m_eff * b + float(resistance_force(P, v))
        elif x < yc:
            f = float(effort_force(P, v, delta))
            if v >= ceil:  # cruise at the line speed
                f = min(f, float(resistance_force(P, v)))
        else:
            f = 0.0
        x1, v1 = rk4_step(P, x, v, f, 0.0, dt)
        x, v, t = float(x1), float(v1), t + dt
    return t


@pytest.mark.parametrize("target", [89.0, 90.0, 95.0])
def test_ectp_meets_running_time(target: float) -> None:
    """ECTP's coasting point gives the scheduled running time within 0.5 s (ACTP n.d.).

    Checked on the planner's prediction, on the distance-domain profile (trapezoid times) and
    on an independent time-domain RK4 replay of the strategy.
    """
    run = _blue_run()
    res = coasting.ectp(run, target)
    assert res.feasible, res.message
    assert abs(res.time_s - target) < 0.5
    _, t_prof, _ = profile_energy_time(run, res.s_grid, res.v_profile)
    assert abs(t_prof - target) < 0.5
    assert abs(_replay_strategy(run, res.coast_point_s, res.delta) - target) < 0.5
    fo = coasting.fotp(run, target)
    assert res.energy_j < fo.energy_j


def test_fotp_minimum_time_replays() -> None:
    """The flat-out minimum running time is reproduced by the time-domain replay."""
    run = _blue_run()
    fo = coasting.fotp(run, 90.0)
    assert abs(_replay_strategy(run, run.length_m + 1.0, 1.0) - fo.time_s) < 0.5


def test_ectp_below_minimum_time_falls_back_to_flat_out() -> None:
    """A schedule shorter than the flat-out time is flagged infeasible."""
    run = _blue_run()
    res = coasting.ectp(run, 60.0)
    assert not res.feasible
    assert "minimum running time" in res.message


def test_actp_tc_saves_energy_against_ectp() -> None:
    """ACTP-TC (traction level + coasting point) uses less energy than ECTP near schedule."""
    run = _blue_run()
    ec = coasting.ectp(run, 90.0)
    ac = coasting.actp(run, 90.0, tune_traction=True,
                       params=coasting.ActpParams(iterations=300))
    assert abs(ac.time_s - 90.0) < 1.0
    assert ac.energy_j < ec.energy_j
    assert ac.history.size == 300


def test_exact_coasting_point_when_time_is_not_monotonic(monkeypatch: pytest.MonkeyPatch
                                                         ) -> None:
    """On steep grades the running time need not fall as y_c moves on: the bracket is found
    where the time crosses the target, even when the last grid point is slower again
    (generated line gen_0046 raised IndexError here)."""
    length = 1000.0

    class _Sim:
        def __init__(self, grid: np.ndarray) -> None:
            # faster in the middle, slower at both ends (non-monotonic in y_c)
            self.time_s = 100.0 + 0.0001 * (grid - 0.6 * length) ** 2

    monkeypatch.setattr(coasting, "simulate_switching", lambda run, grid, d, h: _Sim(grid))
    run = type("Run", (), {"length_m": length})()
    yc, ok, _ = coasting.exact_coasting_point(run, 110.0)  # type: ignore[arg-type]
    assert ok and 0.0 <= yc <= length + 1.0
    assert abs(100.0 + 0.0001 * (yc - 0.6 * length) ** 2 - 110.0) < 1.0
