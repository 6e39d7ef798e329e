"""The dispatcher's desk through the graph: a scripted dispatcher (an rclpy client) on a run.

One recorded run of ``mini`` to completion: the dispatcher imposes a TSR, has train_01 skip
Charlie, switches the ATS from the timetable to the LQR, holds train_02 at Charlie (released
once it stands there) and, once train_02 stands at Bravo, withdraws it at its next station
(Charlie), with invalid requests refused on the way; all take effect at their stated step
and time, are in events.csv and in the bag, no ATP violation happens, and the run completes
(exit 0) with one train withdrawn.  Then ``--replay-commands`` of that bag gives events.csv
byte for byte.  A second, cut run is flooded with requests: the excess is refused and
counted, and the lockstep keeps stepping (no miss).
"""

from __future__ import annotations

import csv
import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from harness import DomainAllocator, TopicProbe

TSR = dict(start_m=1000.0, end_m=1800.0, speed_mps=10.0, from_s=150.0, tsr_id="works")
"""The imposed restriction: between Bravo and Charlie, 36 km/h from t = 150 s."""
RUN_TIMEOUT_S = 240.0


def _argv(out: Path, *extra: str) -> list[str]:
    return [sys.executable, "-m", "metro_atc", "run", "--scenario", "mini", "--json",
            "--no-plots", "--out", str(out), *extra]


def _finish(p: subprocess.Popen[str], code: int = 0) -> dict[str, Any]:
    try:
        stdout, stderr = p.communicate(timeout=RUN_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        p.kill()
        stdout, stderr = p.communicate()
        pytest.fail(f"run did not finish\n{stderr[-3000:]}")
    assert p.returncode == code, stderr[-3000:]
    return json.loads([ln for ln in stdout.splitlines() if ln.strip()][-1])


def _request(**fields: Any) -> Any:
    from metro_atc_msgs.srv import Dispatch
    req = Dispatch.Request()
    for k, v in fields.items():
        setattr(req.command, k, v)
    return req


def _call(client: Any, req: Any, timeout: float = 30.0) -> Any:
    fut = client.call_async(req)
    t0 = time.monotonic()
    while not fut.done():
        assert time.monotonic() - t0 < timeout, "no answer from /line/dispatch"
        time.sleep(0.002)
    return fut.result()


def _fleet_rows(bag: Path) -> list[tuple[float, str, float, float, float]]:
    """(t, train, position, speed, supervision speed) of every recorded fleet state."""
    from rosbags.rosbag2 import Reader

    from metro_atc.nodes.wire import fleet_state
    out = []
    with Reader(bag) as r:
        conns = [c for c in r.connections if c.topic == "/line/fleet_state"]
        for _, _, raw in r.messages(connections=conns):
            m = fleet_state.decode(bytes(raw))
            assert m is not None
            t = m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec
            for k, tid in enumerate(m.train_id):
                out.append((t, tid, m.position_m[k], m.speed_mps[k],
                            m.supervision_speed_mps[k]))
    return out


@pytest.fixture(scope="module")
def dispatched(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """The dispatched run and its replay (outputs, the service's answers)."""
    from metro_atc_msgs.msg import DispatcherCommand as D
    from metro_atc_msgs.msg import TrainEvent
    from metro_atc_msgs.srv import Dispatch

    from rosgraph_msgs.msg import Clock

    from metro_atc.nodes.common import QOS_CLOCK, QOS_EVENTS
    tmp = tmp_path_factory.mktemp("dispatch")
    res: dict[str, Any] = {"out": tmp / "run", "replay": tmp / "replay"}
    procs: list[subprocess.Popen[str]] = []
    with DomainAllocator().allocate() as dom:
        env = dict(os.environ, ROS_DOMAIN_ID=str(dom))
        probe = TopicProbe(dom, name="dispatcher")
        try:
            events = probe.subscribe(TrainEvent, "/line/events", QOS_EVENTS)
            clock = probe.subscribe(Clock, "/clock", QOS_CLOCK)
            client = probe.node.create_client(Dispatch, "/line/dispatch")
            p = subprocess.Popen(_argv(res["out"], "--record", "--step-timeout", "120"),
                                 env=env, cwd=tmp,
                                 stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
            procs.append(p)
            assert client.wait_for_service(timeout_sec=60.0)
            answers = {
                "nan": _call(client, _request(kind=D.KIND_TSR_IMPOSE, **dict(
                    TSR, start_m=math.nan))),
                "off_line": _call(client, _request(kind=D.KIND_TSR_IMPOSE, **dict(
                    TSR, end_m=50000.0))),
                "too_fast": _call(client, _request(kind=D.KIND_TSR_IMPOSE, **dict(
                    TSR, speed_mps=25.0))),
                "unknown": _call(client, _request(kind=D.KIND_HOLD, train_id="train_09",
                                                  station="Charlie")),
                "tsr": _call(client, _request(kind=D.KIND_TSR_IMPOSE, **TSR)),
                "hold": _call(client, _request(kind=D.KIND_HOLD, train_id="train_02",
                                               station="Charlie")),
                "skip": _call(client, _request(kind=D.KIND_SKIP, train_id="train_01",
                                               station="Charlie")),
                "skip_terminus": _call(client, _request(kind=D.KIND_SKIP, train_id="train_01",
                                                        station="Delta")),
                "withdraw_waiting": _call(client, _request(kind=D.KIND_WITHDRAW,
                                                           train_id="train_02")),
                "regulator_unknown": _call(client, _request(kind=D.KIND_REGULATOR,
                                                            regulator="pid")),
                "regulator": _call(client, _request(kind=D.KIND_REGULATOR, regulator="lqr")),
                # (the release of train_02 ends the run: it leaves service, train_01 is done)
                "release_unheld": _call(client, _request(kind=D.KIND_RELEASE,
                                                         train_id="train_01", station="MN03")),
            }

            def at_bravo() -> list[Any]:
                return [e for e in list(events) if e.train_id == "train_02"
                        and e.station_index == 1 and e.kind == 1]
            assert probe.wait_for(lambda: bool(at_bravo()), timeout=RUN_TIMEOUT_S)
            answers["withdraw"] = _call(client, _request(kind=D.KIND_WITHDRAW,
                                                         train_id="train_02"))
            answers["withdraw_again"] = _call(client, _request(kind=D.KIND_WITHDRAW,
                                                               train_id="train_02"))
            # release train_02 60 s after it arrived at Charlie (/line/events, /clock):
            # its passenger exchange is long over, the hold alone keeps it there

            def arrived() -> list[Any]:
                return [e for e in list(events) if e.train_id == "train_02"
                        and e.station_index == 2 and e.kind == 1]
            assert probe.wait_for(lambda: bool(arrived()), timeout=RUN_TIMEOUT_S)
            t_arr = arrived()[0].actual_time_s
            assert probe.wait_for(lambda: bool(clock) and clock[-1].clock.sec >= t_arr + 60.0,
                                  timeout=RUN_TIMEOUT_S)
            answers["release"] = _call(client, _request(kind=D.KIND_RELEASE,
                                                        train_id="train_02", station="MN03"))
            res["kpis"] = _finish(p)
            res["answers"] = answers
            # the replay: same scenario and options, the recorded commands at their steps
            r = subprocess.Popen(_argv(res["replay"], "--step-timeout", "120",
                                       "--replay-commands", str(res["out"] / "bag")),
                                 env=env, cwd=tmp,
                                 stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
            procs.append(r)
            res["replay_kpis"] = _finish(r)
        finally:
            probe.close()
            for proc in procs:
                if proc.poll() is None:  # a failed step above: no run left behind
                    proc.kill()
                    print(proc.communicate()[1][-4000:], file=sys.stderr)
    return res


def test_invalid_requests_refused_with_a_reason(dispatched: dict[str, Any]) -> None:
    a = dispatched["answers"]
    for key, why in (("nan", "start_m is nan"), ("off_line", "not on the line"),
                     ("too_fast", "below the line's limit"), ("unknown", "unknown train"),
                     ("release_unheld", "is not held"), ("skip_terminus", "is the terminus"),
                     ("withdraw_waiting", "has not entered service yet"),
                     ("withdraw_again", "withdrawn already"),
                     ("regulator_unknown", "expected one of")):
        assert not a[key].accepted and why in a[key].reason and a[key].ticket == 0, key
    for key in ("tsr", "hold", "release", "skip", "withdraw", "regulator"):
        assert a[key].accepted, a[key].reason
    k = dispatched["kpis"]["dispatcher"]
    assert k["applied"] == 6 and k["refused"] == {"invalid": 9} and k["stale"] == 0
    # the ATS switched to the LQR: both regulators' departure commands ran
    assert set(dispatched["kpis"]["regulators_seen"]) == {"none", "lqr"}


def test_commands_take_effect_at_their_step(dispatched: dict[str, Any]) -> None:
    rows = list(csv.DictReader((dispatched["out"] / "events.csv").open()))
    cmd = [r for r in rows if r["kind"] in ("tsr_imposed", "hold", "release")]
    assert [r["kind"] for r in cmd] == ["tsr_imposed", "hold", "release"]
    steps = [int(r["detail"].split(";")[0].split()[1]) for r in cmd]
    assert [float(r["t_s"]) for r in cmd] == [0.25 * s for s in steps]
    # the hold: train_02 leaves Charlie exactly at the release's step, not before
    dep = [r for r in rows if r["train_id"] == "train_02" and r["station_name"] == "Charlie"
           and r["kind"] == "departure"]
    arr = [r for r in rows if r["train_id"] == "train_02" and r["station_name"] == "Charlie"
           and r["kind"] == "arrival"]
    assert float(arr[0]["t_s"]) + 60.0 <= float(cmd[2]["t_s"]) == float(dep[0]["t_s"])
    assert rows.index(cmd[2]) < rows.index(dep[0])
    # the TSR: from 150 s the ATP supervises 10 m/s in the zone (its intervention curve
    # just above it; the line's own limit there is 16.7-22.2 m/s), and the trains keep below
    # 10 m/s there without an ATP intervention: the ATOs knew it as a scripted TSR
    fl = _fleet_rows(dispatched["out"] / "bag")
    inside = [r for r in fl if 1000.0 < r[2] < 1800.0 and r[3] > 0.0]
    after = [r for r in inside if r[0] >= TSR["from_s"]]
    assert {r[1] for r in after} == {"train_01", "train_02"}
    assert all(r[3] <= TSR["speed_mps"] and r[4] < TSR["speed_mps"] + 0.5 for r in after)
    k = dispatched["kpis"]
    assert k["atp_violations"] == 0 and k["atp_interventions"] == 0
    assert k["completed_trains"] == 1 and k["withdrawn_trains"] == 1 and k["finished"]
    assert k["incomplete_trains"] == 0 and "1 withdrawn" in k["end"]


def test_skip_and_withdraw(dispatched: dict[str, Any]) -> None:
    """train_01 runs through Charlie (no event there, its ATO planned Bravo -> Delta);
    train_02 leaves service at Charlie once released: every passenger alights, none boards,
    it has no event at Delta."""
    rows = list(csv.DictReader((dispatched["out"] / "events.csv").open()))
    t1 = [(r["station_name"], r["kind"]) for r in rows if r["train_id"] == "train_01"]
    assert [x for x in t1 if x[1] in ("arrival", "departure")] == [
        ("Alpha", "arrival"), ("Alpha", "departure"), ("Bravo", "arrival"),
        ("Bravo", "departure"), ("Delta", "arrival"), ("Delta", "departure")]
    assert ("Charlie", "skip") in t1
    t2 = [r for r in rows if r["train_id"] == "train_02"]
    assert ("Charlie", "withdraw") in [(r["station_name"], r["kind"]) for r in t2]
    last = [r for r in t2 if r["kind"] in ("arrival", "departure")][-1]
    assert (last["station_name"], last["kind"]) == ("Charlie", "departure")
    assert int(last["boarded"]) == 0 and int(last["alighted"]) > 0
    # nobody waited for the withdrawn train (nor for the skipping one) afterwards
    k = dispatched["kpis"]
    assert k["lockstep_misses"] == 0 and k["ats_timeouts"] == 0


def test_commands_in_the_bag(dispatched: dict[str, Any]) -> None:
    from metro_atc.nodes.dispatch_msgs import recorded_commands
    got = recorded_commands(str(dispatched["out"] / "bag"))
    assert [(a.sequence, a.command.kind) for a in got] == [(1, 1), (2, 3), (3, 6), (4, 7),
                                                           (5, 5), (6, 4)]
    assert got[0].command.tsr_id == "works" and got[0].command.from_s == 150.0
    assert got[3].command.regulator == "lqr" and got[3].command.from_s == got[3].t_s + 5.0
    assert got[4].command.station == "Charlie" and got[5].command.station == "MN03"


def test_replay_gives_events_byte_for_byte(dispatched: dict[str, Any]) -> None:
    a = (dispatched["out"] / "events.csv").read_bytes()
    b = (dispatched["replay"] / "events.csv").read_bytes()
    assert a == b
    assert dispatched["replay_kpis"]["dispatcher"]["replay"] is True
    assert dispatched["replay_kpis"]["atp_violations"] == 0


def test_flood_is_refused_and_counted_without_stalling_the_lockstep(tmp_path: Path) -> None:
    """300 requests at once while the run steps: beyond the 64 restrictions the dispatcher
    may hold (TSR_MAX) every imposition is refused and counted on /diagnostics and in the
    KPIs, however fast the requests arrive; the lockstep (10 s step timeout) misses none.
    The client's request queue holds all 300, so DDS drops none of them.
    """
    from diagnostic_msgs.msg import DiagnosticArray
    from metro_atc_msgs.msg import DispatcherCommand as D
    from metro_atc_msgs.srv import Dispatch

    from rosgraph_msgs.msg import Clock

    from metro_atc.nodes.common import QOS_CLOCK, QOS_DIAGNOSTICS
    with DomainAllocator().allocate() as dom:
        env = dict(os.environ, ROS_DOMAIN_ID=str(dom))
        probe = TopicProbe(dom, name="flood")
        try:
            diags = probe.subscribe(DiagnosticArray, "/diagnostics", QOS_DIAGNOSTICS)
            clock = probe.subscribe(Clock, "/clock", QOS_CLOCK)
            from rclpy.qos import QoSProfile, ReliabilityPolicy
            n_req = 300
            client = probe.node.create_client(Dispatch, "/line/dispatch", qos_profile=QoSProfile(
                depth=n_req, reliability=ReliabilityPolicy.RELIABLE))
            p = subprocess.Popen(_argv(tmp_path / "out"), env=env,
                                 cwd=tmp_path, stdout=subprocess.PIPE,
                                 stderr=subprocess.PIPE, text=True)
            assert client.wait_for_service(timeout_sec=60.0)
            assert probe.wait_for(lambda: len(clock) > 4, timeout=120.0)  # stepping
            # valid requests (restrictions far beyond the run), more than the queue holds
            futs = [client.call_async(_request(kind=D.KIND_TSR_IMPOSE, **dict(
                TSR, from_s=1e6 + k, tsr_id=f"flood_{k}"))) for k in range(n_req)]

            def counted() -> bool:
                return any("tsr_limit" in v.value for a in list(diags) for s in a.status
                           if s.name.startswith("line_simulator") for v in s.values
                           if v.key == "dispatch_refused")
            probe.wait_for(counted, timeout=RUN_TIMEOUT_S)
            kpis = _finish(p)
            done = [f.result() for f in futs if f.done()]
        finally:
            probe.close()
    d = kpis["dispatcher"]
    from metro_atc.core.dispatcher_commands import TSR_MAX
    assert d["accepted"] <= TSR_MAX
    assert d["accepted"] + d["refused_total"] == n_req  # every request answered or counted
    assert d["refused"].get("tsr_limit", 0) + d["refused"].get("queue_full", 0) \
        == n_req - d["accepted"] >= n_req - TSR_MAX
    assert all(r.accepted or "restrictions are in force" in r.reason or "queue full" in r.reason
               for r in done)
    assert kpis["lockstep_misses"] == 0 and kpis["completed_trains"] == 2
    assert counted()
