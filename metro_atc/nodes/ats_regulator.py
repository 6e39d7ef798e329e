"""ats_regulator node: timetable and automatic train regulation (ATS).

Subscribes to ``/line/events`` (transient-local: a restarted ATS replays the history and
rebuilds its state) and publishes one transient-local ``/<train>/departure_command`` per
decision: the regulated departure time from the station a train has just reached, the
target running time to the next station and the target dwell there.

Regulators (parameter ``regulator``): ``none`` keeps the timetable (seed 000 eq. 10);
``lqr``, ``dhp`` and ``aoc`` run :class:`metro_atc.core.atr.node_core.AtsRegulatorCore`
(seed 000 eq. 17-48) on the scenario's traffic model
(:func:`metro_atc.core.bridge.atr_line_for`). On the arrival of train i at station j the
core's decision for station j gives the departure time, and its decision for station j+1
(made now, with the arrival known) the running time to j+1 and the dwell there.
"""

from __future__ import annotations

import math
import time
from typing import Any, Sequence

import numpy as np
from metro_atc_msgs.msg import DepartureCommand, TrainEvent
from rclpy.node import Node

from metro_atc.core.atr.cost import CostWeights
from metro_atc.core.atr.node_core import AtsRegulatorCore
from metro_atc.core.atr.regulators import default_weights_path
from metro_atc.core.bridge import atr_line_for, timetable_for
from metro_atc.core.plant.scenario import ScenarioError, load_scenario
from metro_atc.nodes import conversions as conv
from metro_atc.nodes.common import (QOS_EVENTS, QOS_LATCHED, NodeConfigError, bulk_publisher,
                                    declare, run_nodes)

REGULATORS = ("none", "lqr", "dhp", "aoc")


class AtsRegulator(Node):
    """The ATS node (see module docstring)."""

    def __init__(self, **kwargs: Any) -> None:
        """Declare parameters, build the timetable, create publishers and the event sub."""
        super().__init__("ats_regulator", **kwargs)
        self.scenario_name = declare(self, "scenario", "taipei_blue",
                                     "embedded scenario name or path to a scenario YAML")
        self.regulator = declare(self, "regulator", "none",
                                 "regulator: none (timetable) | lqr | dhp | aoc")
        weights_file = declare(self, "weights_file", "",
                               "dhp/aoc weights ('' : the shipped taipei_blue weights)")
        q = declare(self, "cost_q", 1.0, "schedule-deviation weight q (seed 000 eq. 17)",
                    1e-6, 1e6)
        r = declare(self, "cost_r", 0.1, "control-effort weight r (seed 000 eq. 17)", 1e-6, 1e6)
        horizon = declare(self, "horizon", 40, "adjustable services K (seed 000 eq. 17)",
                          1, 1000)
        if self.regulator not in REGULATORS:
            raise NodeConfigError(f"parameter regulator='{self.regulator}' is not one of "
                                  f"{', '.join(REGULATORS)}")
        try:
            scn = load_scenario(self.scenario_name)
        except ScenarioError as exc:
            raise NodeConfigError(str(exc)) from None
        self.tt = timetable_for(scn)
        self.ids = list(self.tt.train_ids)
        self.core: AtsRegulatorCore | None = None
        if self.regulator != "none":
            line = atr_line_for(scn, self.tt)
            path = weights_file or (str(default_weights_path(self.regulator, "taipei_blue"))
                                    if self.regulator in ("dhp", "aoc") else None)
            try:
                self.core = AtsRegulatorCore(
                    line, self.regulator, weights_path=path,
                    cost=CostWeights(q=q, r=r, horizon=horizon), train_ids=self.ids,
                    first_dispatch_s=float(self.tt.departure_s[0, 0]),
                    departure_table_s=self.tt.departure_s)
            except (ValueError, FileNotFoundError) as exc:
                raise NodeConfigError(f"regulator '{self.regulator}': {exc}") from None
        self.index = {t: i for i, t in enumerate(self.ids)}
        n, m = len(self.ids), len(self.tt.station_names)
        self.n_st = m
        self.last_seq = np.zeros(n, dtype=np.int64)
        self.arrival_s = np.full((n, m), math.nan)
        self.departure_s = np.full((n, m), math.nan)
        self.commanded = np.zeros((n, m), dtype=bool)
        self.cmd_seq = np.zeros(n, dtype=np.int64)
        self.rejected = 0
        self.decision_time_s: list[float] = []
        self._last_warn: dict[str, float] = {}
        self.pubs = [bulk_publisher(self, DepartureCommand, f"/{t}/departure_command",
                                    QOS_LATCHED) for t in self.ids]
        self.create_subscription(TrainEvent, "/line/events", self._on_event, QOS_EVENTS)
        for i in range(n):  # first departures (idempotent if replayed after a restart)
            self._command(i, 0, self.tt.departure_s[i, 0])
        self.get_logger().info(f"regulator '{self.regulator}' on '{self.scenario_name}': "
                               f"{n} trains, {m} stations")

    def _warn(self, text: str) -> None:
        """Count a rejection; log it at most once per second per kind of message."""
        now = time.monotonic()
        self.rejected += 1
        key = text[:48]
        if now - self._last_warn.get(key, -math.inf) > 1.0:
            self._last_warn[key] = now
            self.get_logger().warning(text)

    def _on_event(self, msg: TrainEvent) -> None:
        try:
            ev = conv.event_from_msg(msg, "/line/events")
            i = conv.train_index(ev["train_id"], self.index, "/line/events")
        except conv.MessageRejected as exc:
            self._warn(f"rejected event: {exc}")
            return
        j = ev["station"]
        if not 0 <= j < self.n_st:
            self._warn(f"rejected event: /line/events.station_index={j} out of range")
            return
        if ev["sequence"] <= self.last_seq[i]:
            self._warn(f"rejected event: /line/events sequence {ev['sequence']} of "
                       f"{self.ids[i]} is not after {self.last_seq[i]} (out of order/duplicate)")
            return
        self.last_seq[i] = ev["sequence"]
        if self.core is not None:
            try:
                self.core.on_event(ev["train_id"], j, ev["kind"], ev["t_s"])
            except ValueError as exc:
                self._warn(f"rejected event: /line/events: {exc}")
                return
        if ev["kind"] == "arrival":
            self.arrival_s[i, j] = ev["t_s"]
            if j < self.n_st - 1:
                t0 = time.perf_counter()
                dep, run, dwell = self.decide(i, j, ev["t_s"])
                self.decision_time_s.append(time.perf_counter() - t0)
                self._command(i, j, dep, run, dwell)
        else:
            self.departure_s[i, j] = ev["t_s"]

    def decide(self, i: int, j: int, arrival_s: float) -> tuple[float, float, float]:
        """Departure of train i from station j [s], running time to j+1 [s], dwell at j+1 [s].

        ``none``: the timetable. Regulators: the core's decisions for stations j and j+1.
        """
        nxt = min(j + 1, self.n_st - 1)
        if self.core is None:
            return (float(self.tt.departure_s[i, j]), float(self.tt.running_s[j]),
                    float(self.tt.dwell_s[i, nxt]))
        here = self.core.departure_command(self.ids[i], j)
        ahead = self.core.departure_command(self.ids[i], j + 1)
        # trains never leave before the timetable (as with ``none``): the regulator holds
        # (positive adjustments) and shortens running times and dwells of late trains
        dep = max(float(here.departure_time_s), float(self.tt.departure_s[i, j]))
        return dep, float(ahead.target_running_time_s), float(ahead.target_dwell_s)

    def _command(self, i: int, j: int, departure_s: float, running_s: float | None = None,
                 dwell_s: float | None = None) -> None:
        if j >= self.n_st - 1:
            return
        if running_s is None or dwell_s is None:
            departure_s, running_s, dwell_s = self._first(i, j, departure_s)
        self.commanded[i, j] = True
        self.cmd_seq[i] += 1
        msg = conv.departure_msg(self.ids[i], j, departure_s, running_s, dwell_s,
                                 self.regulator, int(self.cmd_seq[i]), departure_s)
        self.pubs[i].publish(msg)

    def _first(self, i: int, j: int, departure_s: float) -> tuple[float, float, float]:
        """Command for a station without an arrival event (first departures)."""
        nxt = min(j + 1, self.n_st - 1)
        if self.core is None:
            return departure_s, float(self.tt.running_s[j]), float(self.tt.dwell_s[i, nxt])
        ahead = self.core.departure_command(self.ids[i], j + 1)
        return (departure_s, float(ahead.target_running_time_s), float(ahead.target_dwell_s))


def main(args: Sequence[str] | None = None) -> int:
    """Entry point of the ``ats_regulator`` executable."""
    return run_nodes(lambda: [AtsRegulator()], None, args)


if __name__ == "__main__":
    raise SystemExit(main())
