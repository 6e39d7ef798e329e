"""The dispatcher's commands on the ROS-free plant: validation, queue, application, replay."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

from metro_atc.core.dispatcher_commands import (KIND_HOLD, KIND_RELEASE, KIND_TSR_IMPOSE,
                                                KIND_SKIP, KIND_TSR_LIFT, KIND_WITHDRAW, LEAD_S,
                                                Command, Dispatcher, TsrBook)
from metro_atc.core.line.scenario import load_scenario
from metro_atc.core.plant.driver import simple_driver
from metro_atc.core.plant.line import LineSim


def _sim() -> LineSim:
    return LineSim(load_scenario("mini"), seed=3, trace_period_s=0.0)


def _run(sim: LineSim, d: Dispatcher, until_s: float, script=None) -> None:
    """Step with the simple driver; ``script(step)`` may submit commands before the step."""
    while not sim.done and sim.t < until_s - 1e-9:
        if script is not None:
            script(sim.step_count)
        d.apply_due(sim.step_count)
        sim.step(simple_driver(sim))


def tsr(start: float = 1000.0, end: float = 1800.0, v: float = 10.0, f: float = 150.0,
        name: str = "") -> Command:
    return Command(KIND_TSR_IMPOSE, start_m=start, end_m=end, speed_mps=v, from_s=f,
                   tsr_id=name)


@pytest.mark.parametrize("cmd, why", [
    (Command(99), "kind 99"),
    (tsr(start=math.nan), "start_m is nan"),
    (tsr(v=math.inf), "speed_mps is inf"),
    (tsr(start=-5000.0), "not on the line"),
    (tsr(end=9000.0), "not on the line"),
    (tsr(start=1800.0, end=1000.0), "expected end_m > start_m"),
    (tsr(v=30.0), "below the line's limit there"),
    (tsr(v=0.0), "below the line's limit there"),
    (tsr(f=100.0), "the earliest is 125"),
    (tsr(name="a b"), "letters, digits"),
    (Command(KIND_TSR_IMPOSE, track="down", start_m=1000.0, end_m=1800.0, speed_mps=10.0,
             from_s=200.0), "one track"),
    (Command(KIND_TSR_LIFT, tsr_id="nope"), "no such restriction"),
    (Command(KIND_HOLD, train_id="train_99", station="Bravo"), "unknown train"),
    (Command(KIND_HOLD, train_id="train_01", station="Zulu"), "unknown station"),
    (Command(KIND_RELEASE, train_id="train_01", station="Bravo"), "is not held"),
    (Command(KIND_WITHDRAW, train_id="train_99"), "unknown train"),
    (Command(KIND_WITHDRAW, train_id="train_01"), "has not entered service yet"),
    (Command(KIND_SKIP, train_id="train_99", station="Bravo"), "unknown train"),
    (Command(KIND_SKIP, train_id="train_01", station="Zulu"), "unknown station"),
    (Command(KIND_SKIP, train_id="train_01", station="Delta"), "is the terminus"),
    (Command(KIND_SKIP, train_id="train_01", station="MN01"), "is the first station"),
])
def test_refused_with_one_line_and_nothing_queued(cmd: Command, why: str) -> None:
    sim = _sim()
    d = Dispatcher(sim)
    ok, reason, ticket = d.submit(cmd)
    assert not ok and ticket == 0 and why in reason and "\n" not in reason, reason
    assert not d.queue and d.refused == {"invalid": 1}
    assert d.apply_due(0) == [] and len(sim.incidents.tsrs) == 0


def test_speed_limit_is_the_line_limit_in_the_zone() -> None:
    """60 km/h on [1200, 1500] m: 17 m/s is a restriction there, not on [1250, 1450] m."""
    d = Dispatcher(_sim())
    assert d.check(tsr(1100.0, 1300.0, 17.0)) is None  # the zone reaches 80 km/h track
    assert "16.667" in (d.check(tsr(1250.0, 1450.0, 17.0)) or "")


def test_hold_refused_for_a_train_out_of_service_or_past_the_station() -> None:
    sim = _sim()
    d = Dispatcher(sim)
    _run(sim, d, 200.0)
    assert int(sim.fleet.next_stop[0]) >= 2  # train_01 has left Bravo
    assert "has left Bravo" in (d.check(Command(KIND_HOLD, train_id="train_01",
                                                station="Bravo")) or "")
    assert d.check(Command(KIND_HOLD, train_id="train_01", station="MN04")) is None
    _run(sim, d, 2000.0)
    assert "out of service" in (d.check(Command(KIND_HOLD, train_id="train_01",
                                                station="Delta")) or "")


def test_queue_is_bounded_excess_counted() -> None:
    d = Dispatcher(_sim(), queue_max=3)
    got = [d.submit(tsr(name=f"z{k}", f=1e5)) for k in range(5)]
    assert [g[0] for g in got] == [True, True, True, False, False]
    assert [g[2] for g in got] == [1, 2, 3, 0, 0]
    assert "queue full" in got[3][1] and d.refused == {"queue_full": 2}
    assert len(d.apply_due(0)) == 3 and not d.queue
    assert d.submit(tsr(name="z0", f=1e5))[1].endswith("already imposed")


def test_tsr_applies_through_the_incidents_at_its_time() -> None:
    """The ATP learns the zone tsr_notice_s before from_s and supervises it from from_s."""
    sim = _sim()
    d = Dispatcher(sim)
    g = sim.geometry
    cell = int((1400.0 - g.x0) / g.dx)
    assert d.submit(tsr(f=150.0, name="works"))[0]
    _run(sim, d, 29.0)
    assert sim.atp.tsr_notice_s == 120.0
    _run(sim, d, 149.0)
    assert sim.incidents.tsrs == [(1000.0, 1800.0, 10.0, 150.0, math.inf)]
    assert [a.command.tsr_id for a in d.log] == ["works"] and d.log[0].step == 0
    assert float(sim.incidents.ceiling(g, 149.0, 0.0)[cell]) > 10.0
    assert float(sim.incidents.ceiling(g, 150.0, 0.0)[cell]) == 10.0
    # lifted at once
    assert d.submit(Command(KIND_TSR_LIFT, tsr_id="works"))[0]
    _run(sim, d, 160.0)
    lift = d.log[1]
    assert sim.incidents.tsrs[0][4] == lift.t_s == 149.0
    assert float(sim.incidents.ceiling(g, 160.0, 0.0)[cell]) > 10.0
    assert "already lifted" in (d.check(Command(KIND_TSR_LIFT, tsr_id="works")) or "")


def test_tsr_book_gives_the_ato_the_scripted_zone() -> None:
    """The zone an ATO learns is the one ato.onboard.tsr_zones gives a scripted TSR."""
    from metro_atc.core.ato.onboard import tsr_zones
    from metro_atc.core.line.scenario import IncidentSpec
    sim = _sim()
    d = Dispatcher(sim)
    d.submit(tsr(f=150.0, v=10.0, name="w"))
    a = d.apply_due(0)[0]
    book = TsrBook(120.0)
    assert book.apply(a) and not book.apply(a)
    scn = load_scenario("mini")
    scripted = dataclasses.replace(scn, incidents=[IncidentSpec(
        kind="tsr", at_s=150.0, duration_s=math.inf, start_m=1000.0, end_m=1800.0,
        limit_kmh=36.0)])
    assert book.tuple() == tuple(tsr_zones(scripted))


def _held_run(release_at_s: float) -> tuple[list, Dispatcher, LineSim]:
    sim = _sim()
    d = Dispatcher(sim)

    def script(step: int) -> None:
        if step == 0:
            assert d.submit(Command(KIND_HOLD, train_id="train_02", station="Charlie"))[0]
        if abs(sim.t - release_at_s) < 1e-9:
            assert d.submit(Command(KIND_RELEASE, train_id="train_02", station="MN03"))[0]
    _run(sim, d, 2000.0, script)
    return sim.event_log(), d, sim


def test_hold_keeps_the_train_until_released() -> None:
    ev, d, sim = _held_run(700.0)
    dep = [e for e in ev if e.train_idx == 1 and e.station_idx == 2 and e.kind == "departure"]
    arr = [e for e in ev if e.train_idx == 1 and e.station_idx == 2 and e.kind == "arrival"]
    assert arr and arr[0].t_s < 650.0
    assert dep and dep[0].t_s == 700.0  # released at 700 s, dwell long done: leaves then
    assert [a.step for a in d.log] == [0, 2800]
    assert sim.fleet.n_done == 2 and float(sim.incidents.extra_hold[1, 2]) == 0.0


def test_replay_reproduces_the_events() -> None:
    ev, d, _ = _held_run(650.0)
    sim = _sim()
    r = Dispatcher(sim)
    r.load_replay((a.step, a.command) for a in d.log)
    assert r.submit(tsr())[1].startswith("replaying")
    _run(sim, r, 2000.0)
    assert sim.event_log() == ev and [a.step for a in r.log] == [a.step for a in d.log]
    plain = _sim()
    _run(plain, Dispatcher(plain), 2000.0)
    assert plain.event_log() != ev


def test_lead_leaves_the_atos_time() -> None:
    assert LEAD_S >= 20 * 0.25


def test_checkpoint_keeps_the_dispatcher_state(tmp_path) -> None:
    """A simulator resumed from a checkpoint taken mid-hold ends as the one never stopped:
    the hold (and the TSR) are still released (lifted) by name, the log is kept."""
    from types import SimpleNamespace

    from metro_atc.core.checkpoint import load, save
    from metro_atc.core.plant.snapshot import static_parts

    sim = _sim()
    d = Dispatcher(sim)
    assert d.submit(Command(KIND_HOLD, train_id="train_02", station="Charlie"))[0]
    assert d.submit(tsr(f=150.0, name="w"))[0]
    _run(sim, d, 600.0)
    path = tmp_path / "ck.npz"
    save(path, SimpleNamespace(line=sim, dispatch_state=d.state), static_parts(sim))

    sim2 = _sim()
    d2 = Dispatcher(sim2)
    holder = SimpleNamespace(line=sim2, dispatch_state=d2.state)
    load(path, holder, static_parts(sim2))
    d2.state = holder.dispatch_state
    assert json.dumps(d2.state) == json.dumps(d.state)  # NaN fields: compared as text
    assert d2.holds == {(1, 2): 0.0}
    assert d2.submit(Command(KIND_TSR_LIFT, tsr_id="w"))[0]
    assert d2.submit(Command(KIND_RELEASE, train_id="train_02", station="Charlie"))[0]
    assert d.submit(Command(KIND_TSR_LIFT, tsr_id="w"))[0]
    assert d.submit(Command(KIND_RELEASE, train_id="train_02", station="Charlie"))[0]
    _run(sim2, d2, 2000.0)
    _run(sim, d, 2000.0)
    assert repr(sim2.event_log()) == repr(sim.event_log())  # NaN fields: as text
    assert json.dumps(d2.state) == json.dumps(d.state)
    assert len(d2.log) == 4


def test_restrictions_in_force_are_bounded() -> None:
    """Beyond TSR_MAX dispatcher restrictions in force or announced, impositions are refused
    (counted as tsr_limit) whatever the step timing; lifting one makes room again."""
    from metro_atc.core.dispatcher_commands import TSR_MAX
    sim = _sim()
    d = Dispatcher(sim, queue_max=10 * TSR_MAX)
    got = [d.submit(tsr(f=1e6 + k, name=f"z{k}")) for k in range(TSR_MAX + 5)]
    assert [a for a, _, _ in got] == [True] * TSR_MAX + [False] * 5
    assert d.refused == {"tsr_limit": 5} and "lift one first" in got[-1][1]
    d.apply_due(0)
    assert d.tsrs_in_force() == TSR_MAX
    assert not d.submit(tsr(f=2e6, name="more"))[0]
    assert d.submit(Command(KIND_TSR_LIFT, tsr_id="z0"))[0]
    d.apply_due(1)
    assert d.tsrs_in_force() == TSR_MAX - 1
    assert d.submit(tsr(f=2e6, name="more"))[0]


def _withdrawn_run(at_s: float = 100.0) -> tuple[Dispatcher, LineSim]:
    sim = _sim()
    d = Dispatcher(sim)

    def script(step: int) -> None:
        if abs(sim.t - at_s) < 1e-9:
            ok, why, _ = d.submit(Command(KIND_WITHDRAW, train_id="train_01"))
            assert ok, why
    _run(sim, d, 2000.0, script)
    return d, sim


def test_withdraw_at_the_next_station() -> None:
    """train_01, withdrawn at 100 s on its way to Bravo: everybody alights there, nobody
    boards, it leaves service at its departure; the run is complete with one withdrawn
    train (neither completed nor missing), train_02 runs its whole trip."""
    from metro_atc.core.plant.fleet import DONE
    from metro_atc.core.plant.kpi import service_end
    d, sim = _withdrawn_run()
    assert d.log[0].command.station == "Bravo" and d.station_of(d.log[0]) == 1
    ev = [e for e in sim.event_log() if e.train_idx == 0]
    assert [(e.station_idx, e.kind) for e in ev] == [
        (0, "arrival"), (0, "departure"), (1, "arrival"), (1, "departure")]
    load_at_bravo = 200 + ev[1].boarded
    assert ev[3].alighted == load_at_bravo and ev[3].boarded == 0
    assert int(sim.fleet.status[0]) == DONE and bool(sim.stations.withdrawn[0])
    assert float(sim.fleet.load[0]) == 0.0
    assert any(e.train_idx == 1 and e.station_idx == 3 for e in sim.event_log())
    assert sim.done and sim.t < 2000.0  # both out of service: the run ends
    k = sim.kpis()
    assert (k["completed_trains"], k["withdrawn_trains"]) == (1, 1)
    assert [p["completed"] for p in k["per_train"]] == [False, True]
    end = service_end(k["trains"], k["completed_trains"], sim.t, True, None, 1200.0,
                      k["withdrawn_trains"])
    assert end["finished"] and end["incomplete_trains"] == 0 and "1 withdrawn" in end["end"]
    assert not service_end(2, 1, sim.t, True, None, 1200.0)["finished"]
    assert "withdrawn already" in (d.check(Command(KIND_WITHDRAW, train_id="train_01")) or "")
    row = d.log[0].csv_row(sim.station_names, 1)
    assert row[:4] == ["train_01", "1", "Bravo", "withdraw"]


def test_withdraw_refused_before_the_terminus_and_twice_pending() -> None:
    sim = _sim()
    d = Dispatcher(sim)
    _run(sim, d, 100.0)
    assert d.submit(Command(KIND_WITHDRAW, train_id="train_01"))[0]
    assert "withdrawn already" in d.submit(Command(KIND_WITHDRAW, train_id="train_01"))[1]
    sim = _sim()
    d = Dispatcher(sim)
    while int(sim.fleet.next_stop[0]) < 3:
        _run(sim, d, sim.t + 1.0)
    why = d.check(Command(KIND_WITHDRAW, train_id="train_01")) or ""
    assert "next station Delta is the terminus" in why and "nothing to withdraw" in why
    _run(sim, d, 400.0)  # turning back, then parked
    assert "out of service" in (d.check(Command(KIND_WITHDRAW, train_id="train_01")) or "")


def test_withdraw_replays_and_survives_a_checkpoint(tmp_path) -> None:
    from types import SimpleNamespace

    from metro_atc.core.checkpoint import load, save
    from metro_atc.core.plant.snapshot import static_parts
    d, sim = _withdrawn_run()
    r_sim = _sim()
    r = Dispatcher(r_sim)
    r.load_replay((a.step, a.command) for a in d.log)
    _run(r_sim, r, 2000.0)
    assert repr(r_sim.event_log()) == repr(sim.event_log())
    # a checkpoint after the command, before the withdrawal: the resumed plant withdraws
    s1 = _sim()
    d1 = Dispatcher(s1)
    _run(s1, d1, 100.0)
    assert d1.submit(Command(KIND_WITHDRAW, train_id="train_01"))[0]
    _run(s1, d1, 101.0)
    path = tmp_path / "ck.npz"
    save(path, SimpleNamespace(line=s1, dispatch_state=d1.state), static_parts(s1))
    s2 = _sim()
    d2 = Dispatcher(s2)
    holder = SimpleNamespace(line=s2, dispatch_state=d2.state)
    load(path, holder, static_parts(s2))
    d2.state = holder.dispatch_state
    _run(s2, d2, 2000.0)
    assert repr(s2.event_log()) == repr(sim.event_log())


def _skip_run(at_s: float = 0.0, train: str = "train_01",
              station: str = "Charlie") -> tuple[Dispatcher, LineSim]:
    sim = _sim()
    d = Dispatcher(sim)

    def script(step: int) -> None:
        if abs(sim.t - at_s) < 1e-9:
            ok, why, _ = d.submit(Command(KIND_SKIP, train_id=train, station=station))
            assert ok, why
    _run(sim, d, 2000.0, script)
    return d, sim


def test_skip_runs_through_the_station() -> None:
    """train_01 skips Charlie: no arrival nor departure there, its passengers for Charlie
    ride on to Delta (all alight there), nobody boards it at Charlie; train_02 stops."""
    d, sim = _skip_run()
    ev = sim.event_log()
    mine = [(e.station_idx, e.kind) for e in ev if e.train_idx == 0]
    assert mine == [(0, "arrival"), (0, "departure"), (1, "arrival"), (1, "departure"),
                    (3, "arrival"), (3, "departure")]
    dep_b = [e for e in ev if e.train_idx == 0 and e.station_idx == 1][1]
    dep_d = [e for e in ev if e.train_idx == 0 and e.station_idx == 3][1]
    load_after_b = 200 + [e for e in ev if e.train_idx == 0][1].boarded \
        - dep_b.alighted + dep_b.boarded
    assert dep_d.alighted == load_after_b
    assert any(e.train_idx == 1 and e.station_idx == 2 for e in ev)
    assert sim.kpis()["completed_trains"] == 2 and sim.stations.skipped_stops == 0
    assert d.log[0].csv_row(sim.station_names, d.station_of(d.log[0]))[:4] == [
        "train_01", "2", "Charlie", "skip"]
    assert "skips Charlie already" in (d.check(Command(KIND_SKIP, train_id="train_01",
                                                       station="MN03")) or "")
    # replay: the same events
    r_sim = _sim()
    r = Dispatcher(r_sim)
    r.load_replay((a.step, a.command) for a in d.log)
    _run(r_sim, r, 2000.0)
    assert repr(r_sim.event_log()) == repr(ev)


def test_skip_target_is_the_runs_past_the_stop() -> None:
    """The ATO's running-time target for a run past a skipped stop: the commanded (else
    scheduled) run to it plus the scheduled run after it."""
    from metro_atc.core.plant.views import target_running_time
    sim = _sim()
    d = Dispatcher(sim)
    _run(sim, d, 100.0)
    assert d.submit(Command(KIND_SKIP, train_id="train_01", station="Charlie"))[0]
    before = float(target_running_time(sim, np.array([0]))[0])
    while int(sim.fleet.cur_station[0]) < 1 or bool(sim.fleet.dwelling[0]):
        _run(sim, d, sim.t + 0.25)
    assert int(sim.fleet.next_stop[0]) == 3
    rs = sim.service.sched_running_s
    rt = float(sim.stations.cmd_rt[0, 1]) if np.isfinite(sim.stations.cmd_rt[0, 1]) \
        else float(rs[1])
    assert float(target_running_time(sim, np.array([0]))[0]) == rt + float(rs[2])
    assert before == float(rs[0])


def test_skip_refused_when_passed_or_too_close() -> None:
    """Within its braking distance at the service brake, v^2 / (2 b), of the stop: too
    late (the check reads the fleet state, set here to a known one)."""
    sim = _sim()
    d = Dispatcher(sim)
    _run(sim, d, 100.0)
    assert int(sim.fleet.next_stop[0]) == 1 and not bool(sim.fleet.dwelling[0])
    x_b = float(sim.geometry.station_positions_m[1])
    b = float(sim.fleet.p.max_service_brake_mps2)
    brake = 15.0 ** 2 / (2 * b)
    x_now, v_now = float(sim.fleet.x[0]), float(sim.fleet.v[0])
    sim.fleet.set_xv(0, x_b - 0.9 * brake, 15.0)
    why = d.check(Command(KIND_SKIP, train_id="train_01", station="Bravo")) or ""
    assert "within its braking distance" in why and f"{brake:.1f} m" in why, why
    sim.fleet.set_xv(0, x_b - 1.1 * brake, 15.0)
    assert d.check(Command(KIND_SKIP, train_id="train_01", station="Bravo")) is None
    sim.fleet.set_xv(0, x_now, v_now)
    _run(sim, d, 300.0)
    why = d.check(Command(KIND_SKIP, train_id="train_01", station="Bravo")) or ""
    assert "has passed Bravo" in why


def test_skip_on_the_way_to_the_station() -> None:
    """Commanded while train_01 runs to Bravo (beyond its braking distance): it runs on to
    Charlie, where it stops."""
    d, sim = _skip_run(70.0, station="Bravo")
    assert d.log[0].step == 280
    assert [(e.station_idx, e.kind) for e in sim.event_log() if e.train_idx == 0] == [
        (0, "arrival"), (0, "departure"), (2, "arrival"), (2, "departure"), (3, "arrival"),
        (3, "departure")]
