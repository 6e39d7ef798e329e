"""The ats_regulator node over DDS: events in, departure commands out; bad events dropped."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from harness import NodeProcess, TopicProbe

pytestmark = pytest.mark.integration


def _reference_dispatcher(regulator: str):  # type: ignore[no-untyped-def]
    """The node's ROS-free core on the same scenario (mini)."""
    from metro_atc.core.atr.dispatch import make_dispatcher
    from metro_atc.core.line.scenario import load_scenario

    return make_dispatcher(load_scenario("mini"), regulator)


@pytest.mark.parametrize("regulator", ["none", "lqr", "elqr"])
def test_node_answers_arrivals_with_departure_commands(installed: Path, ros_env: dict[str, str],
                                                       probe: TopicProbe, tmp_path: Path,
                                                       regulator: str) -> None:
    """An arrival event at station 1 gets a departure command for station 1; bad events don't.

    The command must be exactly the ROS-free dispatcher's decision for the same events
    (timetable: scheduled departure, no dwell cut; lqr: the late train's dwell is cut) and
    carry the regulator's code; NaN times, unknown trains
    and repeated events are logged and dropped while the node stays alive.
    """
    from metro_atc_msgs.msg import DepartureCommand, TrainEvent

    from metro_atc.nodes.common import QOS_EVENTS, QOS_LATCHED
    from metro_atc.nodes.conversions import to_time

    cmds = probe.subscribe(DepartureCommand, "/train_01/departure_command", QOS_LATCHED)
    pub = probe.publisher(TrainEvent, "/line/events", QOS_EVENTS)
    p = NodeProcess.installed("ats_regulator", ["-p", "scenario:=mini",
                                                "-p", f"regulator:={regulator}"],
                              ros_env, tmp_path)
    try:
        assert probe.wait_for(lambda: len(cmds) >= 1, timeout=30), p.log()
        assert cmds[-1].station_index == 0  # the first departure, published at start-up
        assert probe.wait_for(lambda: pub.get_subscription_count() > 0, timeout=30)

        def event(kind: int, station: int, t: float, seq: int,
                  train: str = "train_01") -> TrainEvent:
            ev = TrainEvent(train_id=train, kind=kind, station_index=station,
                            actual_time_s=t, sequence=seq)
            if math.isfinite(t):  # the simulator stamps an event with its time
                ev.header.stamp = to_time(t)
            return ev

        dep0 = cmds[-1].departure_time_s
        pub.publish(event(TrainEvent.KIND_DEPARTURE, 0, dep0, 1))
        pub.publish(event(TrainEvent.KIND_ARRIVAL, 1, dep0 + 140.0, 2))
        assert probe.wait_for(lambda: any(c.station_index == 1 for c in cmds), timeout=20), \
            p.log()
        c = [c for c in cmds if c.station_index == 1][-1]
        # exactly what the ROS-free dispatcher decides for the same events
        ref = _reference_dispatcher(regulator)
        ref.on_event("train_01", 0, "departure", dep0)
        want = ref.on_event("train_01", 1, "arrival", dep0 + 140.0)
        assert want is not None
        assert c.departure_time_s == pytest.approx(want.departure_s)
        assert c.target_running_time_s == pytest.approx(want.running_s)
        if regulator == "none":  # the timetable: no dwell cut
            assert math.isnan(c.dwell_limit_s)
        else:  # 140 s after the departure is late: the regulator cuts the dwell
            assert c.dwell_limit_s == pytest.approx(want.dwell_limit_s)
            assert 20.0 <= c.dwell_limit_s < 40.0
        assert c.target_running_time_s > 0.0
        assert c.regulator == {"none": 0, "lqr": 1, "elqr": 4}[regulator]
        n = len(cmds)
        pub.publish(event(TrainEvent.KIND_ARRIVAL, 2, math.nan, 3))
        assert p.wait_for_log("not finite", timeout=20), p.log()
        pub.publish(event(TrainEvent.KIND_ARRIVAL, 2, dep0 + 300.0, 3, train="train_99"))
        assert p.wait_for_log("train_99", timeout=20), p.log()
        pub.publish(event(TrainEvent.KIND_ARRIVAL, 1, dep0 + 141.0, 2))
        assert p.wait_for_log("out of order", timeout=20), p.log()
        assert len(cmds) == n and p.alive()
    finally:
        code = p.stop()
    assert code == 0
    assert "Traceback" not in p.log()
