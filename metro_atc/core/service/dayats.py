"""The ATS of a two-direction service day: the departure decisions of both directions.

:class:`DayAts` takes the trip events of a day (arrival / departure of a trip at a station,
the turnback link's earliest departure of a trip from its terminus) and returns departure
decisions (:class:`DayDecision`).  It knows the day's timetable (:class:`DaySchedule`) and
nothing of the plant, so the ROS-free day (:class:`metro_atc.core.service.dayplant.
DayPlant`) and a ROS node fed from the trains' events can host the same object.

**One dispatcher per direction.**  Each direction's trips, in timetable order (departure
from the origin), are the services of one :class:`metro_atc.core.atr.dispatch.
AtsDispatcher`, the law the one-way ``ats_regulator`` runs (called, not copied): the
timetable (``none``) or the regulator's u_j applied to what is left of it at each arrival
(dwell hold or cut, running-time target; see that module).  Why the trips and not the
trains: Lin 2010a's traffic model (eq. 1-5) is indexed by *service*: t(k) is the vector of
departure instants along the line, the services dispatched from the first station one
headway apart (eq. 10), and its staggered state at the decision (service m, station j) holds
service m + j - 1 - i at station i (:class:`metro_atc.core.atr.node_core.AtsRegulatorCore`):
the trips of one direction in the order they leave the origin.  They keep that order at
every station (no overtaking on a track; the departure berths of a terminus serve trips in
timetable order), so the state's neighbours are the trip ahead and the trip behind on the
same track, whichever train runs them.  Which train runs a trip (the circulation) is not in
Lin 2010a's state: it enters through the turnback link only, as a bound on the trip's first
departure (:meth:`DayAts.first_departure`, never before the previous trip's arrival plus the
minimum turnback; the interlocking still has to set the departure route).

**Models.**  Each direction is regulated with its own traffic model
(:func:`metro_atc.core.service.regulation.peak_lines`: the line as seen in that direction,
at the peak period's flow factor, the model the shipped AOC / DHP weights of that direction
were trained on, found by traffic-model hash; weights of the other direction or of another
line are refused by that hash).  The model gives the adjustments u (Lin 2010a, eq. 5: a
deviation from the schedule D); the schedule they are applied to is the day's own: the
dispatcher's timetable is the trips' scheduled instants, and a regulated running-time
target is the trip's scheduled run plus the running part of u (the model's scheduled run of
a leg can differ from the plant's: the down model runs the up running times backwards).
The peak model regulates the whole day (the shipped weights exist for the peak only); off
the peak its c_j H and stage spacing overestimate how a delay grows.

The dispatcher's scheduled run of leg j (:attr:`Timetable.running_s`, used for the part of
u already spent on the run into j) is the median over the direction's trips; each trip's own
is scaled to its planned trip time (within 0.05 s of the median with the plant's trip times,
a few seconds with the period table's).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Dict, Mapping, Optional, Sequence, Tuple

import numpy as np

from metro_atc.core.atr.blue_line import LineData
from metro_atc.core.atr.cost import CostWeights
from metro_atc.core.atr.dispatch import AtsDispatcher, Dispatch
from metro_atc.core.atr.fingerprint import line_hash
from metro_atc.core.atr.node_core import AtsRegulatorCore
from metro_atc.core.atr.registry import REGULATORS, TRAINED
from metro_atc.core.atr.regulators import make_regulator, shipped_weights
from metro_atc.core.line.scenario import Scenario
from metro_atc.core.line.service import Timetable

from .circulation import Trip
from .records import DIRECTIONS, StopRecord, TurnbackRecord


@dataclass(frozen=True)
class DirectionSchedule:
    """The scheduled trips of one direction, in timetable order (SI units).

    ``stations``: line station index of each call in running order (up: 0..N-1, down:
    N-1..0); ``origin`` / ``destination``: the termini's station codes; per trip m and call
    p: ``departure_s[m, p]`` (nan at the destination), ``arrival_s[m, p]`` (nan at the
    origin) [s]; ``running_s[m, p]``: the running-time target the timetable gives for the
    run from call p to p+1 [s]; per leg ``min_running_s[p]`` (flat out) [s];
    ``positions_m[p]``: path coordinate of the call's stop, increasing along the run [m].
    """

    direction: str
    trip_ids: Tuple[str, ...]
    stations: Tuple[int, ...]
    origin: str
    destination: str
    departure_s: np.ndarray
    arrival_s: np.ndarray
    running_s: np.ndarray
    min_running_s: np.ndarray
    positions_m: np.ndarray

    def __post_init__(self) -> None:
        """Check shapes, order and finiteness; ValueError (one line)."""
        n, k = len(self.trip_ids), len(self.stations)
        d = self.direction
        if d not in DIRECTIONS:
            raise ValueError(f"direction must be one of {DIRECTIONS}, got {d!r}")
        if n == 0 or k < 2:
            raise ValueError(f"{d}: a direction schedule needs trips and >= 2 calls")
        if len(set(self.trip_ids)) != n:
            raise ValueError(f"{d}: trip ids must be unique")
        for name, arr, shape in (("departure_s", self.departure_s, (n, k)),
                                 ("arrival_s", self.arrival_s, (n, k)),
                                 ("running_s", self.running_s, (n, k - 1)),
                                 ("min_running_s", self.min_running_s, (k - 1,)),
                                 ("positions_m", self.positions_m, (k,))):
            if np.shape(arr) != shape:
                raise ValueError(f"{d}: {name} has shape {np.shape(arr)}, expected {shape}")
        if not (np.all(np.isfinite(self.departure_s[:, :-1]))
                and np.all(np.isfinite(self.arrival_s[:, 1:]))
                and np.all(np.isfinite(self.running_s))):
            raise ValueError(f"{d}: scheduled instants and running times must be finite")
        if np.any(np.diff(self.departure_s[:, 0]) < 0.0):
            raise ValueError(f"{d}: trips must be in timetable order (origin departures)")

    def timetable(self) -> Timetable:
        """The one-way :class:`Timetable` of these trips (the dispatcher's)."""
        dep, arr = self.departure_s, self.arrival_s
        dwell = np.where(np.isfinite(dep - arr), dep - arr, 0.0)
        return Timetable(list(self.trip_ids), [str(s) for s in self.stations],
                         np.asarray(self.positions_m, dtype=float), dep, arr,
                         np.median(self.running_s, axis=0), np.asarray(self.min_running_s,
                                                                       dtype=float), dwell)


@dataclass(frozen=True)
class DaySchedule:
    """The day's timetable as the ATS sees it: a :class:`DirectionSchedule` per direction.

    ``min_dwell_s``: the shortest dwell a cut may command [s] (the line's minimum dwell).
    """

    directions: Mapping[str, DirectionSchedule]
    min_dwell_s: float


@dataclass(frozen=True)
class DayDecision:
    """One departure decision for a trip at a station (times and durations in s).

    ``station``: line station index; ``departure_s``: held until then; ``running_s``: the
    running-time target to the next call; ``dwell_limit_s``: nan or a dwell cut (doors close
    that long after the arrival, :meth:`metro_atc.core.plant.line.LineSim.set_departure`);
    ``adjustment_s``: the dwell adjustment applied (0 for the timetable).
    """

    trip_id: str
    station: int
    departure_s: float
    running_s: float
    dwell_limit_s: float
    adjustment_s: float = 0.0


class DayAts:
    """Departure decisions of a day's trips, both directions (module docstring)."""

    def __init__(self, schedule: DaySchedule, regulator: str = "none",
                 lines: Optional[Mapping[str, LineData]] = None,
                 scenario: Optional[Scenario] = None,
                 weights: Optional[Mapping[str, str]] = None,
                 cost: Optional[CostWeights] = None, hold_max_s: float = 60.0,
                 cut_tolerance_s: float = 30.0) -> None:
        """The ATS of ``schedule`` with ``regulator`` (one of ``REGULATORS``).

        ``lines[direction]``: that direction's traffic model (a regulator other than
        ``none`` needs one per direction with trips; it must run from the direction's
        origin to its destination); ``scenario``: the line's scenario (``elqr``'s energy
        table); ``weights[direction]``: a weights file for ``aoc`` / ``dhp`` (default: the
        shipped weights trained on that direction's model, by traffic-model hash; none: a
        one-line ValueError, never a fallback); ``cost``, ``hold_max_s``,
        ``cut_tolerance_s``: see :func:`metro_atc.core.atr.dispatch.make_dispatcher`.
        ValueError / FileNotFoundError in one line for a bad choice.
        """
        REGULATORS.entry(regulator)
        self.regulator = regulator
        self.schedule = schedule
        lines = dict(lines or {})
        weights = dict(weights or {})
        for d in list(lines) + list(weights):
            if d not in DIRECTIONS:
                raise ValueError(f"unknown direction {d!r} (expected {', '.join(DIRECTIONS)})")
        if weights and regulator not in TRAINED:
            raise ValueError(f"weights are read by {' / '.join(TRAINED)} only, not by "
                             f"regulator {regulator}")
        self._disp: Dict[str, AtsDispatcher] = {}
        self._base: Dict[str, np.ndarray] = {}
        self._where: Dict[str, Tuple[str, int]] = {}
        self._call: Dict[str, Dict[int, int]] = {}
        self.weights_used: Dict[str, str] = {}
        """Weights file of each direction's trained regulator (empty otherwise)."""
        for d, ds in schedule.directions.items():
            if d != ds.direction:
                raise ValueError(f"schedule of {ds.direction!r} filed under {d!r}")
            core = None
            if regulator != "none":
                core = self._core(regulator, ds, lines.get(d), scenario, weights.get(d), cost)
            tt = ds.timetable()
            self._disp[d] = AtsDispatcher(tt, core, min_dwell_s=schedule.min_dwell_s,
                                          hold_max_s=hold_max_s,
                                          cut_tolerance_s=cut_tolerance_s)
            # the scheduled run a decision's running target is measured against
            self._base[d] = (np.asarray(core.line.run_s, dtype=float) if core is not None
                             else np.asarray(tt.running_s, dtype=float))
            for m, tid in enumerate(ds.trip_ids):
                if tid in self._where:
                    raise ValueError(f"trip {tid!r} is in both directions")
                self._where[tid] = (d, m)
            self._call[d] = {st: p for p, st in enumerate(ds.stations)}

    def _core(self, name: str, ds: DirectionSchedule, line: Optional[LineData],
              scenario: Optional[Scenario], path: Optional[str],
              cost: Optional[CostWeights]) -> AtsRegulatorCore:
        """The regulator core of one direction on its traffic model (checked)."""
        d = ds.direction
        if line is None:
            raise ValueError(f"regulator {name}: no traffic model for the {d} direction")
        if (line.n_stations != len(ds.stations) or line.station_codes[0] != ds.origin
                or line.station_codes[-1] != ds.destination):
            raise ValueError(f"regulator {name}: the {d} traffic model runs "
                             f"{line.station_codes[0]}..{line.station_codes[-1]} "
                             f"({line.n_stations} stations), the {d} trips run {ds.origin}.."
                             f"{ds.destination} ({len(ds.stations)} calls)")
        if name in TRAINED:
            if path is None:
                found = shipped_weights(name, line)
                if found is None:
                    raise ValueError(f"regulator {name}: no weights trained on the {d} "
                                     f"direction's traffic model (hash "
                                     f"{line_hash(line)[:12]}); give weights for {d}")
                path = str(found)
            self.weights_used[d] = path
        w = cost if cost is not None else CostWeights()
        reg = make_regulator(name, line, w, path,
                             scenario=scenario if name == "elqr" else None)
        dep = np.array(ds.departure_s, dtype=float)
        arr = np.array(ds.arrival_s, dtype=float)
        dep[:, -1] = arr[:, -1]  # the core wants finite tables: a trip ends at its arrival
        arr[:, 0] = dep[:, 0]
        return AtsRegulatorCore(line, name, weights_path=path, cost=w,
                                train_ids=ds.trip_ids, first_dispatch_s=float(dep[0, 0]),
                                departure_table_s=dep, arrival_table_s=arr, regulator=reg)

    # ------------------------------------------------------------------ events in
    def _locate(self, trip_id: str, direction: Optional[str], station: int
                ) -> Tuple[str, int, int]:
        """(direction, trip index, call index) of a trip's call; ValueError (one line)."""
        if trip_id not in self._where:
            raise ValueError(f"unknown trip {trip_id!r}")
        d, m = self._where[trip_id]
        if direction is not None and direction != d:
            raise ValueError(f"trip {trip_id} runs {d}, not {direction!r}")
        if isinstance(station, bool) or not isinstance(station, (int, np.integer)) \
                or int(station) not in self._call[d]:
            raise ValueError(f"trip {trip_id}: station {station!r} is not one of its calls")
        return d, m, self._call[d][int(station)]

    def on_arrival(self, trip_id: str, direction: str, station: int, t_s: float
                   ) -> Optional[DayDecision]:
        """Arrival of ``trip_id`` at line station ``station`` at ``t_s`` [s].

        Returns the departure decision of an intermediate call, None at the destination.
        ValueError (one line, nothing recorded) for an unknown trip, a station it does not
        call at, a direction it does not run, a non-finite or out-of-order event.
        """
        d, m, p = self._locate(trip_id, direction, station)
        out = self._disp[d].on_event(trip_id, p, "arrival", t_s)
        return None if out is None else self._decision(d, m, int(station), out)

    def on_departure(self, trip_id: str, direction: str, station: int, t_s: float) -> None:
        """Departure of ``trip_id`` from line station ``station`` at ``t_s`` [s] (recorded).

        ValueError as :meth:`on_arrival`.
        """
        d, _, p = self._locate(trip_id, direction, station)
        self._disp[d].on_event(trip_id, p, "departure", t_s)

    def first_departure(self, trip_id: str, earliest_s: float) -> DayDecision:
        """Departure decision of ``trip_id`` from its origin: never before ``earliest_s`` [s].

        ``earliest_s``: the turnback link (the previous trip's arrival plus the minimum
        turnback, the end of the reversal), or the timetable for a trip that starts a
        spell out of the depot.  The decision: max(timetable, earliest) and the running
        target of the first run (:meth:`AtsDispatcher.first_departure`).
        """
        if trip_id not in self._where:
            raise ValueError(f"unknown trip {trip_id!r}")
        d, m = self._where[trip_id]
        out = self._disp[d].first_departure(trip_id, earliest_s)
        return self._decision(d, m, self.schedule.directions[d].stations[0], out)

    # ------------------------------------------------------------------ decisions out
    def _decision(self, d: str, m: int, station: int, out: Dispatch) -> DayDecision:
        """The dispatcher's command in the day's terms: the trip's own scheduled run + du."""
        p = out.station
        run = float(self.schedule.directions[d].running_s[m, p]) + (
            out.running_s - float(self._base[d][p]))
        return DayDecision(self.schedule.directions[d].trip_ids[m], station, out.departure_s,
                           run, out.dwell_limit_s, out.adjustment_s)


def first_trip_from(trips: Sequence[Trip], origin: str, start_s: float) -> Trip:
    """The first of ``trips`` leaving ``origin`` at or after ``start_s`` [s]; else ValueError."""
    cands = [t for t in trips if t.origin == origin and t.departure_s >= start_s]
    if not cands:
        raise ValueError(f"no trip leaves {origin} at or after t={start_s:.0f} s")
    return min(cands, key=lambda t: (t.departure_s, t.trip_id))


def _trip_ends(stops: Sequence[StopRecord], trip_id: str) -> Dict[str, float]:
    """Delays [s] of a trip: origin departure, last departure, worst departure, arrival."""
    cs = [r for r in stops if r.trip_id == trip_id]
    o = [r for r in cs if math.isnan(r.sched_arr_s)]
    e = [r for r in cs if math.isnan(r.sched_dep_s)]
    dep = sorted((r for r in cs if math.isfinite(r.departure_delay_s)),
                 key=lambda r: r.sched_dep_s)
    return {"departure_delay_s": o[0].departure_delay_s if o else math.nan,
            "last_departure_delay_s": dep[-1].departure_delay_s if dep else math.nan,
            "max_departure_delay_s": max((r.departure_delay_s for r in dep),
                                         default=math.nan),
            "arrival_delay_s": e[0].arrival_delay_s if e else math.nan}


def incident_report(stops: Sequence[StopRecord], turnbacks: Sequence[TurnbackRecord],
                    trip_id: str) -> Dict[str, Any]:
    """What a delayed trip and its train's next trip did, from the day's records [s].

    Reported: the trip's departure delay at its origin, at its last call before the
    destination (what the line leaves, before any wait at the terminus) and the worst one,
    its arrival delay at its destination; the turnback that follows (terminus, terminal
    delay, buffer, carried delay: the next trip's departure delay, at least 0) and the
    same delays of the next trip (``turnback`` and ``next_trip`` None when the train
    pulled in after the trip).  JSON-able;
    ValueError (one line) for a trip without records.
    """
    if not any(r.trip_id == trip_id for r in stops):
        raise ValueError(f"trip {trip_id!r} has no records (not run)")
    train = next(r.train for r in stops if r.trip_id == trip_id)
    out: Dict[str, Any] = {"trip_id": trip_id, "train": train, **_trip_ends(stops, trip_id),
                           "turnback": None, "next_trip": None}
    b = next((x for x in turnbacks if x.arr_trip_id == trip_id), None)
    if b is not None:
        out["turnback"] = {"terminus": b.terminus, "terminal_delay_s": b.terminal_delay_s,
                           "buffer_s": b.buffer_s, "carried_delay_s": b.carried_delay_s}
        out["next_trip"] = {"trip_id": b.dep_trip_id, **_trip_ends(stops, b.dep_trip_id)}
    return out


__all__ = ["DayAts", "DayDecision", "DaySchedule", "DirectionSchedule", "first_trip_from",
           "incident_report"]
