"""What a service day leaves behind: one record type per observed fact (ROS-free, SI units).

The plant of a two-direction day produces these records; the day's KPIs and pictures read
them.  Nothing else is shared between the two sides, so either can be tested alone (the
KPIs on records built from the planned timetable, the plant against its own trace).

Conventions: ``direction`` is ``"up"`` (from the line's first station to its last, the
order of the scenario's station list) or ``"down"``; ``station`` is the index of the
station in that list, whatever the direction; instants are seconds of simulated time
after midnight; ``nan`` marks an instant that does not exist (no scheduled arrival at a
trip's origin) or did not happen (a stop not reached).
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, Sequence, Tuple

DIRECTIONS: Tuple[str, str] = ("up", "down")
"""The two running directions: ``up`` = first station -> last station of the line."""

DEPOT_MOVES: Tuple[str, str] = ("pull_out", "pull_in")
"""Depot movements: into service from the depot, out of service back into it."""


@dataclass(frozen=True)
class StopRecord:
    """One train's call at one station on one trip, scheduled and actual [s]."""

    train: str
    trip_id: str
    direction: str
    station: int
    sched_arr_s: float
    sched_dep_s: float
    arr_s: float
    dep_s: float

    @property
    def arrival_delay_s(self) -> float:
        """Actual minus scheduled arrival [s] (nan when either is missing)."""
        return self.arr_s - self.sched_arr_s

    @property
    def departure_delay_s(self) -> float:
        """Actual minus scheduled departure [s] (nan when either is missing)."""
        return self.dep_s - self.sched_dep_s


@dataclass(frozen=True)
class TurnbackRecord:
    """One turnback of a train at a terminus: the trip it ended and the trip it starts.

    ``arr_s``: arrival of the ended trip at the terminus platform; ``dep_s``: departure of
    the next trip from the terminus; ``planned_layover_s`` is the timetable's scheduled
    departure minus scheduled arrival, ``min_turnback_s`` the layout's minimum turnback,
    so the buffer is their difference (Lin 2010a, Experiment 2: 210 s at 105 s headway).
    """

    train: str
    terminus: str
    arr_trip_id: str
    dep_trip_id: str
    arr_s: float
    dep_s: float
    sched_arr_s: float
    sched_dep_s: float
    min_turnback_s: float

    @property
    def buffer_s(self) -> float:
        """Scheduled layover minus the minimum turnback [s]."""
        return (self.sched_dep_s - self.sched_arr_s) - self.min_turnback_s

    @property
    def terminal_delay_s(self) -> float:
        """Arrival delay of the ended trip at the terminus [s]."""
        return self.arr_s - self.sched_arr_s

    @property
    def carried_delay_s(self) -> float:
        """Departure delay of the next trip [s] (0 when it left on time or early)."""
        d = self.dep_s - self.sched_dep_s
        return max(0.0, d) if math.isfinite(d) else d


@dataclass(frozen=True)
class DepotRecord:
    """A depot movement: ``kind`` in DEPOT_MOVES at terminus ``terminus`` at ``t_s`` [s]."""

    train: str
    kind: str
    terminus: str
    t_s: float
    sched_t_s: float


def write_records_csv(records: Sequence[Any], path: Path) -> None:
    """Write records of one type as CSV: a header of their fields, one row per record.

    Floats are written with ``repr`` (exact: a reader gets the same bits back); ``nan``
    for an instant that does not exist or did not happen.
    """
    rows = list(records)
    names = [f.name for f in fields(rows[0])] if rows else ["(no records)"]
    with path.open("w", encoding="utf-8", newline="") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(names)
        for r in rows:
            w.writerow([repr(v) if isinstance(v, float) else v
                        for v in (getattr(r, n) for n in names)])
