"""The bag_recorder in process: its gate waits for every publisher, a re-sent step is once.

Two DDS participants on the test's own domain (two rclpy contexts: the recorder's and the
"graph's"), no launcher:

* the recorder gate (``RECORDER_GATE_TOPIC``, which the simulator waits on) stays shut
  while a topic of the map has no matched publisher, opens once every publisher of every
  topic has matched, and on ``match_timeout_s`` opens anyway naming what was not matched;
* a step of ``/line/fleet_state`` (and of a per-train state) published twice (the
  simulator's legitimate re-send to an ATO that matched late) is in the bag once; every
  other step is there, in order.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any, Callable, Iterator

import pytest

rclpy = pytest.importorskip("rclpy")
import rclpy.duration  # noqa: E402

SCENARIO = "mini"
TRAINS = ("train_01", "train_02")


@pytest.fixture
def graph(ros_domain: int) -> Iterator[Callable[..., Any]]:
    """``graph(kind, **params)``: a node in the recorder's context (``"recorder"``: a
    BagRecorder of ``params``) or in the graph's (``"graph"``: a plain node)."""
    from rclpy.context import Context
    from rclpy.node import Node
    from rclpy.parameter import Parameter

    from metro_atc.nodes.bag_recorder import BagRecorder

    ctx = {k: Context() for k in ("recorder", "graph")}
    for c in ctx.values():
        rclpy.init(context=c, domain_id=ros_domain)
    made: list[Any] = []

    def make(kind: str, **params: Any) -> Any:
        if kind == "recorder":
            n = BagRecorder(context=ctx[kind], parameter_overrides=[
                Parameter(k, value=v) for k, v in params.items()])
        else:
            n = Node(f"graph_{len(made)}", context=ctx[kind])
        made.append(n)
        return n

    try:
        yield make
    finally:
        for n in made:
            if hasattr(n, "bag"):
                n.bag.close()
            n.destroy_node()
        for c in ctx.values():
            rclpy.shutdown(context=c)


def _spin(node: Any, until: Callable[[], bool], timeout_s: float = 30.0) -> bool:
    """Spin ``node`` (its subscriptions and timers) until ``until()`` or the timeout."""
    from rclpy.executors import SingleThreadedExecutor

    ex = SingleThreadedExecutor(context=node.context)
    ex.add_node(node)
    end = time.monotonic() + timeout_s
    try:
        while time.monotonic() < end:
            if until():
                return True
            ex.spin_once(timeout_sec=0.02)
        return until()
    finally:
        ex.remove_node(node)


def _publishers(node: Any) -> dict[str, Any]:
    """A publisher with the map's QoS on every topic of the map (the graph's endpoints)."""
    from metro_atc.nodes.bag_recorder import graph_topics

    return {t: node.create_publisher(cls, t, qos) for t, cls, qos in graph_topics(TRAINS)}


def test_gate_opens_once_every_publisher_is_matched(graph: Any, tmp_path: Path) -> None:
    """No gate while topics lack a matched publisher; the gate once all are matched."""
    from metro_atc.nodes.sim_domain import RECORDER_GATE_TOPIC

    rec = graph("recorder", scenario=SCENARIO, output=str(tmp_path / "bag"))
    assert not _spin(rec, lambda: rec.gate is not None, 2.0)
    missing = rec.unmatched()
    assert "/line/fleet_state (0 of 1)" in missing and "/train_02/command (0 of 1)" in missing
    g = graph("graph")
    _publishers(g)
    assert _spin(rec, lambda: rec.gate is not None, 30.0), rec.unmatched()
    assert rec.unmatched() == [] and rec.unmatched_at_start == []
    # what the simulator's subscribed_by sees: the recorder subscribes to the gate topic
    assert _spin(rec, lambda: any(i.node_name == "bag_recorder" for i in
                                  g.get_subscriptions_info_by_topic(RECORDER_GATE_TOPIC)))


def test_gate_opens_on_timeout_naming_what_was_not_matched(graph: Any,
                                                           tmp_path: Path) -> None:
    """Bounded: with nothing to match and ``match_timeout_s`` 0.3 s the gate opens, the
    topics not matched named (log and the bag's custom_data)."""
    rec = graph("recorder", scenario=SCENARIO, output=str(tmp_path / "bag"),
                match_timeout_s=0.3)
    assert _spin(rec, lambda: rec.gate is not None, 10.0)
    assert "/clock (0 of 1)" in rec.unmatched_at_start
    rec.close()
    meta = (tmp_path / "bag" / "metadata.yaml").read_text()
    assert "unmatched_at_start" in meta and "/clock (0 of 1)" in meta


def test_a_resent_step_is_recorded_once(graph: Any, tmp_path: Path) -> None:
    """/line/fleet_state steps 40, 41, 41 (re-sent), 42 and /train_01/state 41 twice: the bag
    holds each step once, in order; the repeats are counted in custom_data."""
    from metro_atc_msgs.msg import FleetState, TrainState
    from rosbags.highlevel import AnyReader

    from metro_atc.nodes.common import SubscriptionPoller

    rec = graph("recorder", scenario=SCENARIO, output=str(tmp_path / "bag"))
    g = graph("graph")
    pubs = _publishers(g)
    both = [s for s in rec.subs if s.topic_name in ("/line/fleet_state", "/train_01/state")]
    assert len(both) == 2
    writers = [pubs["/line/fleet_state"], pubs["/train_01/state"]]
    # matched on both sides (the reader's match and the writer's are separate)
    assert _spin(rec, lambda: all(s.get_publisher_count() for s in both)
                 and all(p.get_subscription_count() for p in writers), 30.0)
    for step in (40, 41, 41, 42):
        m = FleetState()
        m.step = step
        pubs["/line/fleet_state"].publish(m)
    for step in (41, 41, 42):
        s = TrainState()
        s.train_id, s.step = "train_01", step
        pubs["/train_01/state"].publish(s)
    poller = SubscriptionPoller(rec.context, rec.subs)
    for p in writers:
        assert p.wait_for_all_acked(rclpy.duration.Duration(seconds=10.0))
    end = time.monotonic() + 1.0  # (acknowledged: taken within a few polls)
    while time.monotonic() < end:
        poller.poll(0.05)
    rec.close()
    steps: dict[str, list[int]] = {"/line/fleet_state": [], "/train_01/state": []}
    with AnyReader([tmp_path / "bag"]) as r:
        for con, _, raw in r.messages():
            if con.topic in steps:
                steps[con.topic].append(int(r.deserialize(raw, con.msgtype).step))
    assert steps == {"/line/fleet_state": [40, 41, 42], "/train_01/state": [41, 42]}
    assert rec.dedupe.dropped == {"/line/fleet_state": 1, "/train_01/state": 1}
    meta = (tmp_path / "bag" / "metadata.yaml").read_text()
    assert "/line/fleet_state=1" in meta
