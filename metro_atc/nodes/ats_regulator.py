"""ats_regulator node: timetable and automatic train regulation (ATS).

Subscribes to ``/line/events`` (transient-local: a restarted ATS replays the history and
rebuilds its state) and publishes one transient-local ``/<train>/departure_command`` per
decision: the regulated departure time from the station a train has just reached, the
target running time to the next station and the target dwell there.
"""

from __future__ import annotations

import math
import time
from typing import Any, Sequence

import numpy as np
from metro_atc_msgs.msg import DepartureCommand, TrainEvent
from rclpy.node import Node

from metro_atc.core.bridge import timetable_for
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
        if self.regulator not in REGULATORS:
            raise NodeConfigError(f"parameter regulator='{self.regulator}' is not one of "
                                  f"{', '.join(REGULATORS)}")
        try:
            scn = load_scenario(self.scenario_name)
        except ScenarioError as exc:
            raise NodeConfigError(str(exc)) from None
        self.tt = timetable_for(scn)
        self.ids = list(self.tt.train_ids)
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
        self._last_warn = 0.0
        self.pubs = [bulk_publisher(self, DepartureCommand, f"/{t}/departure_command",
                                    QOS_LATCHED) for t in self.ids]
        self.create_subscription(TrainEvent, "/line/events", self._on_event, QOS_EVENTS)
        for i in range(n):  # first departures (idempotent if replayed after a restart)
            self._command(i, 0, self.tt.departure_s[i, 0])
        self.get_logger().info(f"regulator '{self.regulator}' on '{self.scenario_name}': "
                               f"{n} trains, {m} stations")

    def _warn(self, text: str) -> None:
        now = time.monotonic()
        self.rejected += 1
        if now - self._last_warn > 1.0:
            self._last_warn = now
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
        if ev["kind"] == "arrival":
            self.arrival_s[i, j] = ev["t_s"]
            if j < self.n_st - 1:
                t0 = time.perf_counter()
                dep = self.decide(i, j, ev["t_s"])
                self.decision_time_s.append(time.perf_counter() - t0)
                self._command(i, j, dep)
        else:
            self.departure_s[i, j] = ev["t_s"]

    def decide(self, i: int, j: int, arrival_s: float) -> float:
        """Departure time of train i from station j [s] (timetable for ``none``)."""
        return float(self.tt.departure_s[i, j])

    def _command(self, i: int, j: int, departure_s: float) -> None:
        if j >= self.n_st - 1:
            return
        self.commanded[i, j] = True
        self.cmd_seq[i] += 1
        nxt = min(j + 1, self.n_st - 1)
        msg = conv.departure_msg(self.ids[i], j, departure_s, float(self.tt.running_s[j]),
                                 float(self.tt.dwell_s[i, nxt]), self.regulator,
                                 int(self.cmd_seq[i]), departure_s)
        self.pubs[i].publish(msg)


def main(args: Sequence[str] | None = None) -> int:
    """Entry point of the ``ats_regulator`` executable."""
    return run_nodes(lambda: [AtsRegulator()], None, args)


if __name__ == "__main__":
    raise SystemExit(main())
