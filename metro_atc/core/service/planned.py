"""Records of a planned day with injected delays, without the plant (ROS-free, SI units).

Builds the :mod:`metro_atc.core.service.records` a two-direction day would leave, from the
day's circulation (:func:`metro_atc.core.service.day.run_day`) and timetable, so that the
day's KPIs and pictures can be tested without the line simulator.

Timetable of a trip (Lin 2010a, eq. 5/10): the steady-state offsets O_p of
:func:`metro_atc.core.atr.traffic.schedule_offsets` for the period's headway and the
direction's flow factor, on the line as seen in the running direction (the down direction
runs the station list backwards: running times, fixed dwells and boarding rates reversed).
Scheduled departure at the p-th call: z + O_p - O_0, arrival z + O_{p-1} + R_{p-1} - O_0
(z: the trip's departure; the trip time equals :func:`metro_atc.core.service.day.trip_time_s`).

Operation ("trips run to time", no recovery in running or dwell):

- arrival at call p: max(departure at p-1 + R_{p-1}, departure of the previous train of the
  same direction at that station + ``separation_s``) -- the knock-on law of the truth traffic
  model (:func:`metro_atc.core.atr.traffic.truth_step`, ``separation_min_s``);
- departure at call p: max(timetable, arrival + scheduled dwell) + injected delay at p;
- at the origin the train is ready at the turnback link's earliest departure
  (:func:`metro_atc.core.service.turnback.turnback_link`: previous arrival + minimum
  turnback) or, after a pull-out, at its timetable.

Trains of one direction keep their order at every station (no overtaking on a track), also
with ``separation_s = 0``.  With no injected delay every instant equals the timetable.
With ``separation_s = 0`` one delay d injected on a trip is carried to the train's next
trips exactly as :func:`metro_atc.core.service.circulation.propagate_block` predicts.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Dict, List, Optional, Tuple

import numpy as np

from metro_atc.core.atr.blue_line import LineData
from metro_atc.core.atr.traffic import schedule_offsets
from metro_atc.core.service.circulation import Circulation, Trip
from metro_atc.core.service.day import DayPlan, period_index
from metro_atc.core.service.records import DepotRecord, StopRecord, TurnbackRecord
from metro_atc.core.service.turnback import turnback_link


@dataclass(frozen=True)
class Incident:
    """An extra dwell of ``delay_s`` [s] on trip ``trip_id`` at station index ``station``."""

    trip_id: str
    station: int
    delay_s: float


@dataclass(frozen=True)
class DayRecords:
    """Everything a day leaves: stop calls, turnbacks, depot moves (see records)."""

    stops: Tuple[StopRecord, ...]
    turnbacks: Tuple[TurnbackRecord, ...]
    depot: Tuple[DepotRecord, ...]


def directed_line(line: LineData, direction: str) -> LineData:
    """The line as seen in ``direction``: ``up`` as is, ``down`` with every array reversed."""
    if direction == "up":
        return line
    if direction != "down":
        raise ValueError(f"direction must be 'up' or 'down', got {direction!r}")
    return dataclasses.replace(
        line, station_codes=line.station_codes[::-1], station_names=line.station_names[::-1],
        distance_m=line.distance_m[::-1].copy(), run_s=line.run_s[::-1].copy(),
        run_min_s=line.run_min_s[::-1].copy(), run_max_s=line.run_max_s[::-1].copy(),
        dwell_fixed_s=line.dwell_fixed_s[::-1].copy(),
        dwell_fixed_min_s=line.dwell_fixed_min_s[::-1].copy(),
        boarding_pax_h=line.boarding_pax_h[::-1].copy())


def trip_direction(plan: DayPlan, trip: Trip) -> str:
    """``up`` for a trip from the first terminus, ``down`` from the second."""
    if trip.origin == plan.termini[0].station:
        return "up"
    if trip.origin == plan.termini[1].station:
        return "down"
    raise ValueError(f"trip {trip.trip_id}: origin {trip.origin} is not a terminus")


def trip_schedule(plan: DayPlan, trip: Trip) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(station index, scheduled arrival, scheduled departure) per call [s] of ``trip``.

    Arrays in calling order; nan for the origin's arrival and the destination's departure.
    """
    direction = trip_direction(plan, trip)
    per = plan.periods[period_index(plan.periods, trip.departure_s)]
    flow = per.flow_up if direction == "up" else per.flow_down
    ln = directed_line(plan.line, direction)
    o = schedule_offsets(ln, per.headway_s, flow)
    n = ln.n_stations
    dep = np.full(n, math.nan)
    arr = np.full(n, math.nan)
    dep[:-1] = trip.departure_s + o[:-1] - o[0]
    arr[1:] = trip.departure_s + o[:-1] + ln.run_s - o[0]
    arr[-1] = trip.arrival_s   # the day's trip time (same sum, summed in another order)
    st = np.arange(n) if direction == "up" else np.arange(n)[::-1]
    return st, arr, dep


def planned_records(plan: DayPlan, circ: Circulation,
                    incidents: Optional[List[Incident]] = None,
                    separation_s: Optional[float] = None,
                    depot_lead_s: float = 0.0) -> DayRecords:
    """Records of the day ``circ`` (from ``run_day(plan)``) run with ``incidents``.

    ``separation_s`` [s]: least time from a departure to the next arrival at a platform
    (default: the line's ``separation_min_s``; 0: followers only keep their order);
    ``depot_lead_s`` [s]: a pull-out is recorded that long before the first departure.
    ValueError (one line) for an incident on an unknown trip or station, or a delay that is
    not finite and >= 0.
    """
    sep = plan.line.separation_min_s if separation_s is None else float(separation_s)
    if not (math.isfinite(sep) and sep >= 0.0):
        raise ValueError(f"separation_s must be finite and >= 0, got {separation_s!r}")
    trains = circ.trains()
    known = {t.trip_id for ts in trains.values() for t in ts}
    n = plan.line.n_stations
    extra: Dict[Tuple[str, int], float] = {}
    for inc in incidents or []:
        if inc.trip_id not in known:
            raise ValueError(f"incident on unknown trip {inc.trip_id!r}")
        if isinstance(inc.station, bool) or not 0 <= int(inc.station) < n:
            raise ValueError(f"incident on {inc.trip_id}: station {inc.station!r} outside "
                             f"0..{n - 1}")
        if not (math.isfinite(inc.delay_s) and inc.delay_s >= 0.0):
            raise ValueError(f"incident on {inc.trip_id}: delay must be finite and >= 0 s, "
                             f"got {inc.delay_s!r}")
        key = (inc.trip_id, int(inc.station))
        extra[key] = extra.get(key, 0.0) + float(inc.delay_s)
    tb = {t.station: t.min_turnback_s for t in plan.termini}
    # for each trip: its block and index in it (ready instant from the turnback link)
    where: Dict[str, Tuple[int, int]] = {}
    for bi, blk in enumerate(circ.blocks):
        for ti, t in enumerate(blk.trips):
            where[t.trip_id] = (bi, ti)
    order = sorted((t for blk in circ.blocks for t in blk.trips),
                   key=lambda t: (t.departure_s, t.trip_id))
    last_dep: Dict[Tuple[str, int], float] = {}      # (direction, station) -> departure
    ready: Dict[str, float] = {}                     # trip id -> earliest departure [s]
    actual_arr: Dict[str, float] = {}
    actual_dep0: Dict[str, float] = {}
    stops: List[StopRecord] = []
    turnbacks: List[TurnbackRecord] = []
    for trip in order:
        bi, ti = where[trip.trip_id]
        blk = circ.blocks[bi]
        direction = trip_direction(plan, trip)
        st, s_arr, s_dep = trip_schedule(plan, trip)
        prev_dep = math.nan
        for p, s in enumerate(st):
            s = int(s)
            if p == 0:
                a = math.nan
                start = ready.get(trip.trip_id, trip.departure_s)
                lead = last_dep.get((direction, s), -math.inf) + sep
                d = max(s_dep[p], start, lead)
            else:
                a = max(prev_dep + (s_arr[p] - s_dep[p - 1]),
                        last_dep.get((direction, s), -math.inf) + sep)
                d = (max(s_dep[p], a + (s_dep[p] - s_arr[p]))
                     if p < len(st) - 1 else math.nan)
            if p < len(st) - 1:
                d += extra.get((trip.trip_id, s), 0.0)
                last_dep[(direction, s)] = d
            stops.append(StopRecord(blk.train, trip.trip_id, direction, s, float(s_arr[p]),
                                    float(s_dep[p]), float(a), float(d)))
            prev_dep = d
            if p == 0:
                actual_dep0[trip.trip_id] = d
        actual_arr[trip.trip_id] = a
        lk = turnback_link(blk, ti, a - trip.arrival_s, tb)
        if lk is not None:
            ready[lk.next_trip_id] = lk.earliest_dep_s
    for blk in circ.blocks:
        for a_t, b_t in zip(blk.trips, blk.trips[1:]):
            turnbacks.append(TurnbackRecord(
                blk.train, a_t.destination, a_t.trip_id, b_t.trip_id,
                actual_arr[a_t.trip_id], actual_dep0[b_t.trip_id], a_t.arrival_s,
                b_t.departure_s, tb[a_t.destination]))
    depot: List[DepotRecord] = []
    for blk in circ.blocks:
        first, last = blk.trips[0], blk.trips[-1]
        depot.append(DepotRecord(blk.train, "pull_out", first.origin,
                                 actual_dep0[first.trip_id] - depot_lead_s,
                                 first.departure_s - depot_lead_s))
        depot.append(DepotRecord(blk.train, "pull_in", last.destination,
                                 actual_arr[last.trip_id], last.arrival_s))
    depot.sort(key=lambda r: (r.t_s, r.train))
    turnbacks.sort(key=lambda r: (r.arr_s, r.train))
    return DayRecords(tuple(stops), tuple(turnbacks), tuple(depot))
