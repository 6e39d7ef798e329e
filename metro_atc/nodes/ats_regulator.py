"""ats_regulator node: timetable and automatic train regulation (ATS).

Subscribes to ``/line/events`` (transient-local: a restarted ATS replays the history and
rebuilds its state) and publishes one transient-local ``/<train>/departure_command`` per
decision: the departure time from the station a train has just reached, the target running
time to the next station and, when the regulator cuts the dwell, the dwell limit.

All decisions are made by the ROS-free :class:`metro_atc.core.atr.dispatch.AtsDispatcher`
(its docstring gives the regulation law); regulators (parameter ``regulator``): ``none``
keeps the timetable (Lin 2010a, eq. 10); ``lqr``, ``dhp`` and ``aoc`` run
:class:`metro_atc.core.atr.node_core.AtsRegulatorCore` (Lin 2010a, eq. 17-48) on the
scenario's traffic model (:func:`metro_atc.core.bridge.atr_line_for`); ``elqr`` is the
energy-aware LQR of the Sheu 2011 option (:mod:`metro_atc.core.atr.energy`).

A dispatcher's regulator switch (``/line/dispatch``, applied by line_simulator and published
on ``/line/dispatcher_commands``) takes effect for the events from its ``from_s`` on
(:class:`metro_atc.core.atr.switch.RegulatorSwitch`).
"""

from __future__ import annotations

import time
from typing import Any, Sequence

import numpy as np
from diagnostic_msgs.msg import DiagnosticStatus
from metro_atc_msgs.msg import DepartureCommand, DispatcherCommand, TrainEvent
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node

from metro_atc.core.atr.cost import CostWeights
from metro_atc.core.atr.dispatch import Dispatch, make_dispatcher
from metro_atc.core.atr.registry import REGULATORS
from metro_atc.core.atr.switch import RegulatorSwitch
from metro_atc.core.dispatcher_commands import KIND_REGULATOR
from metro_atc.core.line.scenario import ScenarioError, load_scenario
from metro_atc.core.validate import Rejections, bounds_for
from metro_atc.nodes import conversions as conv
from metro_atc.nodes.common import (OK, QOS_EVENTS, QOS_LATCHED, WARN, NodeConfigError,
                                    RuntimeParams, bulk_publisher, diag_status, run_nodes,
                                    spin_fast, static)


ATS_SLOW_PERIOD_S = 0.2
"""Wall time between two turns of the ATS's executor [s] (events are served at once)."""


class AtsRegulator(Node):
    """The ATS node (see module docstring)."""

    def __init__(self, **kwargs: Any) -> None:
        """Declare parameters, build the timetable, create publishers and the event sub."""
        super().__init__("ats_regulator", **kwargs)
        self.scenario_name = static(self, "scenario", "taipei_blue",
                                    "embedded scenario name or path to a scenario YAML")
        self.regulator = static(self, "regulator", "none", "regulator: " + REGULATORS.help(),
                                choices=REGULATORS.names)
        weights_file = static(self, "weights_file", "",
                              "dhp/aoc weights ('' : the shipped or cached weights trained "
                              "on this line; weights of another line are refused)")
        q = static(self, "cost_q", 1.0, "schedule-deviation weight q (Lin 2010a, eq. 17)",
                   1e-6, 1e6)
        r = static(self, "cost_r", 0.1, "control-effort weight r (Lin 2010a, eq. 17)", 1e-6, 1e6)
        horizon = static(self, "horizon", 40, "adjustable services K (Lin 2010a, eq. 17)",
                         1, 1000)
        w_energy = static(self, "energy_weight", 1.0,
                          "elqr: weight w_E of one service's traction energy (Sheu 2011)",
                          0.0, 1000.0)
        hold_max = static(self, "hold_max_s", 60.0,
                          "longest hold a regulator may add at a platform [s]", 0.0, 600.0)
        tolerance = static(self, "dwell_cut_tolerance_s", 30.0,
                           "a regulator's dwell cut never closes the doors before the "
                           "timetable departure plus this [s]", 0.0, 3600.0)
        try:
            scn = load_scenario(self.scenario_name)
            self.bounds = bounds_for(scn)
            cost = CostWeights(q=q, r=r, horizon=horizon)

            def build(name: str, weights: str) -> Any:
                return make_dispatcher(scn, name, weights, cost, w_energy, hold_max, tolerance)
            self.dispatcher = RegulatorSwitch(build(self.regulator, weights_file),
                                              self.regulator, build)
        except ScenarioError as exc:
            raise NodeConfigError(str(exc)) from None
        except (ValueError, FileNotFoundError) as exc:
            raise NodeConfigError(f"regulator '{self.regulator}': {exc}") from None
        self.tt = self.dispatcher.tt
        self.ids = list(self.tt.train_ids)
        n, m = len(self.ids), len(self.tt.station_names)
        self.cmd_seq = np.zeros(n, dtype=np.int64)
        self.rejected = 0
        self.rejections = Rejections()
        """Rejected events per kind (:mod:`metro_atc.core.validate`)."""
        self.index = {t: i for i, t in enumerate(self.ids)}
        self.last_seq: dict[str, int] = {}
        """Sequence number of the last accepted event per train (events are 1, 2, ...)."""
        self.decision_time_s: list[float] = []
        self._rejected_at_tick = 0
        self.rt = RuntimeParams(self, self.health)
        self.pubs = [bulk_publisher(self, DepartureCommand, f"/{t}/departure_command",
                                    QOS_LATCHED) for t in self.ids]
        # the event subscription is served by spin_fast (a direct wait set): the executor
        # would rebuild its wait set from every entity of the node on each /clock tick
        self.event_sub = self.create_subscription(TrainEvent, "/line/events", self._on_event,
                                                  QOS_EVENTS)
        from metro_atc.nodes.dispatch_msgs import APPLIED_TOPIC
        self.switch_sub = self.create_subscription(DispatcherCommand, APPLIED_TOPIC,
                                                   self._on_dispatcher, QOS_EVENTS)
        self._switch_logged = (0, 0)
        for d in self.dispatcher.initial():  # idempotent if replayed after a restart
            self._publish(d)
        self.get_logger().info(f"regulator '{self.regulator}' on '{self.scenario_name}': "
                               f"{n} trains, {m} stations")

    def health(self) -> list[DiagnosticStatus]:
        """/diagnostics: regulator, decisions and their time; WARN on rejected events."""
        t = np.asarray(self.decision_time_s[-1000:]) * 1e3
        new = self.rejected - self._rejected_at_tick
        self._rejected_at_tick = self.rejected
        level, msg = (WARN, f"{new} events rejected in the last period") if new else \
            (OK, f"regulating ({self.regulator})")
        return [diag_status("ats_regulator: regulation", "ats", level, msg, {
            "regulator": self.regulator, "decisions": len(self.decision_time_s),
            "decision_time_median_ms": float(np.median(t)) if t.size else float("nan"),
            "decision_time_max_ms": float(t.max()) if t.size else float("nan"),
            "rejected_events": self.rejected,
            "regulator_switches": len(self.dispatcher.switched),
            "regulator_switches_late": self.dispatcher.late,
            "regulator_switches_failed": len(self.dispatcher.failed),
            "rejected_by_kind": self.rejections.summary(), "trains": len(self.ids)})]

    def _on_event(self, msg: TrainEvent) -> None:
        """Validate an event (conv.event_from_msg) and hand it to the dispatcher."""
        t0 = time.perf_counter()
        try:
            ev = conv.event_from_msg(msg, "/line/events", self.index, self.bounds,
                                     self.last_seq)
            self.last_seq[ev["train_id"]] = ev["sequence"]
            d = conv.guarded("/line/events", self.dispatcher.on_event, ev["train_id"],
                             ev["station"], ev["kind"], ev["t_s"])
        except conv.MessageRejected as exc:
            self.rejected += 1
            line = self.rejections.note("event", exc, time.monotonic())  # per-kind rate limit
            if line is not None:
                self.get_logger().warning(line)
            return
        if len(self.dispatcher.switched) + len(self.dispatcher.failed) \
                != sum(self._switch_logged):
            self._log_switches()
        if d is not None:
            self.decision_time_s.append(time.perf_counter() - t0)
            self._publish(d)

    def _on_dispatcher(self, msg: Any) -> None:
        """A dispatcher's applied command: a regulator switch is announced (never raises)."""
        try:
            if int(msg.kind) != KIND_REGULATOR:
                return
            if self.dispatcher.announce(int(msg.sequence), float(msg.from_s),
                                        str(msg.regulator), str(msg.weights_file)):
                self.get_logger().info(f"regulator switch to '{msg.regulator}' from "
                                       f"t={float(msg.from_s):.2f} s")
        except (TypeError, ValueError, AttributeError) as exc:
            self.rejected += 1
            self.get_logger().warning(f"unreadable dispatcher command: {exc}")

    def _log_switches(self) -> None:
        """Log the switches made, failed or late since the last call."""
        sw = self.dispatcher
        done, failed = self._switch_logged
        for t, name in sw.switched[done:]:
            self.get_logger().info(f"regulating with '{name}' from t={t:.2f} s")
        for why in sw.failed[failed:]:
            self.get_logger().error(f"regulator switch failed, the previous one kept: {why}")
        self._switch_logged = (len(sw.switched), len(sw.failed))
        self.regulator = sw.regulator

    def close(self) -> None:
        """Log the decision count and time (called once at shutdown)."""
        t = np.asarray(self.decision_time_s) * 1e3
        if t.size:
            self.get_logger().info(
                f"{t.size} decisions: median {np.median(t):.3f} ms, p99 "
                f"{np.percentile(t, 99):.3f} ms, max {t.max():.3f} ms; {self.rejected} "
                f"events rejected")

    def _publish(self, d: Dispatch) -> None:
        i = d.train
        self.cmd_seq[i] += 1
        self.pubs[i].publish(conv.departure_msg(self.ids[i], d.station, d.departure_s,
                                                d.running_s, d.dwell_limit_s, self.regulator,
                                                int(self.cmd_seq[i]), d.departure_s))


def main(args: Sequence[str] | None = None) -> int:
    """Entry point of the ``ats_regulator`` executable."""
    def loop(executor: SingleThreadedExecutor, nodes: Sequence[Node]) -> None:
        subs = [s for n in nodes if isinstance(n, AtsRegulator)
                for s in (n.event_sub, n.switch_sub)]
        # events wake the poller at once; the executor (parameter services, the
        # diagnostics timer, /clock) is served 5 times a second: at 20 (the default) the
        # idle ATS spent ~1 s of CPU per 1 800 s simulated rebuilding its wait set
        spin_fast(executor, nodes, subs, slow_period_s=ATS_SLOW_PERIOD_S)

    return run_nodes(lambda: [AtsRegulator()], loop, args)


if __name__ == "__main__":
    raise SystemExit(main())
