"""Brake-by-wire sensors, slip-adhesion and fault injection on the instrumented car."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from metro_atc.core.plant.driver import simple_driver
from metro_atc.core.plant.line import LineSim
from metro_atc.core.line.scenario import FaultSpec, IncidentSpec, Scenario, load_scenario


def mini(**kw: Any) -> Scenario:
    """The mini scenario with replaced top-level fields."""
    return dataclasses.replace(load_scenario("mini"), **kw)


def test_pad_fault_changes_torque_per_clamp_force() -> None:
    """Degraded pad on axle 2: same commanded clamp force, 2 mu_b R_b F_c / r_w less force.

    Eq. 4 (rolling, w_dot = a / r_w, a the step's actual acceleration) inverted for mu_b
    recovers the injected value on the faulty axle and the nominal one elsewhere -- what
    the UKF observer has to estimate.
    """
    fl = FaultSpec(kind="pad_mu", train="train_01", axle=2, at_s=0.0, mu_b=0.1)
    sim = LineSim(mini(faults=[fl]), seed=0)
    p = sim.p
    seen = 0
    while sim.t < 300.0:
        sim.step(simple_driver(sim))
        fc = sim.clamp[0]
        if fc.min() > 3000.0:
            acc = min(float(sim.fleet.acc[0]), 0.0)  # the wheels follow the train
            mu_b = (sim.fx[0] - p.wheel_inertia_kgm2 * acc / p.wheel_radius_m ** 2) \
                * p.wheel_radius_m / (2.0 * p.brake_radius_m * fc)
            assert np.allclose(mu_b, [p.pad_mu_nominal, 0.1, p.pad_mu_nominal,
                                      p.pad_mu_nominal])
            assert np.allclose(fc, fc[0])  # brake-by-wire commands the same clamp force
            seen += 1
    assert seen > 20


def _run_with_samples(scn: Scenario, t_end: float, seed: int = 0,
                      train: int = 0) -> tuple[LineSim, Any]:
    sim = LineSim(scn, seed=seed)
    rows = []
    while sim.t < t_end and not sim.done:
        res = sim.step(simple_driver(sim))
        b = res.sensor_arrays
        if b is not None:
            for s in range(b.t.size):
                for c, tr in enumerate(b.trains):
                    if tr == train:
                        rows.append((b.t[s], b.omega[s, c].copy(), b.clamp[s, c].copy(),
                                     b.accel[s, c], b.vref[s, c]))
    return sim, rows


def test_defective_wheel_slides_on_wet_rail() -> None:
    """Wet rail + a wheel with half adhesion: service braking makes that axle slide, WSP
    dumps its clamp force and its wheel speed drops below the others; ATP stays safe."""
    line = dataclasses.replace(load_scenario("mini").line, adhesion="wet")
    fl = FaultSpec(kind="wheel", train="train_01", axle=3, at_s=0.0, adhesion_factor=0.5)
    sim = LineSim(mini(line=line, faults=[fl]), seed=0)
    max_slip = np.zeros(4)
    wsp_seen = False
    while sim.t < 300.0:
        sim.step(simple_driver(sim))
        max_slip = np.maximum(max_slip, sim.slip[0])
        if sim.brakes.wsp[0, 2]:
            wsp_seen = True
            assert sim.clamp[0, 2] < 0.5 * sim.clamp[0, 0]
    assert max_slip[2] > sim.curve.slip_peak
    assert np.all(max_slip[[0, 1, 3]] < sim.curve.slip_peak)
    assert wsp_seen
    assert sim.kpis()["atp_violations"] == 0


def test_emergency_brake_on_wet_rail_slides_all_axles() -> None:
    """A breakdown (emergency brake, 1.4 m/s^2 demand) on wet rail exceeds the peak
    adhesion (~0.12 g): every sensed axle slides, the train still stops."""
    line = dataclasses.replace(load_scenario("mini").line, adhesion="wet")
    inc = IncidentSpec(kind="breakdown", train="train_01", at_s=70.0, duration_s=30.0)
    sim = LineSim(mini(line=line, incidents=[inc]), seed=0)
    slid = np.zeros(4, dtype=bool)
    while sim.t < 100.0:
        sim.step(simple_driver(sim))
        if sim.t > 70.0:
            slid |= sim.slip[0] > sim.curve.slip_peak
    assert slid.all()
    assert sim.fleet.v[0] == 0.0


def test_sensor_dropout_and_stuck() -> None:
    """Dropout: NaN only inside the fault window; stuck: constant inside it."""
    faults = [FaultSpec(kind="sensor_dropout", train="train_01", axle=1, at_s=60.0,
                        duration_s=20.0, channel="wheel_omega"),
              FaultSpec(kind="sensor_stuck", train="train_01", at_s=100.0, duration_s=30.0,
                        channel="clamp_force")]
    sim, rows = _run_with_samples(mini(faults=faults), 160.0)
    t = np.array([r[0] for r in rows])
    om = np.array([r[1] for r in rows])
    cf = np.array([r[2] for r in rows])
    inside = (t >= 60.0) & (t < 80.0)
    assert np.all(np.isnan(om[inside, 0])) and not np.isnan(om[~inside, 0]).any()
    assert not np.isnan(om[:, 1:]).any()
    stuck = (t >= 100.0) & (t < 130.0)
    assert np.all(cf[stuck] == cf[stuck][0])
    assert np.unique(cf[(t >= 130.0)][:, 0]).size > 10


def test_sensor_subset_and_no_feedback_on_plant() -> None:
    """Only listed trains are instrumented; reading the samples never changes the plant."""
    sens = dataclasses.replace(load_scenario("mini").sensors, trains=["train_02"])
    sim_a, rows = _run_with_samples(mini(sensors=sens), 400.0)
    assert rows == []  # train_01 is not instrumented
    _, rows2 = _run_with_samples(mini(sensors=sens), 400.0, train=1)
    assert len(rows2) > 1000
    sim_b = LineSim(mini(sensors=sens), seed=0)
    while sim_b.t < sim_a.t:
        sim_b.step(simple_driver(sim_b))
    assert np.array_equal(sim_a.fleet.x, sim_b.fleet.x)
    assert np.array_equal(sim_a.fleet.v, sim_b.fleet.v)
    assert math.isclose(sim_a.t, sim_b.t)


def _loop_times(nxt: float, dt: float, t1: float) -> tuple[list[float], float]:
    """The plain sample clock: ``nxt += dt`` while ``nxt <= t1 + 1e-9``."""
    ts = []
    while nxt <= t1 + 1e-9:
        ts.append(nxt)
        nxt += dt
    return ts, nxt


def test_sample_clock_matches_the_plain_loop() -> None:
    """The laid-out sample clock gives the loop's instants bit for bit, whatever the steps.

    Random rates and step lengths (empty steps, steps longer than the layout), restarts
    by setting ``next_sample_t`` (as a checkpoint restore does), over many layouts.
    """
    rng = np.random.default_rng(7)
    sen = LineSim(mini(), seed=0).sensors
    for _ in range(20):
        dt = float(rng.uniform(0.001, 0.2))
        sen.sensor_dt = dt
        sen.next_sample_t = nxt = float(rng.uniform(0.0, 5.0))
        t = nxt - dt
        for k in range(2000):
            t += float(rng.choice([0.0, 0.25 * dt, dt, 3.7 * dt, 5000.0 * dt]))
            if k == 1000:  # restart the clock
                sen.next_sample_t = nxt = nxt + 0.5 * dt
            want, nxt = _loop_times(nxt, dt, t)
            got = sen.sample_times(t)
            assert got.tolist() == want
            assert sen.next_sample_t == nxt
