"""Line operation: stations, dwell, ATS commands, incidents, turnback, determinism, API."""

from __future__ import annotations

import dataclasses
import json
import math
from typing import Any

import numpy as np
import pytest

from metro_atc.core.plant.driver import simple_driver
from metro_atc.core.plant.line import (MODE_DWELL, MODE_OUT, BrakeSensorSample, LineSim,
                                       TrainEvent)
from metro_atc.core.line.scenario import _package_dir, load_scenario


@pytest.fixture(scope="module")
def mini_run() -> LineSim:
    """The mini scenario run to the end with the reference driver (seed 0)."""
    sim = LineSim(load_scenario("mini"), seed=0)
    while not sim.done:
        sim.step(simple_driver(sim))
    return sim


def test_api_surface() -> None:
    """The contract used by the line_simulator node."""
    sim = LineSim(load_scenario("mini"), seed=0)
    assert sim.control_period_s == 0.25 and sim.t == 0.0
    assert sim.train_ids == ["train_01", "train_02"]
    assert sim.station_names == ["Alpha", "Bravo", "Charlie", "Delta"]
    assert np.allclose(sim.station_positions_m, [0, 900, 1900, 2800])
    assert not sim.active_mask().any()  # nobody in service before the first entry
    st = sim.states()
    for key in ("x_m", "v_mps", "a_mps2", "mode", "current_station", "next_station",
                "traction_energy_j", "regen_energy_j", "atp_limit_mps",
                "movement_authority_m"):
        assert st[key].shape == (2,)
    assert np.all(st["mode"] == MODE_OUT) and np.all(st["current_station"] == -1)
    with pytest.raises(ValueError):
        sim.step(np.zeros(3))
    with pytest.raises(IndexError):
        sim.set_departure(5, 0, 10.0, 60.0, 20.0)


def test_full_run_events_and_kpis(mini_run: LineSim) -> None:
    """Every train stops at every station in order; KPIs are JSON-serialisable and sane."""
    sim = mini_run
    k = sim.kpis()
    json.dumps(k, allow_nan=False)
    assert k["completed_trains"] == k["trains"] == 2
    assert k["atp_violations"] == 0 and k["atp_interventions"] == 0
    assert k["min_separation_m"] >= sim.atp.margin
    assert k["skipped_stops"] == 0
    assert 0.0 < k["energy_kwh"] < 1000.0
    for i in range(sim.n):
        evs = [e for e in sim.event_log() if e.train_idx == i]
        kinds = [(e.station_idx, e.kind) for e in evs]
        assert kinds == [(j, kd) for j in range(sim.n_st) for kd in ("arrival", "departure")]
        for a, d in zip(evs[0::2], evs[1::2]):
            assert d.t_s >= a.t_s + sim.scn.passengers.min_dwell_s - 1e-9
            assert d.dwell_s == pytest.approx(d.t_s - a.t_s)
            # no ATS command: never earlier than the timetable
            assert d.t_s >= d.scheduled_t_s - 1e-9
            assert d.delay_s == pytest.approx(d.t_s - d.scheduled_t_s)
    assert all(isinstance(e, TrainEvent) for e in sim.event_log())
    net = sum(e.boarded - e.alighted for e in sim.event_log())
    on_board_at_entry = sim.n * sim.scn.trains.initial_load_pax
    assert abs(net + on_board_at_entry) <= 2 * sim.n_st  # all alighted (rounding)


def test_trajectories_monotone_within_limits(mini_run: LineSim) -> None:
    """Positions never decrease, speeds stay under the ceiling, stops are within tolerance."""
    sim = mini_run
    x = np.vstack(sim.trace["x"])
    v = np.vstack(sim.trace["v"])
    run = np.vstack(sim.trace["run"])
    for i in range(sim.n):
        xi = x[run[:, i], i]
        assert np.all(np.diff(xi) >= -1e-9)
        k = ((xi - sim.geometry.x0) * sim.geometry.inv_dx).astype(int)
        assert np.all(v[run[:, i], i] <= sim.atp.ceiling_phys[k] + 1e-9)
    arr = sim.stations.act_arr[:, 1:]
    assert np.all(np.isfinite(arr))
    # the reference driver stops within the tolerance: arrival implies |x - stop| <= tol
    assert sim.tol_stop == 1.0


def test_determinism_and_seed_dependence(mini_run: LineSim) -> None:
    """Same seed, same events; another seed changes the random departure delays."""
    def events(seed: int, t_end: float) -> list[Any]:
        sim = LineSim(load_scenario("mini"), seed=seed)
        while not sim.done and sim.t < t_end:
            sim.step(simple_driver(sim))
        return [(e.train_idx, e.station_idx, e.kind, e.t_s) for e in sim.event_log()]
    ref = [(e.train_idx, e.station_idx, e.kind, e.t_s) for e in mini_run.event_log()]
    assert events(0, math.inf) == ref
    assert events(4, 400.0) != [e for e in ref if e[3] <= 400.0]


def _until(sim: LineSim, cond: Any, u: Any = None, limit: float = 2000.0) -> None:
    while not cond(sim) and sim.t < limit:
        sim.step(simple_driver(sim) if u is None else u(sim))


def test_ats_departure_command_holds_train() -> None:
    """set_departure holds the train until the commanded time (+ disturbance)."""
    scn = load_scenario("mini")
    scn = dataclasses.replace(scn, disturbances=dataclasses.replace(
        scn.disturbances, departure_delay_prob=0.0))
    sim = LineSim(scn, seed=0)
    sim.set_departure(0, 1, 400.0, 95.0, 30.0)
    _until(sim, lambda s: not math.isnan(s.stations.act_dep[0, 1]))
    assert sim.stations.act_dep[0, 1] == pytest.approx(400.0, abs=sim.control_period_s + 1e-9)
    assert sim.states()["target_running_time_s"][0] == pytest.approx(95.0)
    # a command during the dwell that asks for less than the passenger exchange is ignored
    sim2 = LineSim(scn, seed=0)
    _until(sim2, lambda s: s.fleet.dwelling[0] and s.fleet.cur_station[0] == 1)
    t_arr = float(sim2.fleet.arr_t[0])
    sim2.set_departure(0, 1, t_arr + 1.0)
    assert sim2.states()["mode"][0] == MODE_DWELL
    _until(sim2, lambda s: not math.isnan(s.stations.act_dep[0, 1]))
    assert sim2.stations.act_dep[0, 1] - t_arr >= scn.passengers.min_dwell_s - 1e-9


def test_nan_command_keeps_last() -> None:
    """A NaN entry keeps the previous command for that train."""
    sim = LineSim(load_scenario("mini"), seed=0)
    _until(sim, lambda s: s.active_mask()[0] and not s.fleet.dwelling[0],
           u=lambda s: np.zeros(s.n))
    for _ in range(8):
        sim.step(np.array([1.0, 0.0]))
    a_full = float(sim.fleet.acc[0])
    sim.step(np.array([np.nan, 0.0]))
    assert sim.fleet.u_last[0] == 1.0
    assert sim.fleet.acc[0] == pytest.approx(a_full, rel=0.05)


def test_initial_delay_incident() -> None:
    """taipei_blue_delay: train_01 leaves BL01 180 s late (Lin 2010a, Exp. 2) and the train
    behind is delayed by the knock-on effect."""
    sim = LineSim(load_scenario("taipei_blue_delay"), seed=0)
    _until(sim, lambda s: not math.isnan(s.stations.act_dep[1, 0]), limit=600.0)
    d0 = sim.stations.act_dep[0, 0] - sim.service.sched_dep[0, 0]
    assert 180.0 <= d0 <= 180.0 + sim.control_period_s + 40.0
    assert sim.stations.act_dep[1, 0] - sim.service.sched_dep[1, 0] > 60.0


def test_breakdown_and_turnback() -> None:
    """A breakdown stops the train for its duration; trains turn back and complete."""
    scn = load_scenario("mini")
    from metro_atc.core.line.scenario import IncidentSpec
    inc = IncidentSpec(kind="breakdown", train="train_01", at_s=80.0, duration_s=60.0)
    sim = LineSim(dataclasses.replace(scn, incidents=[inc]), seed=0)
    _until(sim, lambda s: s.t >= 81.0)
    x_stop = None
    while sim.t < 140.0:
        sim.step(simple_driver(sim))
        if sim.fleet.v[0] == 0.0 and x_stop is None:
            x_stop = float(sim.fleet.x[0])
        if x_stop is not None:
            assert float(sim.fleet.x[0]) == x_stop
    _until(sim, lambda s: s.done)
    assert sim.kpis()["completed_trains"] == 2
    assert np.all(sim.states()["next_station"] == -1)
    assert np.all(sim.states()["mode"] == MODE_OUT)
    # the terminal departure is followed by the turnback time before leaving service
    assert sim.t >= sim.stations.act_dep[1, -1] + scn.line.turnback_s


def test_sensor_rate_and_content(mini_run: LineSim) -> None:
    """Samples arrive at the configured rate with wheel speeds ~ v / r_w and clamp forces."""
    sim = LineSim(load_scenario("mini"), seed=0)
    rate = sim.scn.sensors.rate_hz
    samples: list[BrakeSensorSample] = []
    while sim.t < 300.0:
        samples.extend(sim.step(simple_driver(sim)).sensors)
    tr0 = [s for s in samples if s.train_idx == 0]
    t = np.array([s.t_s for s in tr0])
    assert np.allclose(np.diff(t), 1.0 / rate)
    omega = np.array([s.wheel_omega_radps for s in tr0])
    vref = np.array([s.ref_speed_mps for s in tr0])
    assert np.allclose(omega.mean(axis=1) * sim.p.wheel_radius_m, vref, atol=0.1)
    clamp = np.array([s.clamp_force_n for s in tr0])
    braking = clamp.mean(axis=1) > 2000.0
    assert braking.any() and (~braking).any()


def test_ats_dwell_cut_leaves_passengers_for_the_next_train(tmp_path: Any) -> None:
    """A dwell limit closes the doors early: fewer boarders, the rest take the next train."""
    text = (_package_dir() / "mini.yaml").read_text()
    text = text.replace("boarding_pph: [1200, 900, 600, 0]", "boarding_pph: [1200, 9000, 600, 0]")
    text = text.replace("departure_delay_prob: 0.3", "departure_delay_prob: 0.0")
    path = tmp_path / "crowded.yaml"
    path.write_text(text)
    scn = load_scenario(str(path))
    ref, cut = LineSim(scn, seed=0), LineSim(scn, seed=0)
    for sim in (ref, cut):
        _until(sim, lambda s: s.fleet.dwelling[0] and s.fleet.cur_station[0] == 1)
    t_arr = float(cut.fleet.arr_t[0])
    cut.set_departure(0, 1, t_arr, math.nan, 5.0)   # below the minimum dwell: 20 s applies
    for sim in (ref, cut):
        _until(sim, lambda s: not math.isnan(s.stations.act_dep[1, 1]), limit=3000.0)
    ref_dwell = ref.stations.act_dep[0, 1] - ref.stations.act_arr[0, 1]
    cut_dwell = cut.stations.act_dep[0, 1] - cut.stations.act_arr[0, 1]
    assert ref_dwell > 30.0                                   # passenger-driven dwell
    assert cut_dwell == pytest.approx(scn.passengers.min_dwell_s,
                                      abs=cut.control_period_s + 1e-9)
    ps = scn.passengers
    assert cut.stations.boarded[0, 1] < ref.stations.boarded[0, 1] - 100.0
    # boarding time after the door overhead bounds the boarders
    assert cut.stations.boarded[0, 1] \
        <= (cut_dwell - ps.door_overhead_s) / ps.boarding_s_per_pax + 1e-6
    # the passengers left behind board the next train
    assert cut.stations.boarded[1, 1] > ref.stations.boarded[1, 1] + 100.0
