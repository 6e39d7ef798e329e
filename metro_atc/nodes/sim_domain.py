"""The line_simulator's place on its ROS domain: alone on it, and its last samples delivered.

Two graphs on one ROS domain answer each other's lockstep: a simulator that finds another
``line_simulator`` publishing the fleet state refuses to run (:func:`check_alone`), says so
on :data:`REFUSED_TOPIC` and lingers until the other one refused too, so both runs refuse;
one that learns later that another refused beside it stops too (:func:`check_not_refused`).
At its end the simulator waits for its readers' acknowledgements (:func:`linger`); a
recorder named in ``wait_for_subscribers`` is waited for before step 0
(:func:`subscribed_by`) and its acknowledgements during the run (:func:`wait_acked`).

Functions of the node's public graph API only (names, publishers, topic infos).
"""

from __future__ import annotations

import time
from typing import Any, Sequence

from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.publisher import Publisher

from metro_atc.nodes.common import QOS_LATCHED, NodeConfigError

ALONE_CHECK_S = 10.0
"""Wall seconds after its first start in which the simulator looks for another
``line_simulator`` publishing ``/line/fleet_state`` on its ROS domain (two graphs on one
domain answer each other's lockstep: refused, not run).  A respawn skips the look: the killed
process's endpoints stay in the discovery data until their lease expires."""
ALONE_PERSIST_S = 20.0
"""After :data:`ALONE_CHECK_S`: another ``line_simulator`` publishing the fleet state seen
without a break for this many wall seconds is a second graph too (refused as by
:func:`check_alone`).  Longer than the DDS lease (10 s), which a killed predecessor's
endpoints outlive it by at most; discovery across hosts under load can take longer than the
first look (seen: two split graphs on one domain both ran, one to exit 0)."""
ALONE_LINGER_S = 45.0
"""Wall seconds at most that a simulator which found another one stays on the domain before
it exits: it leaves as soon as every other simulator it sees has refused too (or left).
Discovery is not symmetric in time: across hosts on a loaded machine the other simulator
saw this one's refusal only after more than 15 s (it then ran to the end, exit 0)."""
REFUSED_TOPIC = "/line/simulator_refused"
"""A refusing simulator publishes one DiagnosticStatus (ERROR, the refusal) here, latched: the
other simulator of the domain sees that it was seen (the refusal handshake of
:func:`check_alone`)."""
REFUSED_POLL_S = 0.1
"""Wall seconds between two looks at the graph while a refusing simulator lingers."""
RECORDER_GATE_TOPIC = "/line/recorder_gate"
"""A topic the simulator publishes nothing on, only while ``wait_for_subscribers`` names a
recorder: the bag_recorder subscribes to it only once each of its subscriptions has matched
every publisher it must record (``metro_atc.nodes.bag_recorder``), so the simulator's wait
for the recorder's subscriptions (:func:`subscribed_by`) also waits for that.  A recorder's
subscription seen in the graph is not a matched one: a volatile reader takes only what is
written after it has matched the writer itself, and the steps published before were lost
(a bag held a train's commands from step 110, its states from its first step, 81)."""
LINGER_S = 0.3
"""Most wall time [s] the simulator waits at its end for its last samples to be delivered."""


def other_simulators(node: Node, topic: str) -> int:
    """Publishers of ``topic`` by a node of ``node``'s name other than ``node`` itself."""
    same = [i for i in node.get_publishers_info_by_topic(topic)
            if i.node_name == node.get_name() and i.node_namespace == node.get_namespace()]
    own = 1 if any(p.topic_name == topic for p in node.publishers) else 0
    return max(0, len(same) - own)


def check_alone(node: Node, fleet_topic: str) -> None:
    """Raise :class:`NodeConfigError` when another simulator shares ``node``'s ROS domain.

    Another ``line_simulator`` publishing the fleet state (``fleet_topic``) is a second
    graph: its ATOs would answer this lockstep.  Discovery is not symmetric in time (one
    simulator may see the other seconds before it is seen), so a refusing simulator says so
    on :data:`REFUSED_TOPIC` and stays on the domain until every other simulator it sees
    has refused too or left (at most :data:`ALONE_LINGER_S` of wall time): both runs refuse.
    """
    if other_simulators(node, fleet_topic) == 0:
        return
    reason = (f"another {node.get_name()} publishes {fleet_topic} on "
              f"ROS_DOMAIN_ID={node.context.get_domain_id()}: a second graph on this "
              "domain; give each run its own ROS_DOMAIN_ID")
    node.get_logger().error(reason)
    refused = node.create_publisher(DiagnosticStatus, REFUSED_TOPIC, QOS_LATCHED)
    refused.publish(DiagnosticStatus(level=DiagnosticStatus.ERROR, name=node.get_name(),
                                     message=reason))
    deadline = time.monotonic() + ALONE_LINGER_S
    while time.monotonic() < deadline:
        others = other_simulators(node, fleet_topic)
        if others == 0 or other_simulators(node, REFUSED_TOPIC) >= others:
            break
        time.sleep(REFUSED_POLL_S)
    raise NodeConfigError(reason)


def check_not_refused(node: Node, fleet_topic: str) -> None:
    """Raise :class:`NodeConfigError` when another simulator refused to run beside ``node``.

    Checked once a wall second after :data:`ALONE_CHECK_S`: a loaded machine may let
    the other simulator see this one only after this one's own look ended (seen once
    in CI: the other refused, this one ran to the end).
    """
    if other_simulators(node, REFUSED_TOPIC) == 0:
        return
    raise NodeConfigError(
        f"another {node.get_name()} on ROS_DOMAIN_ID={node.context.get_domain_id()} "
        f"refused to run beside this one (it found this one publishing "
        f"{fleet_topic}): a second graph on this domain; give each run "
        "its own ROS_DOMAIN_ID")


def linger(node: Node, limit_s: float) -> bool:
    """Wait until every matched reader acknowledged the node's samples; True if all did.

    The last events and statuses reach their subscribers before the process exits (a
    reliable writer destroyed earlier takes its unacknowledged samples with it); at most
    ``limit_s`` [s] of wall time (a reader that stopped acknowledging). Best-effort writers
    have nothing to wait for. This used to be a fixed 0.3 s of executor spinning.
    """
    return wait_acked(list(node.publishers), float(limit_s), None)


def subscribed_by(node: Node, pubs: Sequence[Publisher], names: Sequence[str]) -> bool:
    """Each node of ``names`` subscribes to the topic of every publisher of ``pubs``."""
    for p in pubs:
        seen = {i.node_name for i in node.get_subscriptions_info_by_topic(p.topic_name)}
        if not all(w in seen for w in names):
            return False
    return True


def wait_acked(pubs: Sequence[Publisher], timeout_s: float, logger: Any) -> bool:
    """Wait until every reliable reader of ``pubs`` acknowledged what was published.

    At most ``timeout_s`` [s] of wall time for all; the first publisher not acknowledged
    in time is logged (``logger``, if given) and False returned.
    """
    end = time.monotonic() + timeout_s
    for p in pubs:
        rest = end - time.monotonic()
        if rest <= 0.0 or not p.wait_for_all_acked(Duration(seconds=rest)):
            if logger is not None:
                logger.warning(f"{p.topic_name}: not every reader acknowledged "
                               f"the last messages within {timeout_s:g} s")
            return False
    return True
