"""The line_simulator's service day: a DayPlant stepped by the node's lockstep.

When the run's ``scenario`` names a service day (:func:`metro_atc.core.service.dayrun.
day_table`), the simulator's plant is the fleet plant of a
:class:`metro_atc.core.service.dayplant.DayPlant` (a slot per train of the circulation;
the per-train topics are the slots' train ids).  Each lockstep step the node calls
:meth:`DayHost.begin` before it publishes the fleet state (pull-outs from the depot, route
requests, movement authorities: what the ATOs answer depends on them) and
:meth:`DayHost.step` with the ATOs' efforts instead of the plant's own step (the plant
step, then the step's events, track occupancy, the interlockings' route grants and the
safety checks).  The ATO nodes compute the efforts; the day plant's own ATOs are not used.

What the graph's day leaves to the day plant, said in the KPIs (``day.not_in_graph``):
the departure decisions (the day plant's ATS, :class:`metro_atc.core.service.dayats.DayAts`
with the parameter ``day_regulator``, and its turnback link: the ``ats_regulator`` node is
not started), dispatcher commands (refused), checkpoints and resume.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from metro_atc.core.service.dayrun import (DayRun, day_plant, day_table, describe,
                                           load_day_run)

if TYPE_CHECKING:  # the day plant (its regulators: scipy) is imported when a day is built
    from metro_atc.core.service.dayplant import DayPlant

NOT_IN_GRAPH = ("departure decisions: the day plant's ATS (regulator and turnback link) in "
                "line_simulator (no ats_regulator node)", "dispatcher commands (refused)",
                "checkpoints and resume")
"""What a day run of the graph does not do through its nodes (in the KPIs and the log)."""


def day_run_for(scenario: str, trip_times: str = "plant") -> DayRun | None:
    """The day a run's ``scenario`` parameter names, or None (a one-way scenario)."""
    if day_table(scenario) is None:
        return None
    return load_day_run(scenario, trip_times)


@dataclass
class _Seen:
    """The day's stop errors and terminal delays read so far, and their figures."""

    errors: int = 0
    turnbacks: int = 0
    err_max_m: float = math.nan
    err_out: int = 0
    late_max_s: float = math.nan

    def take(self, errs_m: list[float], late_s: list[float]) -> None:
        """Read the new stop errors [m] (absolute) and terminal delays [s]."""
        self.errors += len(errs_m)
        self.turnbacks += len(late_s)
        self.err_max_m = max(errs_m, default=self.err_max_m) if math.isnan(self.err_max_m) \
            else max(errs_m + [self.err_max_m])
        self.err_out += sum(1 for e in errs_m if e > 0.30)
        self.late_max_s = max(late_s, default=self.late_max_s) \
            if math.isnan(self.late_max_s) else max(late_s + [self.late_max_s])


class DayHost:
    """A service day in the simulator node (see the module docstring)."""

    def __init__(self, run: DayRun, seed: int, regulator: str = "none") -> None:
        """Build the day's plant and set its clock to the first step; nothing runs yet.

        ``regulator``: the day's ATS regulator of both directions (:class:`DayAts`; aoc /
        dhp with the shipped weights of each direction).  ValueError in one line.
        """
        self.run = run
        self.regulator = str(regulator)
        self.dp: DayPlant = day_plant(run, seed=seed, regulator=regulator)
        self.dp.start()
        self.sim = self.dp.sim
        self.summary = describe(run, self.dp)
        self._seen = _Seen()
        """What :meth:`kpis` read of the day's lists so far (the status is published every
        few simulated seconds: each record is read once)."""

    @property
    def first_step(self) -> int:
        """The lockstep step index of the day's first step (its time / the control period).

        A state's time is its step index times the control period (the ATOs check the
        stamps so): the day's steps count from midnight, not from its first pull-out.
        """
        return int(round(self.dp.t_start / float(self.sim.control_period_s)))

    def begin(self) -> None:
        """Before the fleet state of a step: pull-outs, routes, authorities."""
        self.dp.begin_step()

    def step(self, effort: np.ndarray) -> Any:
        """The plant step with the ATOs' efforts, then the day's bookkeeping; the result."""
        return self.dp.end_step(effort)

    @property
    def done(self) -> bool:
        """Every train ran its trips and is back in the depot."""
        return self.dp.finished

    def kpis(self) -> dict[str, Any]:
        """The day's figures (``day`` in the KPIs): trips, depot, safety, stop errors."""
        dp = self.dp
        planned = sum(len(b.trips) for b in dp.circ.blocks)
        seen = self._seen
        seen.take([abs(e) for e in dp.stop_err[seen.errors:]],
                  [tb.terminal_delay_s for tb in dp.turnbacks[seen.turnbacks:]])
        return {"name": self.run.name, "trip_times": self.run.trip_times,
                "trips_planned": planned, "trips_run": dp.trips_run,
                "fleet": len(dp.trains),
                "trains_in_depot": sum(1 for tr in dp.trains if not tr.in_service),
                "trains_in_service": sum(1 for tr in dp.trains if tr.in_service),
                "train_steps": dp.train_steps,
                "route_conflicts": dp.route_conflicts,
                "missed_stops": int(dp.sim.stations.skipped_stops),
                "separation_violations": dp.sep_violations,
                "stop_error_max_m": seen.err_max_m, "stops_outside_0p30_m": seen.err_out,
                "forced_stops": len(dp.forced_err),
                "turnbacks": len(dp.turnbacks), "terminal_delay_max_s": seen.late_max_s,
                "depot_moves": len(dp.depot), "notes": dp.notes[:20],
                "not_in_graph": list(NOT_IN_GRAPH)}

    def end(self, reached_end: bool, t_s: float, cut_at_s: float | None) -> dict[str, Any]:
        """The ``finished`` / ``end`` fields of a day run: did the whole day run.

        Finished only when every planned trip ran, every train is back in the depot and
        the interlockings held (no route conflict: two trains on one route is no service).
        """
        k = self.kpis()
        missing = k["trips_planned"] - k["trips_run"]
        out = k["trains_in_service"]
        finished = bool(reached_end) and missing == 0 and out == 0 \
            and k["route_conflicts"] == 0
        if finished:
            end = (f"service day completed: {k['trips_run']} of {k['trips_planned']} trips, "
                   f"{k['fleet']} trains back in the depot")
        else:
            why = (f"{missing} of {k['trips_planned']} trips not run, {out} trains not back "
                   f"in the depot, {k['route_conflicts']} route conflicts")
            if not reached_end:
                end = f"stopped at t={t_s:.1f} s before the end of the day: {why}"
            elif cut_at_s is not None:
                end = f"cut at t={cut_at_s:.1f} s (--duration / max_sim_time_s): {why}"
            else:
                end = f"the day ended with {why}"
        return {"finished": finished, "incomplete_trips": missing,
                "cut_at_s": None if finished or cut_at_s is None else float(cut_at_s),
                "end": end}

    def write_outputs(self, out_dir: str) -> dict[str, str]:
        """The day's KPIs per period and direction and its pictures (:mod:`dayplots`)."""
        from metro_atc.core.service.dayplots import write_day_outputs
        dp = self.dp
        return write_day_outputs(self.run.plan, dp.stops, dp.turnbacks, dp.depot,
                                 Path(out_dir), energy_j=dp.trip_energy_j)


__all__ = ["DayHost", "NOT_IN_GRAPH", "day_run_for"]
