"""Shared node plumbing: QoS profiles, parameter declaration, process entry points.

QoS per topic (see README topic map):

- commands and events: reliable, volatile (events transient-local so a restarted ATS
  rebuilds its state from the history);
- timetable / departure commands / profiles / line status: reliable, transient-local, so late
  joiners and restarted nodes catch up;
- high-rate sensor data: best-effort, keep-last.
"""

from __future__ import annotations

import os
import signal
import sys
import time
from contextlib import ExitStack
from typing import Any, Callable, Iterable, Sequence

import rclpy
from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                ParameterType)
from rclpy.context import Context
from rclpy.exceptions import ParameterException
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.event_handler import PublisherEventCallbacks, SubscriptionEventCallbacks
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.subscription import Subscription
from rclpy.qos import (DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy)

from metro_atc.dds import dds_defaults

QOS_RELIABLE = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=50,
                          reliability=ReliabilityPolicy.RELIABLE,
                          durability=DurabilityPolicy.VOLATILE)
"""Commands and per-step states: every sample matters, no history for late joiners."""

QOS_LATCHED = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                         reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
"""Latest-value topics (departure command, speed profile, line status): late joiners catch up."""

QOS_LATCHED_IN = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000,
                            reliability=ReliabilityPolicy.RELIABLE,
                            durability=DurabilityPolicy.TRANSIENT_LOCAL)
"""Reader side of a latched command topic (compatible with QOS_LATCHED writers): a deep
queue, so that a burst of invalid messages from another writer cannot push the valid
command out before the node takes it (keyless topics share one history)."""

QOS_EVENTS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10000,
                        reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.TRANSIENT_LOCAL)
"""Train events: reliable with a deep transient-local history (restarted ATS replays it)."""

QOS_SENSOR = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=20,
                        reliability=ReliabilityPolicy.BEST_EFFORT,
                        durability=DurabilityPolicy.VOLATILE)
"""High-rate sensor data: best effort, a lost sample is replaced by the next one."""

QOS_CLOCK = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                       reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.VOLATILE)
"""/clock: matches rclpy's best-effort and reliable clock subscribers."""


def bulk_publisher(node: Node, msg_type: Any, topic: str, qos: QoSProfile) -> Publisher:
    """A publisher without rclpy's default QoS-event handlers.

    rclpy adds two event waitables (incompatible QoS/type warnings) to every publisher and
    subscription, and the executor rebuilds its wait set from all of them on every wait.
    For the per-train topics (2 x trains entities per node) that dominated the lockstep
    step time, so they are created without; the QoS of these topics is fixed by this
    package (see the README topic map).
    """
    return node.create_publisher(msg_type, topic, qos,
                                 event_callbacks=PublisherEventCallbacks(
                                     use_default_callbacks=False))


def bulk_subscription(node: Node, msg_type: Any, topic: str, callback: Callable[[Any], None],
                      qos: QoSProfile) -> Subscription:
    """A subscription without rclpy's default QoS-event handlers (see bulk_publisher)."""
    return node.create_subscription(msg_type, topic, callback, qos,
                                    event_callbacks=SubscriptionEventCallbacks(
                                        use_default_callbacks=False))


class SubscriptionPoller:
    """Wait on a fixed set of subscriptions and run their callbacks, bypassing the executor.

    rclpy's executor rebuilds its wait set from every entity of every node (parameter
    services, timers, /clock, ...) in Python on every wait; on the lockstep path that is
    most of a step's time. The poller waits on the given subscriptions only and drains each
    ready one. Everything else (parameter services, timers, /clock) is still served by the
    executor, spun by :func:`spin_fast` every ``slow_period_s``.
    """

    def __init__(self, context: Context, subs: Sequence[Subscription]) -> None:
        """Remember the subscriptions to wait on."""
        self.ctx = context
        self.subs = list(subs)

    def poll(self, timeout_s: float) -> int:
        """Wait up to ``timeout_s`` for messages; run the callbacks; return how many ran."""
        if not self.subs:
            time.sleep(max(timeout_s, 0.0))
            return 0
        with ExitStack() as stack:
            for s in self.subs:
                stack.enter_context(s.handle)
            ctx_handle: Any = self.ctx.handle
            stack.enter_context(ctx_handle)
            ws = _rclpy.WaitSet(len(self.subs), 0, 0, 0, 0, 0, ctx_handle)
            ws.clear_entities()
            for s in self.subs:
                ws.add_subscription(s.handle)
            ws.wait(max(int(timeout_s * 1e9), 0))
            ready = set(ws.get_ready_entities("subscription"))
        n = 0
        for s in self.subs:
            if s.handle.pointer not in ready:
                continue
            while True:
                with s.handle:
                    info = s.handle.take_message(s.msg_type, s.raw)
                if info is None:
                    break
                s.callback(info[0])
                n += 1
        return n


def spin_fast(executor: SingleThreadedExecutor, nodes: Sequence[Node],
              fast_subs: Sequence[Subscription], slow_period_s: float = 0.05,
              until: Callable[[], bool] | None = None) -> None:
    """Serve ``fast_subs`` with a :class:`SubscriptionPoller` and the rest every slow period.

    Runs until the context shuts down or ``until()`` is true.
    """
    ctx = nodes[0].context if nodes else executor.context
    poller = SubscriptionPoller(ctx, fast_subs)
    last_slow = 0.0
    while ctx.ok() and not (until is not None and until()):
        poller.poll(slow_period_s)
        now = time.monotonic()
        if now - last_slow >= slow_period_s:
            last_slow = now
            executor.spin_once(timeout_sec=0.0)


def declare(node: Node, name: str, default: Any, description: str,
            lo: float | int | None = None, hi: float | int | None = None,
            step: float | int | None = None, read_only: bool = False) -> Any:
    """Declare a parameter with a descriptor (description and range); return its value.

    Integer and float ranges are enforced by rclpy: an out-of-range value given with
    ``-p`` or ``--params-file`` makes the declaration fail with a message naming it.
    """
    desc = ParameterDescriptor(description=description, read_only=read_only)
    if isinstance(default, bool):
        desc.type = ParameterType.PARAMETER_BOOL
    elif isinstance(default, int):
        desc.type = ParameterType.PARAMETER_INTEGER
        if lo is not None and hi is not None:
            desc.integer_range = [IntegerRange(from_value=int(lo), to_value=int(hi),
                                               step=int(step or 1) if step else 0)]
    elif isinstance(default, float):
        desc.type = ParameterType.PARAMETER_DOUBLE
        if lo is not None and hi is not None:
            desc.floating_point_range = [FloatingPointRange(
                from_value=float(lo), to_value=float(hi), step=float(step or 0.0))]
    elif isinstance(default, str):
        desc.type = ParameterType.PARAMETER_STRING
    elif isinstance(default, list):
        desc.type = ParameterType.PARAMETER_STRING_ARRAY
    return node.declare_parameter(name, default, desc).value


class NodeConfigError(RuntimeError):
    """A node cannot start because of its configuration (one clear line for the user)."""


def run_nodes(factory: Callable[[], Sequence[Node]],
              loop: Callable[[SingleThreadedExecutor, Sequence[Node]], None] | None = None,
              args: Iterable[str] | None = None) -> int:
    """Init rclpy, build nodes, spin a SingleThreadedExecutor, exit cleanly on SIGINT/SIGTERM.

    Configuration errors (bad scenario, out-of-range parameter) print one line and return 2.
    """
    dds_defaults()
    argv = list(args) if args is not None else sys.argv
    name = os.path.basename(argv[0]) if argv else "node"
    problem = check_params_files(argv)
    if problem:
        print(f"{name}: error: {problem}", file=sys.stderr)
        return 2
    try:
        rclpy.init(args=argv)
    except RuntimeError as exc:
        print(f"{name}: error: {_one_line(exc).split(', at /')[0]}", file=sys.stderr)
        return 2
    signal.signal(signal.SIGTERM, lambda *_: _raise_keyboard_interrupt())
    nodes: Sequence[Node] = ()
    code = 0
    try:
        try:
            nodes = factory()
            check_overrides(nodes, argv)
        except (NodeConfigError, ParameterException, ValueError, TypeError) as exc:
            print(f"{name}: error: {_one_line(exc)}", file=sys.stderr)
            return 2
        executor = SingleThreadedExecutor()
        for n in nodes:
            executor.add_node(n)
        if loop is not None:
            loop(executor, nodes)
        else:
            executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        code = 0
    finally:
        for n in nodes:
            close = getattr(n, "close", None)
            if callable(close):
                try:
                    close()
                except Exception as exc:  # noqa: BLE001 - best effort at shutdown
                    print(f"shutdown: {exc}", file=sys.stderr)
            n.destroy_node()
        if rclpy.ok():
            rclpy.try_shutdown()
    return code


def check_overrides(nodes: Sequence[Node], argv: Sequence[str]) -> None:
    """Raise :class:`NodeConfigError` for a params-file value no node can take.

    See :func:`metro_atc.nodes.param_check.override_problem` (``seed: {a: 1}``, unknown
    parameter names in a section naming the node).
    """
    from metro_atc.nodes.param_check import override_problem

    for n in nodes:
        problem = override_problem(n.get_name(), n.get_namespace(), n.has_parameter, argv)
        if problem:
            raise NodeConfigError(problem)


def check_params_files(argv: Sequence[str]) -> str | None:
    """Validate every ``--params-file`` of a ROS argument list; return one error line or None.

    Checks that the file exists, is YAML, and has the ROS layout
    ``<node name or /**>: {ros__parameters: {...}}``.
    """
    from metro_atc.nodes.param_check import load_params_file

    for i, a in enumerate(argv):
        if a != "--params-file":
            continue
        if i + 1 >= len(argv):
            return "--params-file needs a file path"
        path = argv[i + 1]
        doc, problem = load_params_file(path)
        if problem:
            return problem
        if not isinstance(doc, dict):
            return (f"params file {path}: expected a mapping of node names, "
                    f"got {type(doc).__name__}")
        for key, val in doc.items():
            if not isinstance(val, dict) or "ros__parameters" not in _flatten_ns(val):
                return (f"params file {path}: '{key}': expected "
                        f"'{key}: {{ros__parameters: {{...}}}}'")
    return None


def _flatten_ns(val: dict) -> dict:
    """Descend through nested namespace keys until ``ros__parameters`` (ROS layout)."""
    cur = val
    while isinstance(cur, dict) and "ros__parameters" not in cur and len(cur) == 1:
        cur = next(iter(cur.values()))
    return cur if isinstance(cur, dict) else {}


def _raise_keyboard_interrupt() -> None:
    raise KeyboardInterrupt


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0] if text else type(exc).__name__
