"""Shared node plumbing: QoS profiles, parameter declaration, process entry points.

QoS per topic (see README topic map):

- commands and events: reliable, volatile (events transient-local so a restarted ATS
  rebuilds its state from the history);
- timetable / departure commands / profiles / line status: reliable, transient-local, so late
  joiners and restarted nodes catch up;
- high-rate sensor data: best-effort, keep-last.
"""

from __future__ import annotations

import math
import os
import signal
import sys
import threading
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator, Sequence

import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                ParameterType, SetParametersResult)
from rclpy.clock import Clock, ClockType
from rclpy.context import Context
from rclpy.exceptions import ParameterException
from rclpy.logging import LoggingSeverity
from rclpy.signals import SignalHandlerOptions
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.event_handler import PublisherEventCallbacks, SubscriptionEventCallbacks
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.subscription import Subscription
from rclpy.qos import (DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy)

from metro_atc.dds import dds_defaults
from metro_atc.exit_codes import Exit
from metro_atc.process_watch import watch_parent

QOS_RELIABLE = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=500,
                          reliability=ReliabilityPolicy.RELIABLE,
                          durability=DurabilityPolicy.VOLATILE)
"""Commands and per-step states: every sample matters, no history for late joiners. A keep-last
writer overwrites samples a reader has not acknowledged: 500 steps cover a recorder that
falls behind the lockstep for a few seconds."""

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

FLEET_SENSOR_TOPIC = "/line/brake_sensors"
"""The brake sensor samples of all trains, one FleetBrakeSensorData per step with samples."""

QOS_FLEET_SENSOR = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000,
                              reliability=ReliabilityPolicy.RELIABLE,
                              durability=DurabilityPolicy.VOLATILE)
"""/line/brake_sensors, writer and reader: a lost batch would lose every train's samples of a
step, so reliable; keep-last, so a slow or dead reader never blocks the lockstep (a full
history drops its oldest batch); 1 000 batches (10 s of wall time at 100 steps/s) before
that happens.  Volatile: a restarted reader gets the kept samples from the simulator's
re-send instead (acknowledged per train by the BrakeDiagnosis stamp)."""

QOS_CLOCK = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000,
                       reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.VOLATILE)
"""/clock: matches rclpy's best-effort and reliable clock subscribers; a writer history of
1 000 ticks so that a reliable reader (a recorder) that falls behind loses none (a keep-last
writer overwrites unacknowledged ticks; after the last train left, steps need no command
and run at thousands per second)."""

QOS_DIAGNOSTICS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=50,
                             reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.VOLATILE)
"""/diagnostics: reliable, volatile (as diagnostic_updater publishes it)."""


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


def subscriber_gids(node: Node, publisher: Publisher) -> set[bytes]:
    """Endpoint GIDs of the subscriptions matching ``publisher``'s topic (graph query).

    What ``node.get_subscriptions_info_by_topic`` gives, without building a
    ``TopicEndpointInfo`` (and its QoS profile objects) per endpoint: the simulator asks
    this for its 30 sensor topics every wall second. ``publisher.topic_name``
    is already expanded and remapped.
    """
    with node.handle:
        infos = _rclpy.rclpy_get_subscriptions_info_by_topic(node.handle,
                                                             publisher.topic_name, False)
    return {bytes(bytearray(x["endpoint_gid"])) for x in infos}


class SubscriptionPoller:
    """Wait on a fixed set of subscriptions and run their callbacks, bypassing the executor.

    rclpy's executor rebuilds its wait set from every entity of every node (parameter
    services, timers, /clock, ...) in Python on every wait; on the lockstep path that is
    most of a step's time. The poller waits on the given subscriptions only and drains each
    ready one. Everything else (parameter services, timers, /clock) is still served by the
    executor, spun by :func:`spin_fast` every ``slow_period_s``.
    """

    def __init__(self, context: Context, subs: Sequence[Subscription]) -> None:
        """Remember the subscriptions to wait on (their handles, read once)."""
        self.ctx = context
        self.subs = list(subs)
        # per poll only C-level calls on these: no ExitStack, no property look-ups (with 61
        # subscriptions in the simulator those were ~3 ms of Python per poll)
        self._handles = [s.handle for s in self.subs]
        self._pointers = [h.pointer for h in self._handles]
        self._ws: Any = None

    def poll(self, timeout_s: float) -> int:
        """Wait up to ``timeout_s`` for messages; run the callbacks; return how many ran."""
        if not self.subs:
            time.sleep(max(timeout_s, 0.0))
            return 0
        handles = self._handles
        ctx_handle: Any = self.ctx.handle
        entered: list[Any] = []
        try:
            # each handle is held while it is in the wait set (rclpy's use count: a node
            # destroyed meanwhile is destroyed after the wait, not under it)
            ctx_handle.__enter__()
            entered.append(ctx_handle)
            for h in handles:
                h.__enter__()
                entered.append(h)
            ws = self._ws
            if ws is None:
                ws = self._ws = _rclpy.WaitSet(len(handles), 0, 0, 0, 0, 0, ctx_handle)
            ws.clear_entities()
            for h in handles:
                ws.add_subscription(h)
            ws.wait(max(int(timeout_s * 1e9), 0))
            ready = set(ws.get_ready_entities("subscription"))
        finally:
            for h in reversed(entered):
                h.__exit__(None, None, None)
        n = 0
        if not ready:
            return 0
        for s, h, ptr in zip(self.subs, handles, self._pointers):
            if ptr not in ready:
                continue
            take, msg_type, raw, callback = h.take_message, s.msg_type, s.raw, s.callback
            while True:
                with h:
                    info = take(msg_type, raw)
                if info is None:
                    break
                callback(info[0])
                n += 1
        return n


STOP_POLL_S = 0.05
"""Longest wait for messages of a node's fast loop [s, wall]: a SIGTERM (which does not
interrupt a DDS wait) is seen at most this late (the end of every run waits for it)."""


def spin_fast(executor: SingleThreadedExecutor, nodes: Sequence[Node],
              fast_subs: Sequence[Subscription], slow_period_s: float = 0.05,
              until: Callable[[], bool] | None = None) -> None:
    """Serve ``fast_subs`` with a :class:`SubscriptionPoller` and the rest every slow period.

    Runs until the context shuts down or ``until()`` is true.
    """
    ctx = nodes[0].context if nodes else executor.context
    poller = SubscriptionPoller(ctx, fast_subs)
    last_slow = 0.0
    wait_s = min(slow_period_s, STOP_POLL_S)
    while ctx.ok() and not stop_requested() and not (until is not None and until()):
        poller.poll(wait_s)
        now = time.monotonic()
        if now - last_slow >= slow_period_s:
            last_slow = now
            executor.spin_once(timeout_sec=0.0)


class WarnLimiter:
    """A node's warnings at most once per ``period_s`` [s] of wall time per key."""

    def __init__(self, node: Node, period_s: float = 1.0) -> None:
        """Nothing logged yet."""
        self._node = node
        self._period_s = float(period_s)
        self._last: dict[str, float] = {}

    def __call__(self, key: str, text: str) -> None:
        """Log ``text`` unless ``key`` was logged less than ``period_s`` ago."""
        now = time.monotonic()
        if now - self._last.get(key, -math.inf) > self._period_s:
            self._last[key] = now
            self._node.get_logger().warning(text)


def declare(node: Node, name: str, default: Any, description: str,
            lo: float | int | None = None, hi: float | int | None = None,
            step: float | int | None = None, read_only: bool = False,
            choices: Sequence[str] | None = None) -> Any:
    """Declare a parameter with a descriptor (description, range, choices); return its value.

    Integer and float ranges are enforced by rclpy: an out-of-range value given with
    ``-p`` or ``--params-file`` makes the declaration fail with a message naming it.
    ``read_only`` parameters are fixed for the node's life (``ros2 param set`` is refused by
    rclpy with a reason); ``choices`` (string enumerations) go into the descriptor's
    ``additional_constraints`` and a value outside them is refused at declaration (and at
    runtime by :class:`RuntimeParams`).
    """
    desc = ParameterDescriptor(description=description, read_only=read_only)
    if choices is not None:
        desc.additional_constraints = "one of: " + ", ".join(choices)
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
    value = node.declare_parameter(name, default, desc).value
    if choices is not None and value not in choices:
        raise NodeConfigError(f"parameter {name}='{value}' is not one of {', '.join(choices)}")
    return value


def static(node: Node, name: str, default: Any, description: str,
           lo: float | int | None = None, hi: float | int | None = None,
           choices: Sequence[str] | None = None) -> Any:
    """:func:`declare` a read-only parameter (set at start-up only); return its value."""
    return declare(node, name, default, description, lo, hi, read_only=True, choices=choices)


LOG_LEVELS = {"debug": LoggingSeverity.DEBUG, "info": LoggingSeverity.INFO,
              "warn": LoggingSeverity.WARN, "error": LoggingSeverity.ERROR,
              "fatal": LoggingSeverity.FATAL}
"""Values of the ``log_level`` parameter."""

OK, WARN, ERROR, STALE = (DiagnosticStatus.OK, DiagnosticStatus.WARN, DiagnosticStatus.ERROR,
                          DiagnosticStatus.STALE)
"""diagnostic_msgs levels (bytes): OK / WARN (degraded, still working) / ERROR (not doing
its job) / STALE (no data yet)."""


def diag_status(name: str, hardware_id: str, level: bytes, message: str,
                values: dict[str, Any]) -> DiagnosticStatus:
    """One diagnostic_updater-shaped status (``name`` as ``node: task``, key-values as str)."""
    return DiagnosticStatus(level=level, name=name, message=message, hardware_id=hardware_id,
                            values=[KeyValue(key=str(k), value=_kv(v))
                                    for k, v in values.items()])


def _kv(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.6g}"
    return str(v)


class RuntimeParams:
    """The dynamic parameters of a node and its wall-time ``/diagnostics`` publisher.

    Declares the parameters every node has, both applied at runtime:

    * ``diagnostics_period_s`` -- wall-clock period of the node's ``/diagnostics`` array
      (a steady-clock timer, independent of ``use_sim_time``);
    * ``log_level`` -- the node logger's severity (debug, info, warn, error, fatal).

    Nodes add their own dynamic parameters with :meth:`dynamic`; one on-set callback
    validates a whole change (choices) and then applies every parameter of it through its
    setter, so ``ros2 param set`` takes effect or is refused with a reason. Parameters not
    registered here and not read-only are refused by the callback too (nothing accepts a
    value it then ignores).
    """

    def __init__(self, node: Node, statuses: Callable[[], list[DiagnosticStatus]],
                 period_s: float = 1.0, stamp: Callable[[], float] | None = None) -> None:
        """Declare the common parameters, start the /diagnostics timer, hook the callback.

        ``stamp`` gives the header stamp [s] (default: the node clock, i.e. simulated time
        under ``use_sim_time``).
        """
        self.node = node
        self.statuses = statuses
        self.stamp = stamp
        self._setters: dict[str, Callable[[Any], None]] = {}
        self._choices: dict[str, Sequence[str]] = {}
        self._declaring = False
        node.add_on_set_parameters_callback(self._on_set)
        self.pub = node.create_publisher(DiagnosticArray, "/diagnostics", QOS_DIAGNOSTICS)
        self._steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.period_s = float(self.dynamic(
            "diagnostics_period_s", period_s,
            "/diagnostics period in wall-clock time [s]", self._set_period, 0.05, 3600.0))
        self.timer = node.create_timer(self.period_s, self.publish, clock=self._steady)
        self.dynamic("log_level", "info", "logger severity", self._set_log_level,
                     choices=tuple(LOG_LEVELS))
        self._set_log_level(node.get_parameter("log_level").value)

    def dynamic(self, name: str, default: Any, description: str,
                setter: Callable[[Any], None], lo: float | int | None = None,
                hi: float | int | None = None, choices: Sequence[str] | None = None) -> Any:
        """Declare a parameter applied at runtime by ``setter``; return its start value.

        Call after the node's read-only declarations (the on-set callback refuses runtime
        changes of anything not registered here).
        """
        self._declaring = True
        try:
            value = declare(self.node, name, default, description, lo, hi, choices=choices)
        finally:
            self._declaring = False
        self._setters[name] = setter
        if choices is not None:
            self._choices[name] = choices
        return value

    def _on_set(self, params: list[Any]) -> SetParametersResult:
        if self._declaring:
            return SetParametersResult(successful=True)
        for p in params:
            if p.name == "use_sim_time" or p.name.startswith("qos_overrides."):
                continue
            if not self.node.has_parameter(p.name):
                continue  # being declared (its start-up value): declare() checks it
            if self.node.describe_parameter(p.name).read_only:
                return SetParametersResult(successful=False,
                                           reason=f"{p.name} is read-only (set at start-up)")
            if p.name not in self._setters:
                return SetParametersResult(successful=False,
                                           reason=f"{p.name} cannot be changed at runtime")
            ch = self._choices.get(p.name)
            if ch is not None and p.value not in ch:
                return SetParametersResult(
                    successful=False, reason=f"{p.name}='{p.value}' is not one of "
                    f"{', '.join(ch)}")
        for p in params:
            if p.name in self._setters:
                self._setters[p.name](p.value)
        return SetParametersResult(successful=True)

    def _set_period(self, value: float) -> None:
        self.period_s = float(value)
        old = getattr(self, "timer", None)
        if old is not None:
            self.node.destroy_timer(old)
            self.timer = self.node.create_timer(self.period_s, self.publish,
                                                clock=self._steady)

    def _set_log_level(self, value: str) -> None:
        self.node.get_logger().set_level(LOG_LEVELS[value])

    def publish(self) -> None:
        """Publish the node's statuses now (timer callback)."""
        if not self.node.context.ok():
            return
        arr = DiagnosticArray()
        if self.stamp is None:
            arr.header.stamp = self.node.get_clock().now().to_msg()
        else:
            t = max(float(self.stamp()), 0.0)
            arr.header.stamp.sec = int(t)
            arr.header.stamp.nanosec = int(round((t - int(t)) * 1e9)) % 1000000000
        arr.status = list(self.statuses())
        if arr.status:
            self.pub.publish(arr)


class NodeConfigError(RuntimeError):
    """A node cannot start because of its configuration (one clear line for the user).

    ``code``: the process's exit code (:data:`Exit.REFUSED`: a restart cannot mend it).
    """

    code: int = Exit.REFUSED


class GraphNotReady(NodeConfigError):
    """The graph a node waits for never appeared within its bounded wait (one line)."""

    code = Exit.GRAPH_NOT_READY


def run_nodes(factory: Callable[[], Sequence[Node]],
              loop: Callable[[SingleThreadedExecutor, Sequence[Node]], int | None]
              | None = None,
              args: Iterable[str] | None = None) -> int:
    """Init rclpy, build nodes, spin a SingleThreadedExecutor, exit cleanly on SIGINT/SIGTERM.

    Returns the process's exit code (:class:`metro_atc.exit_codes.Exit`): configuration
    errors (bad scenario, out-of-range parameter, unknown parameter, a params file for no
    node here, a :class:`NodeConfigError` raised by ``loop``) print one line and return its
    ``code`` (:data:`Exit.REFUSED`, :data:`Exit.GRAPH_NOT_READY`); ``loop`` may return the
    code of the run it drove (None: 0); a node whose ``close`` (which writes its outputs)
    fails prints one line and the process returns :data:`Exit.OUTPUTS_NOT_WRITTEN`.
    """
    dds_defaults()
    watch_parent()
    argv = list(args) if args is not None else sys.argv
    name = os.path.basename(argv[0]) if argv else "node"
    problem = check_params_files(argv)
    if problem:
        print(f"{name}: error: {problem}", file=sys.stderr)
        return Exit.REFUSED
    try:
        # rclpy's own SIGINT handler shuts the context down under the running callbacks
        # (RCLError "failed to initialize wait set", "publisher's context is invalid" in
        # the logs); here SIGINT and SIGTERM raise KeyboardInterrupt in the main thread and
        # the context is shut down once, after the nodes are closed and destroyed
        rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
    except RuntimeError as exc:
        print(f"{name}: error: {_one_line(exc).split(', at /')[0]}", file=sys.stderr)
        return Exit.REFUSED
    # a flag, not an exception: raised inside rclpy's executor an exception leaves
    # half-made tasks ("coroutine ... was never awaited"); every loop here waits at most
    # ~0.1 s and checks the flag
    _STOP.clear()
    signal.signal(signal.SIGTERM, _request_stop)
    signal.signal(signal.SIGINT, _request_stop)
    nodes: Sequence[Node] = ()
    code = 0
    try:
        try:
            nodes = factory()
            check_overrides(nodes, argv)
        except (NodeConfigError, ParameterException, ValueError, TypeError) as exc:
            print(f"{name}: error: {_one_line(exc)}", file=sys.stderr)
            return int(getattr(exc, "code", Exit.REFUSED))
        executor = SingleThreadedExecutor()
        for n in nodes:
            executor.add_node(n)
        with _profiled(name):
            if loop is not None:
                code = int(loop(executor, nodes) or 0)
            else:
                spin_until_stopped(executor)
    except (KeyboardInterrupt, ExternalShutdownException):
        code = 0
    except NodeConfigError as exc:
        # found while running (another graph on the domain, a graph that never came): one
        # line, its code (no respawn)
        print(f"{name}: error: {_one_line(exc)}", file=sys.stderr)
        code = int(exc.code)
    finally:
        # a second signal during the clean-up must not leave a traceback either
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        for n in nodes:
            close = getattr(n, "close", None)
            if callable(close):
                try:
                    close()
                except Exception as exc:  # noqa: BLE001 - reported by the exit code
                    # close writes a node's outputs: the run did not produce them
                    print(f"{name}: error: {n.get_name()}: outputs not written: "
                          f"{_one_line(exc)}", file=sys.stderr)
                    if code in (Exit.OK, Exit.SERVICE_INCOMPLETE, Exit.CUT):
                        code = Exit.OUTPUTS_NOT_WRITTEN
            n.destroy_node()
        rclpy.try_shutdown()
        try:
            # the DDS participant (and its shared-memory segments) goes now, not in the
            # interpreter's teardown: a forked node ends with os._exit (metro_atc.zygote)
            rclpy.get_default_context().destroy()
        except Exception as exc:  # noqa: BLE001 - best effort at shutdown
            print(f"shutdown: {exc}", file=sys.stderr)
    return code


PROFILE_ENV = "METRO_ATC_PROFILE_DIR"
"""Environment variable: a directory where each node process writes the cProfile statistics
of its loop (``<executable>_<pid>.prof``; read with ``python -m pstats``)."""
PROFILE_CLOCK_ENV = "METRO_ATC_PROFILE_CLOCK"
"""Environment variable: ``cpu`` makes the profiles of :data:`PROFILE_ENV` count the process's
CPU time (``time.process_time``) instead of wall time (on a loaded machine wall time mostly
counts the waits for a core)."""


@contextmanager
def _profiled(name: str) -> Iterator[None]:
    """cProfile the block when :data:`PROFILE_ENV` names a directory (else nothing)."""
    out = os.environ.get(PROFILE_ENV, "")
    if not out:
        yield
        return
    import cProfile
    cpu = os.environ.get(PROFILE_CLOCK_ENV, "") == "cpu"
    prof = cProfile.Profile(time.process_time) if cpu else cProfile.Profile()
    prof.enable()
    try:
        yield
    finally:
        prof.disable()
        try:
            Path(out).mkdir(parents=True, exist_ok=True)
            prof.dump_stats(str(Path(out) / f"{name}_{os.getpid()}.prof"))
        except OSError as exc:
            print(f"{name}: profile not written: {exc}", file=sys.stderr)


def check_overrides(nodes: Sequence[Node], argv: Sequence[str]) -> None:
    """Raise :class:`NodeConfigError` for a params-file value no node can take.

    See :func:`metro_atc.nodes.param_check.override_problem` (``seed: {a: 1}``, unknown
    parameter names in a section naming the node) and
    :func:`~metro_atc.nodes.param_check.unknown_problem` (``-p no_such_param:=1``, a params
    file naming no node of the process).
    """
    from metro_atc.nodes.param_check import override_problem, unknown_problem

    for n in nodes:
        problem = override_problem(n.get_name(), n.get_namespace(), n.has_parameter, argv)
        if problem:
            raise NodeConfigError(problem)
    problem = unknown_problem([(n.get_name(), n.get_namespace(), n.has_parameter)
                               for n in nodes], argv)
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


_STOP = threading.Event()
"""Set by SIGINT/SIGTERM in a node process (see :func:`run_nodes`)."""


def _request_stop(*_: Any) -> None:
    _STOP.set()


def stop_requested() -> bool:
    """True once the process got SIGINT or SIGTERM (loops end, nodes close cleanly)."""
    return _STOP.is_set()


def spin_until_stopped(executor: SingleThreadedExecutor) -> None:
    """Spin with bounded waits until SIGINT/SIGTERM or the context shuts down."""
    while executor.context.ok() and not stop_requested():
        executor.spin_once(timeout_sec=0.1)


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0] if text else type(exc).__name__
