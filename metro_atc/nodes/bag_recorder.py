"""bag_recorder node: every topic of the graph into a rosbag2 MCAP directory (``run --record``).

rosbag2's recorder is not installable from PyPI; this node does its job for the metro_atc
graph with rclpy and the ``rosbags`` writer (:mod:`metro_atc.bag`):

* it subscribes at start-up to every topic of the graph's topic map (:func:`graph_topics`,
  the scenario's trains) with the QoS of the topic's publishers; every
  ``discovery_period_s`` it also subscribes to any other topic that appears, with a QoS
  adapted from its publishers (reliable / transient-local only if every publisher is);
* **every message from the first step**: the simulator waits for this node
  (``wait_for_subscribers``) until it subscribes to each topic the simulator publishes,
  the recorder gate (:data:`~metro_atc.nodes.sim_domain.RECORDER_GATE_TOPIC`) included,
  and this node subscribes to the gate only once each of its subscriptions of the topic map
  has matched every publisher of its topic (:meth:`BagRecorder.unmatched`: at least one per
  topic, as many as the graph lists, and on ``/line/fleet_command`` one per ATO process)
  and stayed so for :data:`GATE_SETTLE_S`.  A subscription the simulator sees in the graph
  is not yet a matched one: a volatile reader takes only what is written after it matched
  the writer itself, and a loaded machine lost the first 81 steps of states and 110 of
  commands that way.  The wait is bounded (``match_timeout_s``): then the gate opens with
  an error naming the topics not matched (also in the bag's ``custom_data``);
* **exactly once**: a lockstep message repeated by a legitimate re-send (the simulator
  publishes a step's fleet state again to an ATO that matched late or did not answer,
  ``FLEET_RESEND_S``; an ATO answers it again) is recorded once: on ``/clock``,
  ``/line/fleet_state``, ``/line/fleet_command`` and the per-train ``state`` and ``command``
  a message whose (topic, step) (``/clock``: its time; the fleet command: its step and
  trains) was recorded already is dropped (:class:`StepDedupe`) and counted (log line and
  ``custom_data``);
* subscriptions are raw (serialized CDR bytes, no deserialization) and are served by a
  direct wait set (:class:`~metro_atc.nodes.common.SubscriptionPoller`);
* at shutdown (SIGINT/SIGTERM from the launcher after the simulator ended) it drains what
  is queued, finishes the MCAP file and writes ``metadata.yaml``.
"""

from __future__ import annotations

import importlib
import time
from pathlib import Path
from typing import Any, Callable, Sequence

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from metro_atc_msgs.msg import (BrakeDiagnosis, DepartureCommand, DispatcherCommand,
                                FleetBrakeSensorData,
                                FleetCommand, FleetState, LineStatus, SpeedProfile,
                                TractionCommand, TrainEvent, TrainState)
from rcl_interfaces.msg import Log, ParameterEvent
from rclpy.clock import Clock, ClockType
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import (DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy)
from rclpy.subscription import Subscription
from rosgraph_msgs.msg import Clock as ClockMsg

from metro_atc.bag import BagWriter, Qos, qos_profile
from metro_atc.core.line.scenario import ScenarioError
from metro_atc.core.service.dayrun import load_run_scenario
from metro_atc.nodes.wire import cdr
from metro_atc.nodes.common import (OK, FLEET_SENSOR_TOPIC, QOS_CLOCK, QOS_DIAGNOSTICS,
                                    QOS_EVENTS, QOS_FLEET_SENSOR, QOS_LATCHED,
                                    QOS_RELIABLE, WARN, NodeConfigError,
                                    RuntimeParams, SubscriptionPoller, diag_status, run_nodes,
                                    static, stop_requested)
from metro_atc.nodes.dispatch_msgs import APPLIED_TOPIC
from metro_atc.nodes.sim_domain import RECORDER_GATE_TOPIC

QOS_LOG = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000,
                     reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.VOLATILE)
"""/rosout and /parameter_events as read here (rcl publishes them reliable, depth 1000)."""


READER_DEPTH = 10000
"""Reader queue of every recorded topic [messages]."""
GATE_POLL_S = 0.1
"""Wall period of the look at the subscriptions' matches before the gate opens [s]."""
GATE_SETTLE_S = 0.5
"""Wall time every subscription must have stayed matched before the gate opens [s]: the
match seen here is the reader's; the writer's side of it (the publisher's process taking
this reader in) is not observable from here and completes within the same discovery
exchange."""


def _clock_key(r: cdr.Reader) -> Any:
    """``/clock``: its time."""
    return r.stamp()


def _step_key(r: cdr.Reader) -> Any:
    """``FleetState``: its step (after the header)."""
    r.stamp()
    r.string_bytes()
    return r.u64()


def _fleet_command_key(r: cdr.Reader) -> Any:
    """``FleetCommand``: its step and trains (one message per ATO process and step)."""
    step = _step_key(r)
    return step, r.strings_raw()


def _train_step_key(r: cdr.Reader) -> Any:
    """``TrainState`` / ``TractionCommand``: its step (after the header and train id)."""
    r.stamp()
    r.string_bytes()
    r.string_bytes()
    return r.u64()


class StepDedupe:
    """Drops a lockstep message recorded already (see the module docstring).

    ``first(topic, data)`` is False for a message whose key on ``topic`` was seen; a message
    that does not decode is recorded as it is.  The keys of the last :data:`WINDOW`
    messages per topic are kept (a re-send follows its original within a few steps).
    """

    WINDOW = 4096
    """Keys kept per topic (the oldest half dropped beyond twice this)."""

    def __init__(self, train_ids: Sequence[str]) -> None:
        """The keyed topics of a run of ``train_ids``."""
        self.keys: dict[str, Callable[[cdr.Reader], Any]] = {
            "/clock": _clock_key, "/line/fleet_state": _step_key,
            "/line/fleet_command": _fleet_command_key}
        for t in train_ids:
            self.keys[f"/{t}/state"] = _train_step_key
            self.keys[f"/{t}/command"] = _train_step_key
        self.seen: dict[str, dict[Any, None]] = {}
        self.dropped: dict[str, int] = {}
        """Messages dropped per topic."""

    def first(self, topic: str, data: bytes) -> bool:
        """True when ``data`` is not a repeat of a message recorded on ``topic``."""
        f = self.keys.get(topic)
        if f is None:
            return True
        r = cdr.Reader(data)
        key = f(r)
        if not r.ok:
            return True
        seen = self.seen.setdefault(topic, {})
        if key in seen:
            self.dropped[topic] = self.dropped.get(topic, 0) + 1
            return False
        seen[key] = None
        if len(seen) > 2 * self.WINDOW:
            for k in list(seen)[:self.WINDOW]:
                del seen[k]
        return True


def graph_topics(train_ids: Sequence[str]) -> list[tuple[str, Any, QoSProfile]]:
    """The topic map of a run: (topic, message class, publishers' QoS) (README topic map)."""
    out: list[tuple[str, Any, QoSProfile]] = [
        ("/clock", ClockMsg, QOS_CLOCK), ("/line/events", TrainEvent, QOS_EVENTS),
        ("/line/status", LineStatus, QOS_LATCHED),
        ("/diagnostics", DiagnosticArray, QOS_DIAGNOSTICS),
        ("/rosout", Log, QOS_LOG), ("/parameter_events", ParameterEvent, QOS_LOG),
        ("/line/fleet_state", FleetState, QOS_RELIABLE),
        ("/line/fleet_command", FleetCommand, QOS_RELIABLE),
        # the dispatcher's applied commands (what run --replay-commands reads back)
        (APPLIED_TOPIC, DispatcherCommand, QOS_EVENTS),
        # the brake sensor samples of all trains (the per-train /<train>/brake_sensors are
        # published only while read: recording them would make the simulator publish them)
        (FLEET_SENSOR_TOPIC, FleetBrakeSensorData, QOS_FLEET_SENSOR)]
    for t in train_ids:
        out += [(f"/{t}/state", TrainState, QOS_RELIABLE),
                (f"/{t}/command", TractionCommand, QOS_RELIABLE),
                (f"/{t}/departure_command", DepartureCommand, QOS_LATCHED),
                (f"/{t}/speed_profile", SpeedProfile, QOS_LATCHED),
                (f"/{t}/brake_diagnosis", BrakeDiagnosis, QOS_LATCHED)]
    return out


def type_name(cls: Any) -> str:
    """``pkg/msg/Name`` of a generated message class."""
    return f"{cls.__module__.split('.')[0]}/msg/{cls.__name__}"


def bag_qos(q: QoSProfile) -> Qos:
    """An rclpy QoS profile as the bag stores it."""
    return qos_profile(history=q.history.name, depth=int(q.depth),
                       reliability=q.reliability.name, durability=q.durability.name,
                       liveliness=q.liveliness.name)


def find_msg(package: str, name: str) -> str:
    """Text of ``share/<package>/msg/<name>.msg`` (ament index)."""
    from ament_index_python.packages import get_package_share_directory
    return (Path(get_package_share_directory(package)) / "msg" / f"{name}.msg").read_text()


class BagRecorder(Node):
    """The recorder node (see module docstring)."""

    def __init__(self, **kwargs: Any) -> None:
        """Open the bag and subscribe to the graph's topic map."""
        super().__init__("bag_recorder", **kwargs)
        scenario = static(self, "scenario", "taipei_blue",
                          "embedded scenario name or path to a scenario YAML (its trains)")
        output = static(self, "output", "", "bag directory to create (must not exist)")
        self.discovery_period_s = static(self, "discovery_period_s", 0.5,
                                         "wall time between topic discovery passes [s]",
                                         0.05, 60.0)
        self.match_timeout_s = static(self, "match_timeout_s", 60.0,
                                      "longest wall time the recorder gate stays shut while a "
                                      "subscription has not matched every publisher [s]",
                                      0.0, 3600.0)
        if not output:
            raise NodeConfigError("parameter output (bag directory) is empty")
        try:
            from metro_atc.launcher import scenario_train_ids
            ids = scenario_train_ids(load_run_scenario(scenario))
        except ScenarioError as exc:
            raise NodeConfigError(str(exc)) from None
        if Path(output).exists():
            raise NodeConfigError(f"bag directory {output} already exists")
        self.bag = BagWriter(Path(output), find_msg)
        try:
            self.bag.open()
        except OSError as exc:
            raise NodeConfigError(f"cannot create bag {output}: {exc.strerror}") from None
        self.subs: list[Subscription] = []
        self.by_topic: dict[str, Subscription] = {}
        self.ignored: set[str] = set()
        self.bytes = 0
        self.ids = list(ids)
        self.dedupe = StepDedupe(ids)
        self.rt = RuntimeParams(self, self.health)
        self.graph = [topic for topic, _, _ in graph_topics(ids)]
        for topic, cls, qos in graph_topics(ids):
            self._record(topic, cls, qos)
        # not discovered either: the fleet topic records the same samples; the gate is
        # subscribed to (not recorded) once every publisher is matched
        self.ignored |= {f"/{t}/brake_sensors" for t in ids} | {RECORDER_GATE_TOPIC}
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.create_timer(self.discovery_period_s, self.discover, clock=steady)
        self.gate: Subscription | None = None
        self.unmatched_at_start: list[str] = []
        """Topics still not matched when the gate opened on ``match_timeout_s``."""
        self._t0 = time.monotonic()
        self._matched_since = -1.0
        self.gate_timer = self.create_timer(GATE_POLL_S, self.open_gate_when_matched,
                                            clock=steady)
        self.get_logger().info(f"recording {len(self.subs)} topics to {output}")

    def _record(self, topic: str, cls: Any, qos: QoSProfile, offered: list[Qos] | None = None,
                type_hash: str = "") -> None:
        first = self.dedupe.first

        def cb(data: bytes, topic: str = topic) -> None:
            if first(topic, data):
                self.bag.write(topic, data, time.time_ns())
                self.bytes += len(data)

        self.bag.add_topic(topic, type_name(cls), offered or [bag_qos(qos)], type_hash)
        # the reader queue is deeper than the publishers' (QoS-compatible): a burst that
        # arrives while the bag compresses a chunk must not overwrite unread samples
        deep = QoSProfile(history=HistoryPolicy.KEEP_LAST,
                          depth=max(int(qos.depth), READER_DEPTH),
                          reliability=qos.reliability, durability=qos.durability)
        sub = self.create_subscription(cls, topic, cb, deep, raw=True)
        self.subs.append(sub)
        self.by_topic[topic] = sub

    def unmatched(self) -> list[str]:
        """Topics of the map whose subscription has not matched every publisher yet.

        Each as ``topic (matched of needed)``: needed is at least one (every topic of the
        map has a publisher in a run), as many as the graph lists, and on
        ``/line/fleet_command`` one per process publishing a ``/<train>/command`` (each ATO
        process has its fleet link; the graph may list its command topics first).
        """
        out = []
        ato_procs: set[tuple[int, ...]] = set()
        for t in self.ids:
            for info in self.get_publishers_info_by_topic(f"/{t}/command"):
                ato_procs.add(tuple(info.endpoint_gid[:12]))  # the participant's GUID prefix
        for topic in self.graph:
            need = max(1, len(self.get_publishers_info_by_topic(topic)))
            if topic == "/line/fleet_command":
                need = max(need, len(ato_procs))
            got = self.by_topic[topic].get_publisher_count()
            if got < need:
                out.append(f"{topic} ({got} of {need})")
        return out

    def open_gate_when_matched(self) -> None:
        """Subscribe to the recorder gate once every subscription matched (or on timeout)."""
        if self.gate is not None:
            return
        now = time.monotonic()
        missing = self.unmatched()
        if missing:
            self._matched_since = -1.0
            if now - self._t0 < self.match_timeout_s:
                return
            self.unmatched_at_start = missing
            self.get_logger().error(
                f"{len(missing)} topics not matched after {self.match_timeout_s:g} s: "
                f"{', '.join(missing[:10])}: the recording starts anyway, without what "
                "is published on them before they match")
        else:
            if self._matched_since < 0.0:
                self._matched_since = now
            if now - self._matched_since < GATE_SETTLE_S:
                return
            self.get_logger().info(f"every publisher of the {len(self.graph)} topics matched "
                                   f"after {now - self._t0:.2f} s: gate open")
        self.gate_timer.cancel()
        self.gate = self.create_subscription(DiagnosticStatus, RECORDER_GATE_TOPIC,
                                             lambda _msg: None, QOS_LATCHED)

    def discover(self) -> None:
        """Subscribe to topics that appeared since the last pass (QoS from the publishers)."""
        for topic, types in self.get_topic_names_and_types():
            if topic in self.bag.topics or topic in self.ignored or len(types) != 1:
                continue
            pubs = self.get_publishers_info_by_topic(topic)
            if not pubs:
                continue
            pkg, _, name = types[0].split("/")
            try:
                cls = getattr(importlib.import_module(f"{pkg}.msg"), name)
            except (ImportError, AttributeError):
                self.get_logger().warning(f"not recording {topic}: type {types[0]} unknown "
                                          f"here")
                self.ignored.add(topic)
                continue
            qs = [p.qos_profile for p in pubs]
            reliable = all(q.reliability == ReliabilityPolicy.RELIABLE for q in qs)
            latched = all(q.durability == DurabilityPolicy.TRANSIENT_LOCAL for q in qs)
            qos = QoSProfile(
                history=HistoryPolicy.KEEP_LAST, depth=max(100, max(q.depth for q in qs)),
                reliability=ReliabilityPolicy.RELIABLE if reliable
                else ReliabilityPolicy.BEST_EFFORT,
                durability=DurabilityPolicy.TRANSIENT_LOCAL if latched
                else DurabilityPolicy.VOLATILE)
            h = str(getattr(pubs[0], "topic_type_hash", "") or "")
            self._record(topic, cls, qos, [bag_qos(q) for q in qs],
                         h if h.startswith("RIHS") else "")
            self.get_logger().info(f"recording {topic} ({types[0]})")

    def health(self) -> list[DiagnosticStatus]:
        """/diagnostics: topics, messages and bytes recorded."""
        n = sum(t.count for t in self.bag.topics.values())
        level, msg = (OK, "recording") if self.subs else (WARN, "no topic")
        return [diag_status("bag_recorder: bag", str(self.bag.path), level, msg, {
            "topics": len(self.subs), "messages": n, "bytes": self.bytes})]

    def drain(self) -> int:
        """Take every queued message (after the graph stopped); return how many."""
        poller = SubscriptionPoller(self.context, self.subs)
        total = 0
        for _ in range(50):
            n = poller.poll(0.02)
            total += n
            if n == 0:
                break
        return total

    def close(self) -> None:
        """Drain the queues, finish the MCAP file, write metadata.yaml."""
        if self.context.ok():
            self.drain()
        dropped = self.dedupe.dropped
        self.bag.custom_data["duplicates_dropped"] = ",".join(
            f"{k}={v}" for k, v in sorted(dropped.items()))
        self.bag.custom_data["unmatched_at_start"] = ",".join(self.unmatched_at_start)
        self.bag.close()
        n = sum(t.count for t in self.bag.topics.values())
        text = f"bag {self.bag.path}: {n} messages on {len(self.bag.topics)} topics"
        if dropped:
            text += (f"; {sum(dropped.values())} repeated lockstep messages (re-sends) "
                     "recorded once: "
                     + ", ".join(f"{k} {v}" for k, v in sorted(dropped.items())))
        if self.context.ok():
            self.get_logger().info(text)


def main(args: Sequence[str] | None = None) -> int:
    """Entry point of the ``bag_recorder`` executable."""
    def loop(executor: SingleThreadedExecutor, nodes: Sequence[Node]) -> None:
        node = nodes[0]
        assert isinstance(node, BagRecorder)
        ctx = node.context
        last_slow = 0.0
        while ctx.ok() and not stop_requested():
            poller = SubscriptionPoller(ctx, node.subs)
            n_subs = len(node.subs)
            while ctx.ok() and not stop_requested() and len(node.subs) == n_subs:
                poller.poll(0.05)
                now = time.monotonic()
                if now - last_slow >= 0.05:
                    last_slow = now
                    executor.spin_once(timeout_sec=0.0)

    return run_nodes(lambda: [BagRecorder()], loop, args)


if __name__ == "__main__":
    raise SystemExit(main())
