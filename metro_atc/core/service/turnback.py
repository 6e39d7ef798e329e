"""The turnback link between two trips of a train (ROS-free, SI units).

A train that ends trip k at terminus s at instant a can start trip k+1 from s no earlier
than a + turnback(s), the minimum turnback of that terminus (routes, reversal, platform
dwell; :attr:`metro_atc.core.service.day.TerminusSpec.min_turnback_s`).  The scheduled
layover minus that minimum is the turnback buffer (Lin 2010a, Experiment 2: 210 s at the
105 s peak headway); a terminal delay up to the buffer is absorbed, the rest is inherited
by trip k+1 as a departure delay (:func:`metro_atc.core.service.circulation.propagate_delay`,
called, not re-implemented).

:func:`turnback_link` is the one place that turns a terminal arrival delay into the
earliest departure of the next trip; the planned-day records
(:mod:`metro_atc.core.service.planned`) and the regulators' traffic-model hook
(:func:`metro_atc.core.atr.evaluation.simulate_linked`) both use it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping, Optional

from metro_atc.core.service.circulation import Block, propagate_delay


@dataclass(frozen=True)
class TurnbackLink:
    """What a late (or early) terminal arrival means for the train's next trip.

    ``terminus``: station code; ``sched_arr_s`` / ``sched_dep_s``: scheduled arrival of
    trip k and departure of trip k+1 [s]; ``min_turnback_s``, ``buffer_s`` (scheduled
    layover minus the minimum turnback) [s]; ``earliest_dep_s``: actual arrival plus the
    minimum turnback [s]; ``inherited_delay_s``: departure delay of trip k+1 when it leaves
    as soon as it can but never before its timetable, max(0, delay - buffer) [s].
    """

    terminus: str
    next_trip_id: str
    sched_arr_s: float
    sched_dep_s: float
    min_turnback_s: float
    buffer_s: float
    earliest_dep_s: float
    inherited_delay_s: float

    @property
    def departure_s(self) -> float:
        """Departure of trip k+1 run to time: max(timetable, earliest feasible) [s]."""
        return max(self.sched_dep_s, self.earliest_dep_s)


def link(terminus: str, next_trip_id: str, sched_arr_s: float, sched_dep_s: float,
         min_turnback_s: float, arrival_delay_s: float) -> TurnbackLink:
    """Turnback link from scheduled instants [s], the minimum turnback [s] and a delay [s].

    ValueError (one line) for non-finite inputs, a negative minimum turnback or a scheduled
    layover shorter than the minimum turnback (the timetable itself is infeasible).
    """
    for name, v in (("sched_arr_s", sched_arr_s), ("sched_dep_s", sched_dep_s),
                    ("min_turnback_s", min_turnback_s), ("arrival_delay_s", arrival_delay_s)):
        if not math.isfinite(v):
            raise ValueError(f"turnback at {terminus}: {name} must be finite, got {v!r}")
    if min_turnback_s < 0.0:
        raise ValueError(f"turnback at {terminus}: minimum turnback {min_turnback_s:g} s < 0")
    layover = sched_dep_s - sched_arr_s
    if layover < min_turnback_s:
        raise ValueError(f"turnback at {terminus}: scheduled layover {layover:.1f} s before "
                         f"{next_trip_id} is shorter than the minimum turnback "
                         f"{min_turnback_s:.1f} s")
    inherited = propagate_delay(arrival_delay_s, layover, min_turnback_s)
    return TurnbackLink(terminus, next_trip_id, sched_arr_s, sched_dep_s, min_turnback_s,
                        layover - min_turnback_s,
                        sched_arr_s + arrival_delay_s + min_turnback_s, inherited)


def turnback_link(block: Block, trip_index: int, arrival_delay_s: float,
                  turnback_s: Mapping[str, float]) -> Optional[TurnbackLink]:
    """Link after trip ``trip_index`` of ``block`` arrives ``arrival_delay_s`` late [s].

    ``turnback_s[s]``: minimum turnback at terminus s [s].  None when that trip is the
    block's last (the train pulls in: nothing is carried through the depot).
    """
    if not 0 <= trip_index < len(block.trips):
        raise ValueError(f"{block.train}: trip index {trip_index} outside "
                         f"0..{len(block.trips) - 1}")
    if trip_index == len(block.trips) - 1:
        return None
    a, b = block.trips[trip_index], block.trips[trip_index + 1]
    if a.destination not in turnback_s:
        raise ValueError(f"{block.train}: no minimum turnback for terminus {a.destination}")
    return link(a.destination, b.trip_id, a.arrival_s, b.departure_s,
                float(turnback_s[a.destination]), arrival_delay_s)
