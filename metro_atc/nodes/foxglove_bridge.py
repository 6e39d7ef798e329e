"""foxglove_bridge node: the graph's topics over Foxglove's WebSocket protocol (``--foxglove``).

A viewer (Foxglove, Lichtblick) connects to ``ws://127.0.0.1:PORT`` and sees:

* every topic of the graph's topic map (:func:`~metro_atc.nodes.bag_recorder.graph_topics`,
  the scenario's trains), each a channel with message encoding ``cdr`` and its schema in the
  ``ros2msg`` encoding (the type's ``.msg`` text and its nested types', from
  ``msg_defs/msg`` and the ROS 2 Jazzy types: :class:`metro_atc.bag.TypeDefs`, the text a
  bag holds); the messages are the serialized CDR bytes as received (no deserialization);
* three derived topics (:mod:`metro_atc.nodes.wire.line_view`): ``/line/trains``
  (``sensor_msgs/JointState``: per train of the scenario, in a fixed order, chainage [m],
  speed [m/s] and mode, from a ``/line/fleet_state``; to viewers at most one message per
  ``view_period_s`` of wall time), ``/line/layout``
  (``metro_atc_msgs/LineLayout``: stations, speed limits, gradients; latched) and
  ``/line/event_log`` (``rcl_interfaces/Log``: one line per arrival or departure of
  ``/line/events``).  They are published on ROS as well (``/line/layout`` transient local,
  the others while a ROS reader, a recorder, subscribes), so a bag of a run with
  ``--record --foxglove`` holds them.

Cost to the lockstep: a ROS topic is subscribed to only while a viewer subscribes to its
channel (``/line/fleet_state`` also while a reader of ``/line/trains`` exists), and the
high-rate volatile topics with a best-effort reader (no acknowledgement the simulator's
writer waits for; a viewer that falls behind loses messages, the lockstep does not wait).
The lockstep steps far faster than a viewer draws (about 1300 steps per second of wall
time on taipei_blue), so ``/line/trains`` goes to viewers at the viewer's rate, not the
lockstep's: at most one message per ``view_period_s`` (default 0.1 s of wall time, 10 Hz),
the latest step the bridge has read.  While only viewers want it, ``/line/fleet_state`` is
read with a best-effort depth-1 reader taken once per view period (every other step is
never handed to Python here); while a ROS reader of ``/line/trains`` exists (a recorder:
``--record --foxglove``), every fleet state read is converted and published on ROS, and
viewers still get one per view period.  Every step stays in ``/line/fleet_state`` (the
recorder reads it itself, reliably).
Latched topics keep their last message here and send it again to a viewer that subscribes.

The server binds ``host`` (default 127.0.0.1, loopback only); another address is taken only
when given explicitly (``run --foxglove-host``).
"""

from __future__ import annotations

import collections
import time
from typing import Any, Sequence

from foxglove.websocket import ServerListener
from metro_atc_msgs.msg import LineLayout, TrainEvent
from rcl_interfaces.msg import Log
from rclpy.clock import Clock, ClockType
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message, serialize_message
from rclpy.subscription import Subscription
from sensor_msgs.msg import JointState

from metro_atc.bag import TypeDefs
from metro_atc.core.line.scenario import ScenarioError
from metro_atc.core.service.dayrun import load_run_scenario
from metro_atc.nodes.bag_recorder import find_msg, graph_topics, type_name
from metro_atc.nodes.common import (OK, QOS_EVENTS, QOS_LATCHED, QOS_RELIABLE, WARN,
                                    NodeConfigError,
                                    RuntimeParams, SubscriptionPoller, diag_status, run_nodes,
                                    static, stop_requested)
from metro_atc.nodes.wire import fleet_state, line_view

DEFAULT_HOST = "127.0.0.1"
"""The address the server binds unless told otherwise: loopback only."""
DEFAULT_PORT = 8765
"""The Foxglove WebSocket port viewers try first."""
FLEET_TOPIC = "/line/fleet_state"
"""The lockstep state /line/trains is derived from."""
EVENTS_TOPIC = "/line/events"
"""The arrivals and departures /line/event_log is derived from."""
READER_DEPTH = 100
"""Reader queue of a forwarded topic [messages]."""
LATEST_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                        reliability=ReliabilityPolicy.BEST_EFFORT,
                        durability=DurabilityPolicy.VOLATILE)
"""Reader of a topic only viewers want at the view rate: the latest message, best effort."""
SAMPLED = frozenset({FLEET_TOPIC})
"""Source topics read as their latest message once per view period while only viewers of
the topic derived from them want them (the event log's ``/line/events``: every message)."""
SUBSCRIBE_PERIOD_S = 0.2
"""Wall period of the look at which channels viewers subscribe to [s]."""


def reader_qos(qos: QoSProfile) -> QoSProfile:
    """The bridge's reader of a topic published with ``qos``.

    Latched (transient local) topics: reliable, as published (a late reader gets the last
    message).  Volatile ones: best effort (the publisher never waits for the bridge).
    """
    latched = qos.durability == DurabilityPolicy.TRANSIENT_LOCAL
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=max(int(qos.depth), READER_DEPTH),
                      reliability=qos.reliability if latched
                      else ReliabilityPolicy.BEST_EFFORT, durability=qos.durability)


class _Listener(ServerListener):
    """Foxglove server callbacks (server threads): note each subscription for the node."""

    def __init__(self) -> None:
        """An empty queue of subscribed channel ids."""
        self.subscribed: collections.deque[int] = collections.deque()

    def on_subscribe(self, client: Any, channel: Any) -> None:
        """A viewer subscribed to a channel: its latched message is sent again."""
        self.subscribed.append(int(channel.id))

    def on_unsubscribe(self, client: Any, channel: Any) -> None:
        """Nothing to do: :meth:`FoxgloveBridge.update_subscriptions` sees it."""


def take_latest(sub: Subscription) -> Any:
    """The newest message waiting in ``sub`` (None: none); the older ones are dropped."""
    handle = sub.handle
    last = None
    while True:
        with handle:
            info = handle.take_message(sub.msg_type, sub.raw)
        if info is None:
            return last
        last = info[0]


class FoxgloveBridge(Node):
    """The bridge node (see module docstring)."""

    def __init__(self, **kwargs: Any) -> None:
        """Start the WebSocket server and advertise the graph's channels."""
        super().__init__("foxglove_bridge", **kwargs)
        import foxglove
        from foxglove import Channel, Schema

        scenario = static(self, "scenario", "taipei_blue",
                          "embedded scenario name or path to a scenario YAML (its trains)")
        host = static(self, "host", DEFAULT_HOST,
                      "address the WebSocket server binds (default loopback only)")
        port = static(self, "port", DEFAULT_PORT,
                      "TCP port of the WebSocket server (0: any free port)", 0, 65535)
        self.view_period_s = float(static(
            self, "view_period_s", line_view.VIEW_PERIOD_S,
            "wall period of /line/trains to viewers [s]: at most one message (the latest "
            "step read) per period; ROS readers of /line/trains get every step read",
            0.01, 60.0))
        try:
            scn = load_run_scenario(scenario)
        except ScenarioError as exc:
            raise NodeConfigError(str(exc)) from None
        order = line_view.train_order(scn)
        self.trains = line_view.TrainsBuilder(order)
        self.types = TypeDefs(find_msg)
        topics = graph_topics(order)
        self.ros: dict[str, tuple[Any, QoSProfile]] = {t: (c, q) for t, c, q in topics}
        self.latched = {t for t, _, q in topics if q.durability ==
                        DurabilityPolicy.TRANSIENT_LOCAL} | {line_view.LAYOUT_TOPIC}
        self.channels: dict[str, Any] = {}
        self.fg = foxglove.Context()
        """The SDK context of this node's channels and server (not the process-wide one)."""
        for topic, cls in [(t, c) for t, c, _ in topics] + [
                (line_view.TRAINS_TOPIC, JointState), (line_view.LAYOUT_TOPIC, LineLayout),
                (line_view.EVENT_LOG_TOPIC, Log)]:
            name = type_name(cls)
            schema = Schema(name=name, encoding="ros2msg",
                            data=self.types.msgdef(name).encode("utf-8"))
            self.channels[topic] = Channel(topic, schema=schema, message_encoding="cdr",
                                           context=self.fg)
        self.by_id = {ch.id(): t for t, ch in self.channels.items()}
        self.last: dict[str, bytes] = {}
        """The last message of each latched topic (sent again to a new subscriber)."""
        self.count: dict[str, int] = collections.Counter()
        self.subs: dict[str, Subscription] = {}
        self.sampled: set[str] = set()
        """Topics of :attr:`subs` read as their latest message once per view period (a
        depth-1 reader outside the wait set), not message by message."""
        self.next_take = 0.0
        """Wall time (monotonic) of the next take of the sampled topics [s]."""
        self.next_view = 0.0
        """Wall time (monotonic) from which /line/trains goes to viewers again [s]."""
        self.trains_pub = self.create_publisher(JointState, line_view.TRAINS_TOPIC,
                                                QOS_RELIABLE)
        self.layout_pub = self.create_publisher(LineLayout, line_view.LAYOUT_TOPIC,
                                                QOS_LATCHED)
        self.event_log_pub = self.create_publisher(Log, line_view.EVENT_LOG_TOPIC, QOS_EVENTS)
        self.derived = {FLEET_TOPIC: (line_view.TRAINS_TOPIC, self.trains_pub),
                        EVENTS_TOPIC: (line_view.EVENT_LOG_TOPIC, self.event_log_pub)}
        """Source topic -> (derived topic, its ROS publisher)."""
        layout = line_view.encode_layout(line_view.layout_values(scn))
        self.last[line_view.LAYOUT_TOPIC] = layout
        self.layout_pub.publish(layout)
        self.listener = _Listener()
        try:
            self.server: Any = foxglove.start_server(
                name="metro_atc", host=host, port=int(port), server_listener=self.listener,
                context=self.fg)
        except Exception as exc:  # the SDK raises its own error types (bind, address)
            raise NodeConfigError(f"cannot serve on {host}:{port}: {exc}") from None
        self.host = host
        self.port = int(self.server.port)
        self.rt = RuntimeParams(self, self.health)
        self.changed = True
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.create_timer(SUBSCRIBE_PERIOD_S, self.update_subscriptions, clock=steady)
        self.get_logger().info(f"Foxglove WebSocket server on ws://{host}:{self.port} "
                               f"({len(self.channels)} channels)")

    # ------------------------------------------------------------ forwarding
    def forward(self, topic: str, data: bytes, now: float | None = None) -> None:
        """One message of ``topic`` to its channel (and /line/trains from a fleet state).

        ``now``: the wall time (monotonic) [s] (None: read here); /line/trains goes to
        viewers only when the view period since the last one has passed.
        """
        if topic in self.latched:
            self.last[topic] = data
        self.count[topic] += 1
        ch = self.channels[topic]
        if ch.has_sinks():
            ch.log(data)
        if topic not in self.derived:
            return
        name, pub = self.derived[topic]
        to_ros = pub.get_subscription_count() > 0
        view = self.channels[name]
        to_view = view.has_sinks()
        if to_view and name == line_view.TRAINS_TOPIC:
            now = time.monotonic() if now is None else now
            to_view = now >= self.next_view
            if to_view:
                self.next_view = now + self.view_period_s
                self.count["trains_viewed"] += 1
        if not (to_ros or to_view):
            return
        out = self.derive(topic, data)
        if out is None:
            self.count["rejected"] += 1
            return
        self.count[name] += 1
        if to_view:
            view.log(out)
        if to_ros:
            pub.publish(out)

    def take_sampled(self, now: float) -> None:
        """Once per view period: the latest message of each sampled topic, forwarded."""
        if not self.sampled or now < self.next_take:
            return
        self.next_take = now + self.view_period_s
        for topic in sorted(self.sampled):
            data = take_latest(self.subs[topic])
            if data is not None:
                self.forward(topic, data, now)

    def poll_timeout(self, now: float, longest_s: float) -> float:
        """How long the loop may wait for messages before the next sampled take [s]."""
        if not self.sampled:
            return longest_s
        return min(longest_s, max(self.next_take - now, 0.0))

    def derive(self, topic: str, data: bytes) -> bytes | None:
        """The derived message of one message of a source topic (None: it does not read)."""
        if topic == FLEET_TOPIC:
            view = fleet_state.decode(data)
            return None if view is None else self.trains.build(view)
        try:
            ev = deserialize_message(data, TrainEvent)
        except Exception:  # rclpy raises its own error types for bytes that do not read
            return None
        level, text = line_view.event_log_line(
            int(ev.kind), ev.train_id, ev.station_name, float(ev.actual_time_s),
            float(ev.scheduled_time_s), float(ev.dwell_s), TrainEvent.KIND_ARRIVAL)
        out = Log(level=level, name=ev.train_id, msg=text, file="", function="", line=0)
        out.stamp = ev.header.stamp
        return bytes(serialize_message(out))

    def wanted(self) -> dict[str, bool]:
        """The ROS topics a viewer (or a reader of /line/trains) needs now.

        Topic -> True: every message; False: the latest once per view period (a source in
        :data:`SAMPLED` only viewers of its derived topic want).
        """
        out = {t: True for t in self.ros if self.channels[t].has_sinks()}
        for src, (name, pub) in self.derived.items():
            if pub.get_subscription_count() > 0:
                out[src] = True
            elif self.channels[name].has_sinks():
                out.setdefault(src, src not in SAMPLED)
        return out

    def update_subscriptions(self) -> None:
        """Subscribe to the topics viewers want, drop the others; re-send latched messages."""
        want = self.wanted()
        for topic in sorted(self.subs):
            if topic not in want or want[topic] == (topic in self.sampled):
                # not wanted, or wanted the other way (every message / the latest)
                self.destroy_subscription(self.subs.pop(topic))
                self.sampled.discard(topic)
                self.changed = True
        for topic in sorted(set(want) - set(self.subs)):
            cls, qos = self.ros[topic]

            def cb(data: bytes, topic: str = topic) -> None:
                self.forward(topic, data)

            every = want[topic]
            self.subs[topic] = self.create_subscription(
                cls, topic, cb, reader_qos(qos) if every else LATEST_QOS, raw=True)
            if not every:
                self.sampled.add(topic)
            self.changed = True
        while self.listener.subscribed:
            topic = self.by_id.get(self.listener.subscribed.popleft(), "")
            if topic in self.last:
                self.channels[topic].log(self.last[topic])

    def health(self) -> list[Any]:
        """/diagnostics: the server's address, topics forwarded, messages."""
        level, msg = (OK, "serving") if self.subs else (WARN, "no viewer subscribed")
        return [diag_status("foxglove_bridge: server", f"ws://{self.host}:{self.port}", level,
                            msg, {"channels": len(self.channels),
                                  "subscribed_topics": len(self.subs),
                                  "sampled_topics": len(self.sampled),
                                  "view_period_s": self.view_period_s,
                                  "trains_to_viewers": self.count["trains_viewed"],
                                  "messages": sum(v for k, v in self.count.items()
                                                  if k not in ("rejected", "trains_viewed")),
                                  "rejected_inputs": self.count["rejected"]})]

    def close(self) -> None:
        """Stop the server (viewers are disconnected) and close the channels (once)."""
        if self.server is None:
            return
        self.server.stop()
        self.server = None
        for ch in self.channels.values():
            ch.close()

    def destroy_node(self) -> None:
        """:meth:`close`, then destroy the node."""
        self.close()
        super().destroy_node()


def main(args: Sequence[str] | None = None) -> int:
    """Entry point of the ``foxglove_bridge`` executable."""
    def loop(executor: SingleThreadedExecutor, nodes: Sequence[Node]) -> None:
        node = nodes[0]
        assert isinstance(node, FoxgloveBridge)
        ctx = node.context
        last_slow = 0.0
        poller = SubscriptionPoller(ctx, [])
        while ctx.ok() and not stop_requested():
            if node.changed:
                node.changed = False
                # the sampled topics are not waited on: taken once per view period
                poller = SubscriptionPoller(ctx, [s for t, s in node.subs.items()
                                                  if t not in node.sampled])
            if not node.subs:  # no viewer: only the timers, at their own pace
                executor.spin_once(timeout_sec=0.1)
                continue
            poller.poll(node.poll_timeout(time.monotonic(), 0.05))
            now = time.monotonic()
            node.take_sampled(now)
            if now - last_slow >= 0.1:
                last_slow = now
                executor.spin_once(timeout_sec=0.0)

    return run_nodes(lambda: [FoxgloveBridge()], loop, args)


if __name__ == "__main__":
    raise SystemExit(main())
