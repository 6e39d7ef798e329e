"""The ATO's fleet lockstep on CDR bytes: the same answers, hostile bytes dropped.

A :class:`FleetLink` of two hosted trains, in the test process on its own context and
domain (nothing published reaches another test): fleet states of a recorded ROS-free run,
given as rclpy message objects to one link and as their CDR bytes to another, give the same
commands byte for byte; truncated, corrupted and foreign bytes never raise out of the
callback, are counted as rejected inputs, and leave the trains' step windows where they
were.
"""

from __future__ import annotations

import random
from typing import Any, Iterator

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

F64 = ("position_m", "speed_mps", "acceleration_mps2", "departure_time_s",
       "target_running_time_s", "supervision_speed_mps", "movement_authority_m")


@pytest.fixture
def links(ros_domain: int) -> Iterator[tuple[Any, Any, list[Any], list[Any]]]:
    """Two FleetLinks (trains 1 and 2 of taipei_blue) and the lists of what they publish."""
    from rclpy.context import Context

    from metro_atc.core.bridge import timetable_for
    from metro_atc.core.line.scenario import load_scenario
    from metro_atc.nodes.ato_controller import AtoController, FleetLink

    ctx = Context()
    rclpy.init(context=ctx, domain_id=ros_domain)
    scn = load_scenario("taipei_blue")
    tt = timetable_for(scn)
    made: list[Any] = []
    out: list[Any] = []
    sent: list[list[Any]] = []
    try:
        for _ in range(2):
            shared: dict[str, Any] = {}
            nodes = [AtoController(t, scenario=scn, timetable=tt, shared=shared, context=ctx)
                     for t in tt.train_ids[:2]]
            made += nodes
            link = FleetLink(nodes)
            box: list[Any] = []
            link.pub.publish = box.append  # type: ignore[method-assign]
            out.append(link)
            sent.append(box)
        yield out[0], out[1], sent[0], sent[1]
    finally:
        for n in made:
            n.destroy_node()
        rclpy.shutdown(context=ctx)


def _fleet_states(n: int = 900) -> list[Any]:
    """FleetStates of the first steps of a ROS-free taipei_blue run (trains 1-2 depart)."""
    from metro_atc.core.line.scenario import load_scenario
    from metro_atc.core.plant.driver import simple_driver
    from metro_atc.core.plant.line import LineSim
    from metro_atc.nodes.wire import fleet_state

    scn = load_scenario("taipei_blue")
    sim = LineSim(scn, seed=1)
    ids = list(scn.train_ids)
    out = []
    for k in range(n):
        st = sim.states()
        out.append(fleet_state.to_msg(ids, np.arange(len(ids)), st, k, float(sim.t),
                                      np.arange(len(ids)) % 4 == 0))
        sim.step(simple_driver(sim))
    return out


def test_bytes_and_messages_give_the_same_commands(links: Any) -> None:
    """Every command (stamp, step, trains, effort bits, modes) equal from bytes and objects;
    hostile bytes in between change nothing and are counted."""
    from metro_atc_msgs.msg import FleetCommand
    from rclpy.serialization import deserialize_message, serialize_message

    from metro_atc.nodes.wire import cdr, fleet_command, fleet_state

    by_msg, by_raw, sent_msg, sent_raw = links
    assert by_raw.sub.raw
    rng = random.Random(9)
    states = _fleet_states()
    rejected0 = sum(n.rejected for n in by_raw.nodes.values())
    hostile = 0
    for m in states:
        raw = bytes(serialize_message(m))
        by_msg.on_fleet_state(m)
        if rng.random() < 0.1:  # hostile bytes before the genuine message
            # rclpy's buffer runs past the message (rmw's size estimate): cut inside it
            t = m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec
            exact = fleet_state.encode(t, m.step, cdr.string_seq(list(m.train_id)), [
                np.frombuffer(a, np.uint8) if isinstance(a, bytes) else np.asarray(a)
                for a in (getattr(m, n) for n in fleet_state.NAMES)])
            assert raw.startswith(exact[:16])
            bad = rng.choice((b"", b"\x00\x01\x00\x00", raw[:rng.randrange(len(exact))],
                              b"\x00\x01\x00\x00" + b"\xff" * 40))
            by_raw.on_fleet_state(bad)
            hostile += 1
        by_raw.on_fleet_state(raw)
    assert hostile > 20
    assert sum(n.rejected for n in by_raw.nodes.values()) - rejected0 == hostile
    kinds = next(iter(by_raw.nodes.values())).rejections.summary()
    assert "cdr" in kinds
    assert len(sent_raw) == len(sent_msg) > 800
    for a, b in zip(sent_msg, sent_raw):
        assert isinstance(b, bytes)
        ma = serialize_message(a) if not isinstance(a, bytes) else a
        va = fleet_command.decode(ma)
        vb = fleet_command.decode(b)
        assert va is not None and vb is not None
        assert va[:5] == vb[:5] and va.mode.tolist() == vb.mode.tolist()
        assert [x.hex() for x in va.effort.tolist()] == [x.hex() for x in vb.effort.tolist()]
        back = deserialize_message(b, FleetCommand)  # what the simulator takes
        assert [x.hex() for x in back.effort] == [x.hex() for x in vb.effort]
    moving = sum(1 for b in sent_raw for u in fleet_command.decode(b).effort  # type: ignore
                 if u > 0.05)
    assert moving > 50  # trains were driven, not only held
