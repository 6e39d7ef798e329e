"""Effort limits are motor and brake properties: a fuller train accelerates and brakes less.

The traction curve is specified at the reference mass m_ref (``mass_kg`` with its
``mass_load_pax``): up to it the drive is load-weighed, above it the motors give the force
``phi(v) m_ref`` (:func:`metro_atc.core.laws.traction_mass`).  The service brake is
load-weighed up to ``service_brake_load_pax`` (crush by default), the emergency brake up to
crush (:func:`metro_atc.core.laws.load_weighed_decel`).  The plant and the on-board ATO at
the train's load-weigh mass (:meth:`TrainParams.at_mass`) must agree on both.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import pytest

from metro_atc.core import laws
from metro_atc.core.ato.onboard import OnboardAto
from metro_atc.core.line.scenario import parse_scenario
from metro_atc.core.line.vehicle import (TAIPEI_MRT_6CAR, Track, TrainParams,
                                         max_traction_force_at)
from metro_atc.core.plant.line import LineSim

FLAT = """
name: flat
sources: [test]
sim: {control_period_s: 0.25, duration_s: 3000}
trains: {count: 1, preset: taipei_mrt_6car, initial_load_pax: LOAD}
line:
  stations:
    - {name: A, position_m: 0}
    - {name: B, position_m: 20000}
  line_speed_kmh: 300
timetable:
  first_departure_s: 30
  periods: [{start_s: 0, headway_s: 600, boarding_pph: [0, 0]}]
passengers: {alight_fraction: [0, 1], min_dwell_s: 5, door_overhead_s: 5}
disturbances: {departure_delay_prob: 0, running_time_noise: 0}
signalling: {overspeed_margin_kmh: 30}
"""

FRICTIONLESS = dataclasses.replace(TAIPEI_MRT_6CAR, davis_a_n=0.0, davis_b_n_per_mps=0.0,
                                   davis_c_n_per_mps2=0.0, max_speed_mps=200 / 3.6)
"""The Taipei preset without running resistance (closed forms below)."""
EMPTY, CRUSH = 0.0, TAIPEI_MRT_6CAR.capacity_pax
"""Loads [persons]: the empty and the crush-loaded train (the reference load is 1000)."""


def _sim(load: float, p: TrainParams = FRICTIONLESS) -> LineSim:
    """One train with ``load`` persons on a level line (its load stays: no one boards)."""
    scn = parse_scenario(FLAT.replace("LOAD", repr(float(load))), "flat.yaml")
    return LineSim(scn, seed=0, params=p)


def _run(sim: LineSim, u: float, until: Any) -> list[float]:
    """Step at the constant command u until ``until(sim)``; the accelerations [m/s^2]."""
    acc = []
    for _ in range(100_000):
        if until(sim):
            break
        v0 = float(sim.fleet.v[0])
        sim.step(np.array([u]))
        acc.append((float(sim.fleet.v[0]) - v0) / sim.control_period_s)
    return acc


def _released(sim: LineSim) -> bool:
    return bool(sim.fleet.status[0] == 1 and not sim.fleet.dwelling[0])


def _plant_traction(load: float) -> tuple[float, float]:
    """(mass [kg], steady full-traction acceleration [m/s^2]) of the plant at 3-8 m/s."""
    sim = _sim(load)
    _run(sim, 0.0, _released)
    _run(sim, 1.0, lambda s: s.fleet.v[0] >= 3.0)  # jerk ramp done, constant torque
    acc = _run(sim, 1.0, lambda s: s.fleet.v[0] >= 8.0)
    assert max(acc) - min(acc) < 1e-9  # constant force: a constant acceleration
    return float(sim.fleet.mass[0]), acc[-1]


def _plant_service(load: float, p: TrainParams) -> tuple[float, float]:
    """(mass [kg], steady full-service deceleration [m/s^2]) of the plant from 18 m/s."""
    sim = _sim(load, p)
    _run(sim, 0.0, _released)
    _run(sim, 1.0, lambda s: s.fleet.v[0] >= 18.0)
    _run(sim, -1.0, lambda s: s.fleet.a_dem[0] <= -1e9 or s.fleet.v[0] < 12.0)
    acc = _run(sim, -1.0, lambda s: s.fleet.v[0] < 6.0)
    return float(sim.fleet.mass[0]), -acc[-1]


def test_laws_known_values() -> None:
    """traction_mass = min(m, m_ref); the load-weighed brake: rate, then its maximum force."""
    assert laws.traction_mass(150e3, 214e3) == 150e3
    assert laws.traction_mass(300e3, 214e3) == 214e3
    assert laws.load_weighed_decel(1.0, 200e3, 250e3) == 1.0
    assert laws.load_weighed_decel(1.0, 250e3, 250e3) == 1.0
    assert laws.load_weighed_decel(1.0, 300e3, 250e3) == pytest.approx(250.0 / 300.0, 1e-15)
    assert laws.brake_force_max(1.2, 250e3) == pytest.approx(300e3, 1e-15)


def test_fuller_train_accelerates_less() -> None:
    """Above the reference load the tractive force is phi m_ref: a = a1 m_ref / M_eff.

    Below it the drive is load-weighed (a = a1 m / M_eff, as before); the crush-loaded
    train gets m_ref / m_crush = 0.79 of the force a mass-proportional limit would give.
    """
    p = FRICTIONLESS
    m_rot = p.rotary_allowance * p.mass_kg
    got = {}
    for load in (EMPTY, p.nominal_load_pax, CRUSH):
        m, a = _plant_traction(load)
        assert m == pytest.approx(p.mass_at_load(load), rel=1e-12)
        a_exp = p.a1_mps2 * min(m, p.mass_kg) / (m + m_rot)
        assert a == pytest.approx(a_exp, rel=1e-12, abs=1e-12), load
        got[load] = a
    assert got[CRUSH] < got[p.nominal_load_pax]
    m_crush = p.mass_at_load(CRUSH)
    assert got[CRUSH] < 0.85 * p.a1_mps2 * m_crush / (m_crush + m_rot)  # not load-weighed


def test_service_brake_falls_above_its_load_weigh_limit() -> None:
    """Load-weighed up to ``service_brake_load_pax``: below it the full service rate, above
    it the maximum brake force ``b M_eff(limit)`` over the train's effective mass."""
    p = dataclasses.replace(FRICTIONLESS, service_brake_load_pax=1200.0)
    b = p.max_service_brake_mps2
    m, d = _plant_service(800.0, p)
    assert d == pytest.approx(b, rel=1e-9)
    m, d = _plant_service(CRUSH, p)
    meff = m + p.rotary_allowance * p.mass_kg
    assert d == pytest.approx(b * p.service_brake_meff_limit_kg / meff, rel=1e-9)
    assert d < 0.95 * b
    # default: load-weighed to crush, the nominal rate at every load
    m, d = _plant_service(CRUSH, FRICTIONLESS)
    assert d == pytest.approx(b, rel=1e-9)


def test_emergency_brake_holds_its_guarantee_up_to_crush() -> None:
    """The emergency brake is load-weighed to crush: its nominal rate at every load up to it
    (above the ATP's guaranteed rate), and the plant's kernel constant is that mass."""
    for p in (TAIPEI_MRT_6CAR, FRICTIONLESS):
        lim = p.emergency_brake_meff_limit_kg
        for load in np.linspace(0.0, p.capacity_pax, 7):
            meff = float(p.effective_mass_at(p.mass_at_load(load)))
            d = laws.load_weighed_decel(p.emergency_brake_actual_mps2, meff, lim)
            assert d == p.emergency_brake_actual_mps2 >= p.emergency_brake_mps2
    st = _sim(CRUSH).stepper
    c = st.c.view(st.kn.CONSTANTS)[0]
    assert c["meff_eb"] == FRICTIONLESS.emergency_brake_meff_limit_kg
    assert c["meff_sb"] == FRICTIONLESS.service_brake_meff_limit_kg
    assert c["m_trac"] == FRICTIONLESS.mass_kg


def test_at_mass_is_the_reference_stock_at_its_mass() -> None:
    """at(m_ref) is the stock itself; elsewhere mass, effective mass and force limits."""
    p = TAIPEI_MRT_6CAR
    assert p.at_mass(p.mass_kg) is p
    for load in (EMPTY, 500.0, CRUSH):
        m = p.mass_at_load(load)
        q = p.at_mass(m)
        assert q.mass_kg == m and q.tare_mass_kg == pytest.approx(p.tare_mass_kg, rel=1e-12)
        assert q.effective_mass_kg == pytest.approx(p.effective_mass_at(m), rel=1e-14)
        for v in (0.0, 5.0, 12.0, 20.0):
            f_ref = laws.traction_force(v, laws.traction_mass(m, p.mass_kg), *p.traction_law)
            assert max_traction_force_at(q, v) == pytest.approx(f_ref, rel=1e-14)
    with pytest.raises(ValueError):
        p.at_mass(float("nan"))


@pytest.mark.parametrize("load", [EMPTY, CRUSH])
def test_ato_and_plant_agree(load: float) -> None:
    """The ATO at the train's load-weigh mass predicts the plant's full-traction
    acceleration and full-service deceleration (empty and crush load)."""
    p = FRICTIONLESS
    m, a_plant = _plant_traction(load)
    _, b_plant = _plant_service(load, p)
    ato = OnboardAto(p, Track.flat(30.0), [0.0, 20000.0], kernel="python")
    assert ato.set_load_mass(m)
    tr = ato.train
    a_ato = max_traction_force_at(tr, 5.0) / tr.effective_mass_kg  # no resistance
    assert a_ato == pytest.approx(a_plant, rel=1e-12)
    assert tr.max_service_brake_mps2 == pytest.approx(b_plant, rel=1e-9)
    assert ato.core.train is tr
    # a mass the load-weigh cannot give is ignored (counted), the train kept
    assert not ato.set_load_mass(float("nan")) and not ato.set_load_mass(1.0)
    assert ato.train is tr and ato.mass_rejected == 2


def test_ato_at_a_heavier_mass_plans_its_runs_apart() -> None:
    """Plans at another mass are not the reference's (the shared caches key by mass)."""
    p = TAIPEI_MRT_6CAR
    shared: dict[str, Any] = {}
    a = OnboardAto(p, Track.flat(80 / 3.6), [0.0, 1500.0], shared=shared, kernel="python")
    b = OnboardAto(p, Track.flat(80 / 3.6), [0.0, 1500.0], shared=shared, kernel="python")
    b.set_load_mass(p.mass_at_load(CRUSH))
    pa = a.plan(0, 110.0, 0.0).profile
    pb = b.plan(0, 110.0, 0.0).profile
    assert pa is not pb
    run_a, run_b = a.core.run, b.core.run
    assert run_a is not None and run_b is not None
    assert run_b is not run_a and run_b.train is b.train and run_a.train is p
