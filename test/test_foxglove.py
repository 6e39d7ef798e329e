"""The live view (``run --foxglove``): derived messages, layout file, loopback binding, and
Foxglove's own readers (Node: ``test/js``) on a live run and on its bag.

* ``/line/trains`` and ``/line/layout`` (:mod:`metro_atc.nodes.wire.line_view`) read back
  with rclpy's and rosbags' deserializers (independent readers) to the values they carry;
* ``config/foxglove_layout.json`` is :mod:`metro_atc.live_layout`'s output and every
  message path in it names a channel the bridge advertises and a field of its type;
* the WebSocket server listens on 127.0.0.1 only unless a host is given (the kernel's
  socket table, ``/proc/net/tcp``);
* one mini run with ``--record --foxglove``: a ``@foxglove/ws-protocol`` client decodes
  ``/train_01/state`` while it runs, and ``@mcap/core`` + ``@foxglove/rosmsg2-serialization``
  decode every message of its bag, as many per topic as the ``rosbags`` reader counts.
  Skipped (one line) without node/npm.
"""

from __future__ import annotations

import json
import math
import os
import re
import shutil
import socket
import subprocess
import time
from collections import Counter
from pathlib import Path
from typing import Any, Iterator

import pytest

ROOT = Path(__file__).resolve().parent.parent
JS = ROOT / "test" / "js"
LAYOUT_FILE = ROOT / "config" / "foxglove_layout.json"


def _free_port() -> int:
    """A TCP port free on loopback now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _listening(port: int) -> set[str]:
    """The local addresses with a socket listening on ``port`` (/proc/net/tcp, tcp6)."""
    out = set()
    for name in ("tcp", "tcp6"):
        path = Path("/proc/net") / name
        if not path.exists():
            continue
        for line in path.read_text().splitlines()[1:]:
            f = line.split()
            addr, hexport = f[1].split(":")
            if f[3] != "0A" or int(hexport, 16) != port:  # 0A: LISTEN
                continue
            raw = bytes.fromhex(addr)
            if len(raw) == 4:
                out.add(socket.inet_ntop(socket.AF_INET, raw[::-1]))
            else:
                words = b"".join(raw[i:i + 4][::-1] for i in range(0, 16, 4))
                out.add(socket.inet_ntop(socket.AF_INET6, words))
    return out


# ------------------------------------------------------------------ derived messages
def test_trains_message_reads_back() -> None:
    """JointState of a FleetState: fixed train order, NaN for a train not in service."""
    from rclpy.serialization import deserialize_message
    from rosbags.typesys import Stores, get_typestore
    from sensor_msgs.msg import JointState

    from metro_atc.nodes.wire import cdr, fleet_state, line_view

    ids = ["train_03", "train_01"]  # in service, not in timetable order
    n = len(ids)
    arrays = []
    for f in fleet_state.ARRAYS:
        if f.name == "position_m":
            arrays.append([1500.25, -20.0])
        elif f.name == "speed_mps":
            arrays.append([12.5, 0.0])
        elif f.name == "mode":
            arrays.append([3, 1])
        elif f.boolean:
            arrays.append([True] * n)
        else:
            arrays.append([0] * n)
    data = fleet_state.encode(123.4, 1234, cdr.string_seq(ids), arrays)
    view = fleet_state.decode(data)
    assert view is not None
    out = line_view.TrainsBuilder(["train_01", "train_02", "train_03"]).build(view)
    m = deserialize_message(out, JointState)
    assert list(m.name) == ["train_01", "train_02", "train_03"]
    assert (m.header.stamp.sec, m.header.stamp.nanosec) == (123, 400_000_000)
    assert m.header.frame_id == "line"
    assert m.position[0] == -20.0 and m.position[2] == 1500.25 and math.isnan(m.position[1])
    assert m.velocity[0] == 0.0 and m.velocity[2] == 12.5 and math.isnan(m.velocity[1])
    assert m.effort[0] == 1.0 and m.effort[2] == 3.0 and math.isnan(m.effort[1])
    store = get_typestore(Stores.ROS2_JAZZY)
    r = store.deserialize_cdr(out, "sensor_msgs/msg/JointState")
    assert list(r.name) == list(m.name) and r.position[2] == 1500.25


def test_layout_message_reads_back() -> None:
    """LineLayout of the mini line: its stations, limits and gradients, the train order."""
    from metro_atc_msgs.msg import LineLayout
    from rclpy.serialization import deserialize_message

    from metro_atc.core.line.scenario import load_scenario
    from metro_atc.nodes.wire import line_view

    scn = load_scenario("mini")
    m = deserialize_message(line_view.encode_layout(line_view.layout_values(scn)), LineLayout)
    assert m.scenario == "mini"
    assert list(m.station_name) == [s.name for s in scn.line.stations]
    assert list(m.station_code) == [s.code for s in scn.line.stations]
    assert list(m.station_position_m) == [s.position_m for s in scn.line.stations]
    assert list(m.speed_limit_start_m) == [s.start_m for s in scn.line.speed_limits]
    assert list(m.speed_limit_start_m[:3]) == [-1000.0, 1200.0, 1500.0]
    assert m.speed_limit_mps[1] == pytest.approx(60.0 / 3.6)
    assert list(m.grade_permille[:3]) == [0.0, 20.0, 0.0]
    assert m.line_speed_mps == pytest.approx(scn.line.line_speed_kmh / 3.6)
    assert list(m.train_id) == ["train_01", "train_02"]
    with pytest.raises(Exception, match="without a value"):
        line_view.encode_layout({"header": 0.0})


def test_event_log_line() -> None:
    """A departure 75 s late is a warning with its dwell; an arrival on time is info."""
    from metro_atc.nodes.wire.line_view import LOG_INFO, LOG_WARN, event_log_line

    assert event_log_line(1, "train_01", "Bravo", 100.0, 100.0, 0.0) == (
        LOG_INFO, "train_01 arrives at Bravo at 100.0 s (+0.0 s vs timetable)")
    assert event_log_line(2, "train_02", "Alpha", 175.0, 100.0, 30.0) == (
        LOG_WARN, "train_02 departs from Alpha at 175.0 s (+75.0 s vs timetable), dwell 30.0 s")


def test_live_view_line_states_the_view_rate() -> None:
    """The run's line about its live view names the address and the view period."""
    from metro_atc.nodes.wire.line_view import live_view_line

    line = live_view_line("127.0.0.1", 8765, 0.25)
    assert line.startswith("live view on ws://127.0.0.1:8765;")
    assert "/line/trains goes to viewers at most once per 0.25 s of wall time" in line


def test_schema_text_is_the_msg_text_with_nested_types() -> None:
    """The ros2msg schema of TrainState: its .msg definitions, then Header's and Time's."""
    from metro_atc.bag import TypeDefs
    from metro_atc.nodes.bag_recorder import find_msg

    text = TypeDefs(find_msg).msgdef("metro_atc_msgs/msg/TrainState")
    assert "float64 position_m" in text and "uint8 MODE_ATP_BRAKE=6" in text
    assert "\nMSG: std_msgs/Header\n" in text and "\nMSG: builtin_interfaces/Time\n" in text


# ------------------------------------------------------------------ layout file
def _paths(cfg: Any) -> Iterator[str]:
    """Every message path of a layout's panel settings."""
    if isinstance(cfg, dict):
        for k, v in cfg.items():
            if k in ("value", "topicToRender") and isinstance(v, str):
                yield v
            else:
                yield from _paths(v)
    elif isinstance(cfg, list):
        for v in cfg:
            yield from _paths(v)


def test_shipped_layout_is_generated() -> None:
    """config/foxglove_layout.json is ``python -m metro_atc.live_layout``'s output."""
    from metro_atc.live_layout import layout_text
    assert LAYOUT_FILE.read_text() == layout_text(), \
        "regenerate: python -m metro_atc.live_layout > config/foxglove_layout.json"


def test_layout_paths_name_advertised_fields() -> None:
    """Every path: a topic the bridge advertises, a field of its type; 30 trains plotted."""
    import importlib

    from sensor_msgs.msg import JointState
    from metro_atc_msgs.msg import LineLayout
    from rcl_interfaces.msg import Log

    from metro_atc.core.line.scenario import load_scenario
    from metro_atc.launcher import scenario_train_ids
    from metro_atc.nodes.bag_recorder import graph_topics
    from metro_atc.nodes.wire import line_view

    ids = scenario_train_ids(load_scenario("taipei_blue"))
    types = {t: c for t, c, _ in graph_topics(ids)}
    types.update({line_view.TRAINS_TOPIC: JointState, line_view.LAYOUT_TOPIC: LineLayout,
                  line_view.EVENT_LOG_TOPIC: Log})
    cfg = json.loads(LAYOUT_FILE.read_text())
    paths = list(_paths(cfg["configById"]))
    assert sum(p.startswith(line_view.TRAINS_TOPIC + ".position[") for p in paths) == len(ids)
    for p in paths:
        topic, _, field = p.partition(".")
        assert topic in types, f"{p}: no channel {topic}"
        name = re.sub(r"\[.*\]$", "", field)
        if name:
            cls = types[topic]
            mod = importlib.import_module(cls.__module__)
            assert name in getattr(mod, cls.__name__).get_fields_and_field_types(), p
    leaves = re.findall(r'"([A-Za-z]+![a-z]+)"', json.dumps(cfg["layout"]))
    assert sorted(leaves) == sorted(cfg["configById"])


# ------------------------------------------------------------------ launcher, binding
def test_launcher_adds_the_bridge_on_loopback() -> None:
    """``--foxglove``: the bridge process on 127.0.0.1:8765; a host only when given."""
    from metro_atc.launcher import parse_args, processes_for

    def bridge(*argv: str) -> dict[str, Any]:
        a = parse_args(["--scenario", "mini", *argv])
        specs = [p for p in processes_for(a, ["train_01", "train_02"], Path("/tmp/x"))
                 if p.label == "foxglove_bridge"]
        return specs[0].params if specs else {}

    assert bridge() == {}
    p = bridge("--foxglove")
    assert (p["host"], p["port"], p["use_sim_time"]) == ("127.0.0.1", 8765, False)
    p = bridge("--foxglove", "9001", "--foxglove-host", "0.0.0.0")
    assert (p["host"], p["port"]) == ("0.0.0.0", 9001)


def test_run_refuses_a_port_in_use(tmp_path: Path, capsys: pytest.CaptureFixture[str]
                                   ) -> None:
    """``--foxglove PORT`` with PORT taken, or with --single-process: exit 2, one line,
    before any node starts."""
    from metro_atc.exit_codes import Exit
    from metro_atc.launcher import main

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        code = main(["--scenario", "mini", "--out", str(tmp_path / "a"), "--foxglove",
                     str(port)])
        assert code == Exit.REFUSED
        err = capsys.readouterr().err.strip().splitlines()
        assert err == [f"metro_atc run: error: --foxglove {port} on 127.0.0.1: cannot listen "
                       "there: Address already in use"]
    code = main(["--scenario", "mini", "--out", str(tmp_path / "b"), "--single-process",
                 "--foxglove"])
    assert code == Exit.REFUSED
    assert "--foxglove needs the multi-process graph" in capsys.readouterr().err
    assert not (tmp_path / "a" / "logs").exists()


@pytest.mark.parametrize("host,expect", [(None, {"127.0.0.1"}), ("0.0.0.0", {"0.0.0.0"})])
def test_bridge_binds_loopback_unless_told(ros_domain: int, host: str | None,
                                           expect: set[str]) -> None:
    """The server's listening socket: 127.0.0.1 by default, the given host otherwise."""
    import rclpy
    from rclpy.context import Context
    from rclpy.parameter import Parameter

    from metro_atc.nodes.foxglove_bridge import FoxgloveBridge

    ctx = Context()
    rclpy.init(context=ctx, domain_id=ros_domain)
    port = _free_port()
    params = [Parameter("scenario", value="mini"), Parameter("port", value=port)]
    if host is not None:
        params.append(Parameter("host", value=host))
    node = FoxgloveBridge(context=ctx, parameter_overrides=params)
    try:
        assert node.port == port
        assert _listening(port) == expect
    finally:
        node.destroy_node()
        rclpy.shutdown(context=ctx)
    assert _listening(port) == set()


def _fleet_msg(k: int, ids: list[str]) -> bytes:
    """A FleetState of step ``k`` (t = 0.25 k s): train i at chainage 100 k + i [m]."""
    from metro_atc.nodes.wire import cdr, fleet_state

    n = len(ids)
    arrays: list[list[Any]] = []
    for f in fleet_state.ARRAYS:
        if f.name == "position_m":
            arrays.append([100.0 * k + i for i in range(n)])
        elif f.boolean:
            arrays.append([True] * n)
        else:
            arrays.append([0] * n)
    return fleet_state.encode(0.25 * k, k, cdr.string_seq(ids), arrays)


def _viewed_trains(path: Path) -> list[float]:
    """The header stamps [s] of the /line/trains messages a bridge wrote to an MCAP sink."""
    from mcap.reader import make_reader
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import JointState

    out = []
    with path.open("rb") as f:
        for _, channel, message in make_reader(f).iter_messages():
            assert channel.topic == "/line/trains"
            m = deserialize_message(message.data, JointState)
            out.append(m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec)
    return out


def test_trains_go_to_viewers_once_per_view_period(ros_domain: int, tmp_path: Path) -> None:
    """A viewer of /line/trains gets one message per view period of wall time (the first
    fleet state read once the period has passed); while only viewers want it, the fleet
    state is read as its latest message once per period (depth 1: the older ones are
    dropped); a ROS reader of /line/trains (a recorder) makes the bridge read every one."""
    import foxglove
    import rclpy
    from metro_atc_msgs.msg import FleetState
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from rclpy.qos import ReliabilityPolicy
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import JointState

    from metro_atc.nodes.common import QOS_RELIABLE
    from metro_atc.nodes.foxglove_bridge import FLEET_TOPIC, FoxgloveBridge, take_latest

    ctx = Context()
    rclpy.init(context=ctx, domain_id=ros_domain)
    node = FoxgloveBridge(context=ctx, parameter_overrides=[
        Parameter("scenario", value="mini"), Parameter("port", value=_free_port()),
        Parameter("view_period_s", value=0.1)])
    other = Node("fleet_source", context=ctx)
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(other)
    ids = ["train_01", "train_02"]
    try:
        assert node.wanted() == {}  # no viewer: nothing read
        sink = tmp_path / "view.mcap"
        writer = foxglove.open_mcap(sink, context=node.fg,
                                    channel_filter=lambda ch: ch.topic == "/line/trains")
        # only a viewer of /line/trains: the fleet state's latest, once per period
        assert node.wanted() == {FLEET_TOPIC: False}
        for k, now in enumerate([10.0, 10.03, 10.06, 10.1, 10.12, 10.25, 10.3]):
            node.forward(FLEET_TOPIC, _fleet_msg(k, ids), now)
        node.update_subscriptions()
        assert node.sampled == {FLEET_TOPIC} and set(node.subs) == {FLEET_TOPIC}
        qos = node.subs[FLEET_TOPIC].qos_profile
        assert (qos.depth, qos.reliability) == (1, ReliabilityPolicy.BEST_EFFORT)
        pub = other.create_publisher(FleetState, FLEET_TOPIC, QOS_RELIABLE)
        got: list[Any] = []
        seen = other.create_subscription(FleetState, FLEET_TOPIC, got.append, QOS_RELIABLE)
        deadline = time.monotonic() + 10.0
        while pub.get_subscription_count() < 2 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert pub.get_subscription_count() == 2
        for k in range(10, 20):
            pub.publish(FleetState(step=k))
        while len(got) < 10 and time.monotonic() < deadline:  # all delivered here
            executor.spin_once(timeout_sec=0.05)
        time.sleep(0.2)
        raw = take_latest(node.subs[FLEET_TOPIC])
        assert raw is not None and take_latest(node.subs[FLEET_TOPIC]) is None
        assert deserialize_message(raw, FleetState).step == 19  # the latest only
        other.destroy_subscription(seen)
        # a ROS reader of /line/trains: every fleet state read, each published on ROS
        reader = other.create_subscription(JointState, "/line/trains", lambda m: None,
                                           QOS_RELIABLE)
        while node.trains_pub.get_subscription_count() == 0 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert node.wanted() == {FLEET_TOPIC: True}
        node.update_subscriptions()
        assert node.sampled == set() and set(node.subs) == {FLEET_TOPIC}
        other.destroy_subscription(reader)
        writer.close()
    finally:
        executor.shutdown()
        other.destroy_node()
        node.destroy_node()
        rclpy.shutdown(context=ctx)
    # 10.0, then 10.1 (>= 10.0 + 0.1), then 10.25 (10.12 < 10.2): steps 0, 3 and 5
    assert _viewed_trains(sink) == [0.0, 0.75, 1.25]


# ------------------------------------------------------------------ Foxglove's readers
def _node_or_skip() -> str:
    """The node executable (skip when node or npm is absent; fail when not installed)."""
    node, npm = shutil.which("node"), shutil.which("npm")
    if node is None or npm is None:
        pytest.skip("node/npm not installed: the Foxglove JS reader tests do not run")
    assert (JS / "node_modules" / "@mcap" / "core").is_dir(), \
        "test/js/node_modules missing: run `make setup` (npm ci of test/js)"
    return node


def _python_counts(bag: Path) -> Counter[str]:
    """Messages per topic as the rosbags reader counts them (and deserializes them)."""
    from rosbags.highlevel import AnyReader
    n: Counter[str] = Counter()
    with AnyReader([bag]) as r:
        for con, _, raw in r.messages():
            r.deserialize(raw, con.msgtype)
            n[con.topic] += 1
    return n


def test_foxglove_readers_on_a_live_run_and_its_bag(tmp_path: Path) -> None:
    """A mini run with --record --foxglove: the ws client decodes /train_01/state live;
    decode_bag.mjs decodes every message of the bag, per topic as many as rosbags."""
    from graph_runs import finish_graph, start_graph
    from harness import DomainAllocator

    node = _node_or_skip()
    port = _free_port()
    with DomainAllocator().allocate() as dom:
        env = dict(os.environ, ROS_DOMAIN_ID=str(dom))
        out = tmp_path / "run"
        out.mkdir()
        p = start_graph(env, out, "--record", "--foxglove", str(port))
        try:
            ws = subprocess.run([node, str(JS / "ws_client.mjs"), f"ws://127.0.0.1:{port}",
                                 "/train_01/state", "3", "90"], capture_output=True,
                                text=True, timeout=120)
        finally:
            kpis, _ = finish_graph(p)
    assert ws.returncode == 0, ws.stderr
    live = json.loads(ws.stdout)
    assert live["schema"] == "metro_atc_msgs/msg/TrainState" and live["encoding"] == "cdr"
    assert {"/line/trains", "/line/layout", "/line/event_log", "/train_02/state"} <= \
        set(live["channels"])
    assert [m["train_id"] for m in live["messages"]] == ["train_01"] * 3
    steps = [m["step"] for m in live["messages"]]
    assert steps == sorted(steps) and all(m["position_m"] > -1e4 for m in live["messages"])

    bag = Path(kpis["bag"])
    t0 = time.monotonic()
    res = subprocess.run([node, str(JS / "decode_bag.mjs"), str(bag)], capture_output=True,
                         text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    js = json.loads(res.stdout)
    py = _python_counts(bag)
    assert {t: v["count"] for t, v in js["topics"].items() if v["count"]} == dict(py)
    assert js["total"] == sum(py.values()) > int(kpis["steps"])
    assert js["topics"]["/line/fleet_state"]["count"] == int(kpis["steps"])
    # the derived topics went into the bag through the recorder, and decode to the line
    layout = js["first"]["/line/layout"]
    assert layout["scenario"] == "mini" and layout["train_id"] == ["train_01", "train_02"]
    assert layout["station_name"][:2] == ["Alpha", "Bravo"]
    assert js["first"]["/line/trains"]["name"] == ["train_01", "train_02"]
    assert time.monotonic() - t0 < 60.0
