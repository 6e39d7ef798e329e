"""The simulator's dispatcher's desk: the ``/line/dispatch`` service and its applied commands.

The ROS side of :mod:`metro_atc.core.dispatcher_commands` inside ``line_simulator``: a
deep request queue answered a bounded number of requests per lockstep step (a flood costs
each step a bounded time and is refused and counted, never waited on), the commands due
applied at the step boundary and published on ``/line/dispatcher_commands`` (reliable,
transient local: the ATOs, the ATS and the bag), and replay of a recorded run's commands.
"""

from __future__ import annotations

import time
from typing import Any

from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

from metro_atc.core.dispatcher_commands import KIND_NAMES, Applied, Dispatcher
from metro_atc.core.plant.line import LineSim
from metro_atc.core.validate import Rejections
from metro_atc.nodes import dispatch_msgs
from metro_atc.nodes.common import QOS_EVENTS, NodeConfigError

DISPATCH_DEPTH = 1000
"""Requests of /line/dispatch the service's reader holds before answering [requests]."""
DISPATCH_PER_STEP = 256
"""Requests of /line/dispatch answered per lockstep step at most."""


class DispatchDesk:
    """``/line/dispatch`` served for one simulator node; commands applied at step boundaries.

    ``replay_bag`` (non-empty): the recorded commands of that bag are applied at their
    steps and live requests are refused (``run --replay-commands``); an unreadable bag
    raises NodeConfigError.
    """

    def __init__(self, node: Node, sim: LineSim, queue_max: int, replay_bag: str,
                 rejections: Rejections, closed: str = "") -> None:
        """Create the dispatcher, the applied-commands publisher and the service.

        ``closed``: why every request is refused ('' : requests are served).
        """
        from metro_atc_msgs.msg import DispatcherCommand
        from metro_atc_msgs.srv import Dispatch
        self.node = node
        self.rejections = rejections
        self.dispatcher = Dispatcher(sim, int(queue_max), closed)
        """The dispatcher's commands (:mod:`metro_atc.core.dispatcher_commands`)."""
        if replay_bag:
            try:
                recorded = dispatch_msgs.recorded_commands(replay_bag)
            except ValueError as exc:
                raise NodeConfigError(f"replay_commands: {exc}") from None
            self.dispatcher.load_replay((a.step, a.command) for a in recorded)
        self.pub = node.create_publisher(DispatcherCommand, dispatch_msgs.APPLIED_TOPIC,
                                         QOS_EVENTS)
        # a deep request queue: a flood waits in it and is answered (refused, counted) a
        # bounded number per step (:meth:`take_requests`)
        self.srv = node.create_service(
            Dispatch, dispatch_msgs.SERVICE, self.on_request,
            qos_profile=QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=DISPATCH_DEPTH,
                                   reliability=ReliabilityPolicy.RELIABLE))
        self._request_type = Dispatch

    @property
    def state(self) -> dict[str, Any]:
        """What a checkpoint keeps of the dispatcher (its ``state`` attribute)."""
        return self.dispatcher.state

    @state.setter
    def state(self, st: dict[str, Any]) -> None:
        """Restore the dispatcher from a checkpoint's state."""
        self.dispatcher.state = st

    def on_request(self, request: Any, response: Any) -> Any:
        """/line/dispatch: validate one command and queue it (never raises)."""
        try:
            cmd = dispatch_msgs.command_from_msg(request.command)
            ok, reason, ticket = self.dispatcher.submit(cmd)
        except Exception as exc:  # noqa: BLE001 - a request never ends the node
            ok, reason, ticket = False, f"request not readable ({type(exc).__name__})", 0
            self.dispatcher.refused["unreadable"] = \
                self.dispatcher.refused.get("unreadable", 0) + 1
        response.accepted, response.reason, response.ticket = bool(ok), reason, int(ticket)
        log = self.node.get_logger()
        if not ok and self.rejections.add("dispatch", time.monotonic()):
            log.warning(f"dispatcher command refused: {reason}")
        elif ok:
            log.info(f"dispatcher command {ticket} accepted: {reason}")
        return response

    def take_requests(self) -> int:
        """Answer at most :data:`DISPATCH_PER_STEP` waiting requests; how many were taken.

        Called once per step: a flood of requests costs each step a bounded time, and its
        excess is answered (refused: queue full) a few steps later, never waited on.
        """
        srv, n = self.srv, 0
        while n < DISPATCH_PER_STEP:
            with srv.handle:
                request, header = srv.handle.service_take_request(self._request_type.Request)
            if header is None:
                break
            n += 1
            srv.send_response(self.on_request(request, self._request_type.Response()), header)
        return n

    def apply(self, k: int) -> list[Applied]:
        """Apply the dispatcher's commands due at step ``k`` (before the plant advances)."""
        applied = self.dispatcher.apply_due(k)
        for a in applied:
            self.pub.publish(dispatch_msgs.applied_msg(a))
            c = a.command
            self.node.get_logger().info(
                f"dispatcher command applied at step {a.step} (t={a.t_s:.2f} s): "
                f"{KIND_NAMES[c.kind]} {c.tsr_id or ''}{c.train_id} {c.station}".rstrip())
        return applied

    def republish(self) -> None:
        """Publish every applied command again (a restarted ATO learns its TSRs)."""
        for a in self.dispatcher.log:
            self.pub.publish(dispatch_msgs.applied_msg(a))
