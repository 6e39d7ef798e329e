"""A two-direction service day on the plant: ROS-free closed loop of plant, ATO, interlocking.

The whole fleet runs the unfolded loop of :mod:`metro_atc.core.service.loop` on one
:class:`metro_atc.core.plant.line.LineSim` (one slot per train: the same plant code and one
compiled step for all the trains; a train keeps its slot, brakes, sensors, energy meter and
disturbance stream across all its trips and blocks; a train in the depot is an idle slot:
out of service, it does not move, meter energy nor give sensor samples); the trains share
the platform queues (passengers left behind and the last departure per stop).  The
index order of the slots is not the order on the loop: the plant takes the end of
authority of every train from here (:meth:`LineSim.set_authority_ends`, one array per
step).  Per control period:

1. pull-outs due (``PULL_OUT_LEAD_S`` before a block's first trip) enter at the departure
   berth of their terminus when it is free (a platform neither occupied nor locked);
2. movement authority of each train (:meth:`LineSim.set_authority_ends`): a train inside a
   terminus (from its arrival route being set until its departure route is set) runs to
   the exit signal of its set route plus the route's overlap (the ATP margin where it has
   none) or stands at its berth; every train runs at most to the rear of the nearest train
   ahead outside the termini (sorted path positions, O(n log n), array operations) minus
   the ATP margin; a
   train on the open line runs to the entry signal of the terminus ahead until its arrival
   route is set (asked for by the first train before that signal only);
3. the ATO of each train in service (:class:`metro_atc.core.ato.onboard.OnboardAto`, a new
   one per lap: the cab changes at the reversal) gives the effort from the fleet state of
   the trains running (one :func:`fleet_state_rows` call); the plant steps once;
4. track occupancy from the trains' positions (their routes' sections over the loop)
   feeds :meth:`Interlocking.occupy` / ``clear``; arrivals at a route's exit signal report
   :meth:`Interlocking.arrived`; route requests (the next route of the train's itinerary,
   the siding / platform chosen free first; a departure route ``REQUEST_LEAD_S`` before
   its departure) are granted by :meth:`Interlocking.process`; a berth's departure is
   commanded when its next route is set;
5. the ATS (:class:`metro_atc.core.service.dayats.DayAts`, events in, decisions out)
   decides every departure: at an intermediate platform on the trip's arrival (the
   timetable with ``none``, a regulated hold, dwell cut and running-time target with
   ``lqr`` / ``dhp`` / ``aoc`` / ``elqr``); from a terminus the trip's first departure,
   never before max(scheduled departure, arrival + minimum turnback), so with the
   timetable a late arrival delays the next trip by max(0, delay - buffer)
   (:func:`metro_atc.core.service.circulation.propagate_delay`).

Independent checks every step: :func:`metro_atc.core.service.interlocking.check_safe` on
each interlocking, no section occupied by two trains, and the separation of the trains
outside the termini (gap to the train ahead below the ATP margin: a violation, as the plant's own
monitor counts it); the plant counts overspeed violations.

Output: :class:`metro_atc.core.service.records.StopRecord`, ``TurnbackRecord`` and
``DepotRecord`` lists and the KPIs of the run (:class:`DayResult`).
"""

from __future__ import annotations

import dataclasses
import math
import operator
import os
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Dict, List, Mapping, Optional, Sequence, Tuple

import numpy as np

from metro_atc.core.ato.cab import CabWatch
from metro_atc.core.ato.control_kernel import AUTH_MARGIN as AUTHORITY_MARGIN_M
from metro_atc.core.ato.onboard import OnboardAto
from metro_atc.core.ato.wiring import ato_wiring
from metro_atc.core.bridge import timetable_for
from metro_atc.core.closed_loop import STOP_WINDOW_M, ato_input
from metro_atc.core.line.scenario import Scenario
from metro_atc.core.plant.fleet import RUN
from metro_atc.core.plant.line import LineSim
from metro_atc.core.plant.stations import HELD_S
from metro_atc.core.plant.sensors import StepResult
from metro_atc.core.plant.views import fleet_state_rows

from .circulation import Block, Circulation, Trip
from .dayats import DayAts, DaySchedule, DirectionSchedule
from .interlocking import Interlocking, check_safe
from .loop import LoopLine, TerminusPath
from .records import DepotRecord, StopRecord, TurnbackRecord

PULL_OUT_LEAD_S = 120.0
"""A pulled-out train stands at its departure platform this long before its first trip [s]."""
REQUEST_LEAD_S = 30.0
"""A departure / reversal route is requested this long before the train may leave [s]."""
STABLE_AFTER_S = 600.0
"""A train that would stand longer than this at a terminus with a depot goes to the depot.

It is pulled out again for its next trip [s].  A tail track holds four trains (arrival
platform, two sidings, departure platform): at the 105-120 s peak headways a train standing
longer than ~5 headways (e.g. the surplus of the morning fleet circulating in the evening
peak, 840 s layovers) fills it and the trains behind queue on the line.
"""
_slot = operator.attrgetter("train_idx")


class _Dropped(list):  # type: ignore[type-arg]
    """A record list that keeps nothing; ``count_appended``: how many were appended."""

    count_appended = 0

    def append(self, item: Any) -> None:
        """Count ``item`` and drop it."""
        self.count_appended += 1


@dataclass(frozen=True)
class DayTerminus:
    """A terminus of the day: station code, minimum turnback [s], depot connection."""

    code: str
    min_turnback_s: float
    depot: bool


@dataclass(frozen=True)
class Breakdown:
    """Train ``train`` stands still for ``duration_s`` [s], then recovers (a disturbance).

    It breaks down at ``at_s`` [s] wherever it is, or, with ``section``, the first time at
    or after ``at_s`` that its front is inside that section of terminus ``terminus``'s
    layout (0: A, 1: B; e.g. on the points of a crossover).  Plant side:
    :meth:`metro_atc.core.plant.line.LineSim.breakdown`.
    """

    train: str
    at_s: float
    duration_s: float
    terminus: int = 0
    section: str = ""


@dataclass
class DayResult:
    """What a day on the plant leaves (records) and its figures (SI units)."""

    stops: List[StopRecord]
    turnbacks: List[TurnbackRecord]
    depot: List[DepotRecord]
    trips_planned: int
    trips_run: int
    trains_in_depot: int
    fleet: int
    atp_violations: int
    separation_violations: int
    route_conflicts: int
    missed_stops: int
    stop_errors_m: List[float]
    forced_stop_errors_m: List[float]
    atp_interventions: int
    sim_time_s: float
    wall_s: float
    finished: bool
    notes: List[str] = field(default_factory=list)
    sensor_samples: int = 0
    """Brake sensor samples read (train x instant; :meth:`DayPlant.run` with ``sensors``)."""
    cpu_split_s: Dict[str, float] = field(default_factory=dict)
    """CPU time of this process [s] in the plant step (with the sensor samples read), the
    ATOs (fleet state and control) and the rest (interlocking, authorities, bookkeeping):
    the figures to compare on a shared machine."""
    cpu_s: float = 0.0
    """CPU time of this process over the run [s]."""
    start_s: float = 0.0
    """Time the day's clock started at (just before the first pull-out) [s]."""
    train_steps: int = 0
    """Sum over the steps of the trains in service (the ATO calls' upper bound)."""

    def speed(self) -> Dict[str, float]:
        """Real-time factors of the run: simulated span over wall / CPU time, loop and plant.

        ``rtf``: (``sim_time_s`` - ``start_s``) / ``wall_s``; ``rtf_cpu``: the same span over
        the CPU time; ``plant_rtf_cpu``: over the plant step's CPU time alone (the ROS-free
        core, with the sensor samples when they were read); ``cpu_us_per_train_step``: CPU
        time per train in service and step [us].
        """
        span = self.sim_time_s - self.start_s
        cs = self.cpu_split_s
        return {"sim_span_s": span, "rtf": span / max(self.wall_s, 1e-9),
                "rtf_cpu": span / max(self.cpu_s, 1e-9),
                "plant_rtf_cpu": span / max(cs.get("plant", 0.0), 1e-9),
                "cpu_us_per_train_step": 1e6 * self.cpu_s / max(self.train_steps, 1),
                **{f"cpu_{k}_s": v for k, v in cs.items()}}

    def row(self) -> Dict[str, Any]:
        """JSON-friendly summary."""
        err = np.abs(np.asarray(self.stop_errors_m, dtype=float))
        return {"trips_planned": self.trips_planned, "trips_run": self.trips_run,
                "fleet": self.fleet, "trains_in_depot": self.trains_in_depot,
                "atp_violations": self.atp_violations,
                "separation_violations": self.separation_violations,
                "route_conflicts": self.route_conflicts, "missed_stops": self.missed_stops,
                "stops": len(self.stops),
                "stop_error_max_m": float(err.max()) if err.size else math.nan,
                "stops_outside_0p30_m": int(np.count_nonzero(err > STOP_WINDOW_M)),
                "forced_stops": len(self.forced_stop_errors_m),
                "atp_interventions": self.atp_interventions,
                "sim_time_s": self.sim_time_s, "wall_s": self.wall_s,
                "finished": self.finished}


@dataclass
class _Req:
    term: int
    route: str
    at_s: float
    stop: int = -1
    """Berth the train stands at (-1: requested while running)."""
    earliest_s: float = -math.inf
    running_s: float = math.nan


@dataclass
class _Train:
    name: str
    i: int
    """Slot of the train in the fleet plant."""
    blocks: List[Block]
    b: int = 0
    k: int = 0
    """Next trip of block ``b`` to start."""
    in_service: bool = False
    ato: Optional[OnboardAto] = None
    cab: CabWatch = field(default_factory=CabWatch)
    """When the train's ATO starts afresh (pull-out, new lap)."""
    zone: int = -1
    """Terminus the train is inside (arrival route set .. departure route set), else -1."""
    itin: Dict[int, List[str]] = field(default_factory=dict)
    route: Dict[int, str] = field(default_factory=dict)
    """Route set for the train at a terminus and not yet arrived at its exit."""
    req: Optional[_Req] = None
    trip: Optional[Trip] = None
    trip_plan: Dict[int, Tuple[float, float]] = field(default_factory=dict)
    trip_log: Dict[int, List[float]] = field(default_factory=dict)
    last_arr: Optional[Tuple[Trip, float]] = None
    withdraw_at: float = math.inf
    energy0_j: float = 0.0
    """Substation energy of the train when its current trip departed [J]."""


class DayPlant:
    """The day's plants, interlockings and bookkeeping (see the module docstring)."""

    def __init__(self, loop: LoopLine, circ: Circulation, termini: Sequence[DayTerminus],
                 planner: str = "ectp", tracker: str = "fuzzy", seed: int = 0,
                 extra_dwell: Optional[Mapping[Tuple[str, str, int], float]] = None,
                 breakdowns: Sequence[Breakdown] = (), records: bool = True,
                 ats: Optional[Callable[[DaySchedule], DayAts]] = None) -> None:
        """Plant, ATOs and interlockings of the day; nothing runs yet.

        ``termini``: A (first station) then B; ``extra_dwell[(train, trip, station)]`` [s]:
        a hold added to that call's departure (a disturbance of a test or study; at the
        trip's origin station: added to its first departure, after the turnback link);
        ``breakdowns``: trains that stand still a while (:class:`Breakdown`).  ValueError
        (one line) for a breakdown of an unknown train or section.  ``records`` False:
        the stop, turnback and depot records are counted, not kept (a run for its figures
        and its speed: memory that does not grow with the day).  ``ats``: builds the ATS
        that decides every departure from the day's schedule (:meth:`day_schedule`), e.g.
        ``functools.partial(DayAts, regulator="lqr", lines=...)``; None: the timetable
        (:class:`DayAts` with ``none``).
        """
        self.loop = loop
        self.circ = circ
        self.termini = tuple(termini)
        codes = [t.code for t in self.termini]
        for b in circ.blocks:
            for tr in b.trips:
                for c in (tr.origin, tr.destination):
                    if c not in codes:
                        raise ValueError(f"trip {tr.trip_id}: terminus {c!r} is not one of "
                                         f"{codes}")
        self.scn: Scenario = loop.scenario
        self.il = [Interlocking(tp.layout) for tp in loop.termini]
        self.extra = dict(extra_dwell or {})
        by_train: Dict[str, List[Block]] = {}
        for b in circ.blocks:
            by_train.setdefault(b.train, []).append(b)
        tt = timetable_for(self.scn)
        self.wiring = ato_wiring(self.scn, planner, tracker, tt=tt)
        self.shared: Dict[str, Any] = {}
        self.trains: List[_Train] = []
        if not by_train:
            raise ValueError("a day needs at least one block")
        for n, (name, blocks) in enumerate(sorted(by_train.items())):
            blocks.sort(key=lambda b: b.trips[0].departure_s)
            self.trains.append(_Train(name, n, blocks))
        self._by_name = {tr.name: tr for tr in self.trains}
        # one plant for the fleet: a slot per train, the loop's stops, no timetabled
        # entries (pull-outs), authorities from here, each train's own disturbance stream
        # (the stream it had on a plant of its own: seed + slot)
        nt = len(self.trains)
        self.sim = sim = LineSim(fleet_scenario(self.scn, nt), seed=seed, trace_period_s=0.0)
        sim.external_entries(loop.period_m)
        sim.external_authority()
        sim.train_streams([seed + n for n in range(nt)])
        sim.stations.keep_log = False  # the day records its own calls
        self.sv = sim.service
        self.margin = float(sim.atp.margin)
        self.length = float(sim.geometry.length_m)
        for tp in loop.termini:  # a berth must hold the train (else it blocks its own exit)
            lay = tp.layout
            for r in lay.routes:
                d = r.destination
                if d != lay.exit_section and lay.section_length_m[d] < self.length:
                    raise ValueError(f"terminus layout {lay.name}: berth {d} of "
                                     f"{lay.section_length_m[d]:g} m is shorter than the "
                                     f"{self.length:g} m train")
        self.min_dwell = float(self.scn.passengers.min_dwell_s)
        names = {tr.name for tr in self.trains}
        for bd in breakdowns:
            if bd.train not in names:
                raise ValueError(f"breakdown of {bd.train!r}: not a train of the day")
            if not (math.isfinite(bd.duration_s) and bd.duration_s > 0.0
                    and math.isfinite(bd.at_s)):
                raise ValueError(f"breakdown of {bd.train}: at_s must be finite and "
                                 f"duration_s finite and > 0 s")
            if bd.section and (bd.terminus not in (0, 1) or bd.section not in
                               loop.termini[bd.terminus].layout.section_length_m):
                raise ValueError(f"breakdown of {bd.train}: no section {bd.section!r} at "
                                 f"terminus {bd.terminus}")
        self.breakdowns: List[Breakdown] = sorted(breakdowns, key=lambda b: b.at_s)
        self.tol_stop = float(self.sim.tol_stop)
        self.t = 0.0
        self.t_start = 0.0
        """The day's clock at its first step [s] (just before the first pull-out)."""
        self.step_no = 0
        self.stops: List[StopRecord] = [] if records else _Dropped()
        self.turnbacks: List[TurnbackRecord] = [] if records else _Dropped()
        self.depot: List[DepotRecord] = [] if records else _Dropped()
        self.route_conflicts = 0
        self.sep_violations = 0
        self._in_sep = np.zeros(nt, dtype=bool)
        """Per slot: the train was closer than the margin to the one ahead last step."""
        self._collide: set[Tuple[int, str]] = set()
        self.stop_err: List[float] = []
        self.forced_err: List[float] = []
        self.trips_run = 0
        self.trip_energy_j: Dict[str, float] = {}
        """Energy drawn from the substations per trip run, departure to arrival [J]."""
        self.notes: List[str] = []
        m = len(loop.stops)
        self.m = m
        self._entry = [min(sp.entry_m for sp in tp.spans.values() if sp.route.stage == 0)
                       for tp in loop.termini]
        self.lead_s = np.zeros(0)
        """Sorted fronts [m] of the trains that can lead (:meth:`_leaders`)."""
        top = [max(r.stage for r in tp.layout.routes) for tp in loop.termini]
        self._area = [(self._entry[T], self.length + max(
            sp.exit_m for sp in tp.spans.values() if sp.route.stage == top[T]))
            for T, tp in enumerate(loop.termini)]
        # authority at the exit of a route: its exit signal plus its overlap (the ATP
        # margin where it has none) [m], per terminus and route
        self._route_end = [
            {rn: sp.exit_m + (sum(tp.layout.section_length_m[q] for q in sp.route.overlap)
                              or self.margin) for rn, sp in tp.spans.items()}
            for tp in loop.termini]
        order = sorted(range(len(self._entry)), key=lambda T: self._entry[T])
        self._entry_sorted = np.array([self._entry[T] for T in order])
        self._entry_term = np.array(order + [0], dtype=np.intp)
        """Terminus of each sorted entry signal, then 0 (beyond the last: A's, a lap on)."""
        self._entry_next = np.append(self._entry_sorted, self._entry[0] + loop.period_m)
        self._u = np.full(nt, math.nan)
        self.sensor_samples = 0
        self.train_steps = 0
        self.wall_total = 0.0
        self.cpu_total = 0.0
        self.cpu_split = {"plant": 0.0, "ato": 0.0, "rest": 0.0}
        self._started = False
        # the departure berths of each terminus (where a trip starts: a pull-out enters one)
        self._dep_berths = [frozenset(
            r.destination for d in tp.layout.routes if d.stage == top[T]
            for r in tp.layout.routes if r.exit_signal == d.entry_signal)
            for T, tp in enumerate(loop.termini)]
        self.ats: DayAts = (ats if ats is not None else DayAts)(self.day_schedule())
        """The ATS deciding every departure (events in, decisions out)."""

    # ------------------------------------------------------------------ helpers

    def _norm(self, k: int) -> int:
        return 0 if k == self.m - 1 else k

    def _term_of(self, code: str) -> int:
        return [t.code for t in self.termini].index(code)

    def _trip_stops(self, trip: Trip) -> List[int]:
        """Raw loop stops of a trip (origin departure berth .. destination arrival)."""
        lp = self.loop
        n = len(lp.up_stop)
        if self._term_of(trip.origin) == 0:
            return [lp.up_stop[j] for j in range(n)]
        raw_arr_a = lp.down_stop[0] if lp.termini[0].arrival_stop != 0 else self.m - 1
        return [lp.down_stop[j] for j in range(n - 1, 0, -1)] + [raw_arr_a]

    def trip_plan(self, trip: Trip) -> Dict[int, Tuple[float, float]]:
        """Scheduled (arrival, departure) [s] per normalised loop stop of a trip.

        The plant's scheduled running times and nominal dwells of the loop scenario, scaled
        so that the trip ends at ``trip.arrival_s``; nan where an instant does not exist.
        """
        ks = self._trip_stops(trip)
        run = [float(self.sv.sched_running_s[k]) for k in range(ks[0], ks[-1])]
        inner = [k for k in ks[1:-1]]
        row = _dwell_row(self.sv, trip.departure_s)
        dw = [float(row[k]) for k in inner]
        total = sum(run) + sum(dw)
        scale = (trip.arrival_s - trip.departure_s) / total
        out: Dict[int, Tuple[float, float]] = {}
        t = trip.departure_s
        out[self._norm(ks[0])] = (math.nan, t)
        for a, b in zip(ks[:-1], ks[1:]):
            t_arr = t + scale * sum(float(self.sv.sched_running_s[k]) for k in range(a, b))
            t = t_arr + (scale * float(row[b]) if b != ks[-1] else 0.0)
            out[self._norm(b)] = (t_arr, t if b != ks[-1] else math.nan)
        return out

    def _running(self, j: int) -> float:
        return float(self.sv.sched_running_s[j])

    def _direction(self, trip: Trip) -> str:
        return "up" if self._term_of(trip.origin) == 0 else "down"

    def day_schedule(self) -> DaySchedule:
        """The day's timetable as the ATS sees it (:class:`DaySchedule`).

        Per direction the trips in timetable order, their scheduled instants
        (:meth:`trip_plan`) and the running-time targets the timetable commands: at an
        intermediate platform the loop's scheduled run scaled to the trip's planned time,
        from the origin the loop's scheduled run as it is (the departure berth's request).
        """
        fl = self.loop.stops
        by_dir: Dict[str, List[Trip]] = {}
        for b in self.circ.blocks:
            for trip in b.trips:
                by_dir.setdefault(self._direction(trip), []).append(trip)
        out: Dict[str, DirectionSchedule] = {}
        for d, trips in sorted(by_dir.items()):
            trips.sort(key=lambda x: (x.departure_s, x.trip_id))
            ks = self._trip_stops(trips[0])
            n = len(ks)
            dep = np.full((len(trips), n), math.nan)
            arr = np.full((len(trips), n), math.nan)
            run = np.full((len(trips), n - 1), math.nan)
            for m, trip in enumerate(trips):
                plan = self.trip_plan(trip)
                scale = self._scale(trip)
                for p, k in enumerate(ks):
                    arr[m, p], dep[m, p] = plan[self._norm(k)]
                    if p + 1 < n:
                        run[m, p] = self._running(k) * scale if p else self._running(k)
            out[d] = DirectionSchedule(
                d, tuple(t.trip_id for t in trips),
                tuple(fl[self._norm(k)].station for k in ks), trips[0].origin,
                trips[0].destination, dep, arr, run,
                np.array([float(self.sv.min_running_s[k]) for k in ks[:-1]]),
                np.array([fl[k].s_m for k in ks]))
        return DaySchedule(out, self.min_dwell)

    # ------------------------------------------------------------------ run

    def run(self, end_s: Optional[float] = None, max_wall_s: float = math.inf,
            progress: Optional[Callable[["DayPlant"], None]] = None,
            sensors: bool = False) -> DayResult:
        """Run the day to its last pull-in (or ``end_s`` [s], or ``max_wall_s`` of wall time).

        A second call runs on from where the first stopped (its result covers the whole
        run so far, wall time included).
        ``progress(self)`` is called once per simulated hour; ``sensors``: read the brake
        sensor samples of every step (noise and faults generated, counted in
        ``sensor_samples``; nothing of the day uses them).
        """
        w0 = time.perf_counter()
        c0 = time.process_time()
        all_trips = [tr for b in self.circ.blocks for tr in b.trips]
        last = max(tr.arrival_s for tr in all_trips)
        stop_at = last + 3600.0 if end_s is None else float(end_s)
        sim = self.sim
        self.start()  # a second call runs on from where the first stopped
        t0 = self.t_start
        dt = float(self.scn.sim.control_period_s)
        next_report = self.t
        while self.t < stop_at - 1e-9 and time.perf_counter() - w0 < max_wall_s:
            if self.finished:
                break
            self._step(dt, sensors)
            if progress is not None and self.t >= next_report:
                progress(self)
                next_report = self.t + 3600.0
        finished = self.finished
        if not finished:
            why = ("wall-time limit" if time.perf_counter() - w0 >= max_wall_s
                   else "end time")
            self.notes.append(f"stopped at t={self.t:.0f} s ({why}) before every train was "
                              f"back in the depot")
        self.wall_total += time.perf_counter() - w0
        self.cpu_total += time.process_time() - c0
        viol = int(np.sum(sim.atp.violations))
        return DayResult(
            stops=self.stops, turnbacks=self.turnbacks, depot=self.depot,
            trips_planned=len(all_trips), trips_run=self.trips_run,
            trains_in_depot=sum(1 for tr in self.trains if not tr.in_service),
            fleet=len(self.trains), atp_violations=viol + self.sep_violations,
            separation_violations=self.sep_violations, route_conflicts=self.route_conflicts,
            missed_stops=int(sim.stations.skipped_stops),
            stop_errors_m=self.stop_err, forced_stop_errors_m=self.forced_err,
            atp_interventions=int(np.sum(sim.atp.interventions)),
            sim_time_s=self.t, wall_s=self.wall_total, finished=finished,
            notes=self.notes, sensor_samples=self.sensor_samples,
            cpu_split_s=dict(self.cpu_split), cpu_s=self.cpu_total, start_s=t0,
            train_steps=self.train_steps)

    def _in_service(self) -> Tuple[List[_Train], Any]:
        """The trains in service and their slots (an int array), in slot order."""
        svc = [tr for tr in self.trains if tr.in_service]
        return svc, np.fromiter((tr.i for tr in svc), dtype=np.intp, count=len(svc))

    def start(self) -> None:
        """Set the plant's clock to the day's first step (once; nothing runs yet).

        The plant starts at 0: its clock jumps to just before the first pull-out, and the
        passengers gather from then on (one queue per stop, shared).  :meth:`run` calls it;
        a caller stepping the day itself (:meth:`begin_step`, :meth:`end_step`) first.
        """
        if self.step_no != 0 or self._started:
            return
        self._started = True
        first = min(b.trips[0].departure_s for b in self.circ.blocks) - PULL_OUT_LEAD_S
        sim = self.sim
        self.t_start = max(0.0, math.floor(first) - 1.0)
        sim.t = self.t_start
        sim.sensors.next_sample_t = self.t_start
        sim.stations.last_dep_t[:] = self.t_start
        self.t = self.t_start

    @property
    def finished(self) -> bool:
        """Every train ran its blocks and is back in the depot."""
        return all(tr.b >= len(tr.blocks) and not tr.in_service for tr in self.trains)

    def begin_step(self) -> Any:
        """The part of a control period before the ATOs: pull-outs, routes, authorities.

        Returns the slots of the trains whose ATO commands this step (in service and
        running, in slot order: the plant's :meth:`LineSim.active_mask`).  Then the
        caller gets their efforts from their ATOs (from :func:`fleet_state_rows` of these
        slots at step :attr:`step_no`, time :attr:`t`) and calls :meth:`end_step`.
        """
        t = self.t
        sim = self.sim
        self._pull_outs_and_ins(t)
        svc, rows = self._in_service()
        self.train_steps += len(svc)
        self._leaders(rows)
        self._requests(t)
        self._authorities(svc, rows)
        return rows[sim.fleet.status[rows] == RUN]

    def end_step(self, u: Any, sensors: bool = False) -> StepResult:
        """The plant step with the efforts ``u`` (one per slot, NaN: the last command).

        Then the step's events (arrivals, departures), track occupancy, route grants and
        the safety checks; the day's clock advances by one control period.  ``sensors``:
        count the step's brake sensor samples.  Returns the plant's step result.
        """
        sim = self.sim
        clock = time.process_time
        c0 = clock()
        res = sim.step(u)
        if sensors:
            self._read_samples(res)
        c1 = clock()
        # a train's events in the order the plant gave them, the trains in slot order
        for ev in sorted(res.events, key=_slot):
            self._event(self.trains[ev.train_idx], ev)
        self.t = self.t + float(self.scn.sim.control_period_s)
        self.step_no += 1
        self._occupancy()
        self._grants()
        self._checks()
        if self.breakdowns:
            self._breakdowns_due()
        ws = self.cpu_split
        ws["plant"] += c1 - c0
        ws["rest"] += clock() - c1
        return res

    def control(self, run: Any) -> Any:
        """The efforts of the trains ``run`` (slots) from their on-board ATOs, NaN elsewhere.

        One fleet state for all of them; a train's ATO is a new one when its state starts
        a new cab (:class:`metro_atc.core.ato.cab.CabWatch`: back in service, or a new
        lap of the loop), as the ``ato_controller`` node decides it.
        """
        u = self._u
        u.fill(math.nan)
        if run.size:
            sim = self.sim
            st = fleet_state_rows(sim, run)
            trains = self.trains
            step = self.step_no
            t = self.t
            for k, i in enumerate(run.tolist()):
                tr = trains[i]
                s = ato_input(st, k, step, t)
                if tr.cab.new_cab(step, s["current_station"]) or tr.ato is None:
                    tr.ato = self.wiring.onboard(self.shared)
                u[i] = tr.ato.control(s)[0]
        return u

    def _step(self, dt: float, sensors: bool = False) -> None:
        clock = time.process_time
        w0 = clock()
        run = self.begin_step()
        w1 = clock()
        u = self.control(run)
        w2 = clock()
        self.end_step(u, sensors)  # its plant step and the rest counted by itself
        ws = self.cpu_split
        ws["ato"] += w2 - w1
        ws["rest"] += w1 - w0

    def _read_samples(self, res: StepResult) -> None:
        """Read the step's brake sensor samples (generated now; counted)."""
        blk = res.sensor_arrays
        if blk is not None:
            self.sensor_samples += blk.t.size * blk.trains.size

    # ------------------------------------------------------------------ depot

    def _pull_outs_and_ins(self, t: float) -> None:
        for tr in self.trains:
            if tr.in_service and t >= tr.withdraw_at - 1e-9:
                self._withdraw(tr, t)
            if tr.in_service or tr.b >= len(tr.blocks):
                continue
            trip = tr.blocks[tr.b].trips[0]
            sched = trip.departure_s - PULL_OUT_LEAD_S
            if t >= sched - 1e-9:
                self._pull_out(tr, trip, t, sched)

    def _pull_out(self, tr: _Train, trip: Trip, t: float, sched: float) -> None:
        T = self._term_of(trip.origin)
        tp = self.loop.termini[T]
        choice = self._departure_berth(T)
        if choice is None:
            return  # berth taken: try again next step
        arr_route, dep_route = choice
        tr.in_service = True
        tr.zone = T
        tr.itin = {T: [arr_route, dep_route]}
        tr.route = {}
        tr.last_arr = None
        sim = self.sim
        if not sim.sensors.any_sensed:  # no samples were due while no train ran
            sim.sensors.next_sample_t = t
        sim.enter(tr.i, tp.departure_stop)
        sim.set_departure(tr.i, tp.departure_stop, HELD_S)  # until its route is set
        dep, run = self._first_departure(tr, trip, trip.departure_s)
        tr.req = _Req(T, dep_route, dep - REQUEST_LEAD_S, tp.departure_stop, dep, run)
        self.depot.append(DepotRecord(tr.name, "pull_out", trip.origin, t, sched))
        self._occupancy()

    def _departure_berth(self, T: int) -> Optional[Tuple[str, str]]:
        """(route ending at a free departure berth, departure route from it) or None."""
        lay = self.loop.termini[T].layout
        top = max(r.stage for r in lay.routes)
        il = self.il[T]
        for dep in (r for r in lay.routes if r.stage == top):
            into = [r for r in lay.routes if r.exit_signal == dep.entry_signal]
            if not into:
                continue
            berth = into[0].destination
            if berth in il.occupied or berth in il.lock or self._claimed(T, berth):
                continue
            return into[0].name, dep.name
        return None

    def _claimed(self, T: int, section: str, me: Optional[_Train] = None) -> bool:
        """A train in service (other than ``me``) has a route into ``section`` at T."""
        lay = self.loop.termini[T].layout
        return any(o is not me and o.in_service
                   and any(lay.route(rn).destination == section for rn in o.itin.get(T, []))
                   for o in self.trains)

    def _withdraw(self, tr: _Train, t: float) -> None:
        trip = tr.last_arr[0] if tr.last_arr else None
        self.sim.pull_in(tr.i)
        tr.in_service = False
        tr.ato = None
        tr.itin = {}
        tr.route = {}
        tr.zone = -1
        tr.req = None
        tr.withdraw_at = math.inf
        tr.b += 1
        tr.k = 0
        if trip is not None:
            self.depot.append(DepotRecord(tr.name, "pull_in", trip.destination, t,
                                          trip.arrival_s + self.min_dwell))
        self._occupancy()

    # ------------------------------------------------------------------ routes

    def _requests(self, t: float) -> None:
        for tr in self.trains:
            q = tr.req
            if q is None or q.at_s > t + 1e-9:
                continue
            il = self.il[q.term]
            if any(r.train == tr.name for r in il.queue):
                continue
            if q.stop < 0:  # an arrival route: only the first train before the signal asks
                x = float(self.sim.fleet.x[tr.i])
                k = int(np.searchsorted(self.lead_s, x, side="right"))
                if k < len(self.lead_s) and self.lead_s[k] <= self._entry[q.term] + 1.0:
                    continue
            it = tr.itin.setdefault(q.term, [])
            if q.route not in it:
                # chosen now (a siding or platform chosen earlier may be taken since); the
                # route claims its destination from its request on
                q.route = self._choose(q.term, tr)
                if self._yields(q.term, tr, q.route):
                    continue
                it.append(q.route)
            il.request(tr.name, q.route)

    def _yields(self, T: int, tr: _Train, route: str) -> bool:
        """``tr`` waits before taking a departure berth of T that a pull-out needs first.

        Departure berths serve trips in timetable order: a train whose next trip from T
        leaves at d may take one only while more of them are free than there are pull-outs
        still to come at T for trips leaving before d (a train standing at the berth until
        d would shut such a pull-out out, and the timetable falls behind).  A train that
        ends its block at T (pulls in) never waits.
        """
        lay = self.loop.termini[T].layout
        berth = lay.route(route).destination
        if berth not in self._dep_berths[T]:
            return False
        blk = tr.blocks[tr.b].trips
        k = tr.k  # trips started so far in this block: the next one is trips[k]
        if k >= len(blk) or self._term_of(blk[k].origin) != T:
            return False
        d = blk[k].departure_s
        code = self.termini[T].code
        due = sum(1 for o in self.trains if not o.in_service and o.b < len(o.blocks)
                  and o.blocks[o.b].trips[0].origin == code
                  and o.blocks[o.b].trips[0].departure_s < d)
        if due == 0:
            return False
        il = self.il[T]
        free = sum(1 for b in self._dep_berths[T] if b not in il.occupied
                   and b not in il.lock and not self._claimed(T, b, tr))
        return free <= due

    def _grants(self) -> None:
        for T, il in enumerate(self.il):
            for name, route in il.process():
                tr = self._by_name[name]
                q = tr.req
                tr.req = None
                r = il.layout.route(route)
                top = max(x.stage for x in il.layout.routes)
                tr.route[T] = route
                if r.stage == top:
                    tr.zone = -1  # the departure route leads onto the open line
                else:
                    tr.zone = T
                if q is not None and q.stop >= 0:
                    dep = max(self.t, q.earliest_s)
                    self.sim.set_departure(tr.i, q.stop, dep, q.running_s)

    def _choose(self, T: int, tr: _Train) -> str:
        """The next route of ``tr``'s itinerary at T (a free destination first).

        The candidates continue the routes the train took so far at T
        (``Layout.itineraries``); a destination neither occupied, locked nor claimed by
        another train is preferred (the siding or platform chosen free first).
        """
        lay = self.loop.termini[T].layout
        il = self.il[T]
        done = tr.itin.get(T, [])
        cands: List[str] = []
        for it in lay.itineraries:
            if list(it[:len(done)]) == done and len(it) > len(done) \
                    and it[len(done)] not in cands:
                cands.append(it[len(done)])
        if not cands:
            raise RuntimeError(f"{tr.name}: no route continues {done} at {lay.name}")
        for rn in cands:
            d = lay.route(rn).destination
            if d not in il.occupied and d not in il.lock and not self._claimed(T, d, tr):
                return rn
        return cands[0]

    # ------------------------------------------------------------------ events

    def _event(self, tr: _Train, ev: Any) -> None:
        j = int(ev.station_idx)
        t = float(ev.t_s)
        if ev.kind == "arrival":
            err = float(ev.stop_error_m)
            if math.isfinite(err):
                forced = bool(self.sim.fleet.broken[tr.i] or self.sim.atp.eb[tr.i])
                (self.forced_err if forced else self.stop_err).append(err)
            self._arrival(tr, j, t)
        else:
            self._departure(tr, j, t)

    def _terminus_at(self, j: int) -> Optional[TerminusPath]:
        for tp in self.loop.termini:
            if j in (tp.arrival_stop, tp.reversal_stop, tp.departure_stop):
                return tp
        return None

    def _arrival(self, tr: _Train, j: int, t: float) -> None:
        sim = self.sim
        tp = self._terminus_at(j)
        if tp is None:  # an intermediate platform of the running trip: the ATS decides
            trip = tr.trip
            if trip is None:
                raise RuntimeError(f"{tr.name} arrived at stop {j} outside a trip")
            tr.trip_log.setdefault(j, [math.nan, math.nan])[0] = t
            st = self.loop.stops[j].station
            d = self.ats.on_arrival(trip.trip_id, self._direction(trip), st, t)
            assert d is not None  # an intermediate call always gets a decision
            dep = d.departure_s + self.extra.get((tr.name, trip.trip_id, st), 0.0)
            run = d.running_s
            sim.set_departure(tr.i, j, dep, run, d.dwell_limit_s)
            return
        T = tp.index
        lay = tp.layout
        route = tr.route.pop(T, None)
        if route is not None:
            self.il[T].arrived(route)
        sim.set_departure(tr.i, j, HELD_S)
        if j == tp.arrival_stop and tr.trip is not None and \
                self._term_of(tr.trip.destination) == T:
            self.ats.on_arrival(tr.trip.trip_id, self._direction(tr.trip),
                                self.loop.stops[j].station, t)
            self._end_trip(tr, j, t)
            if tr.k >= len(tr.blocks[tr.b].trips):  # end of the block: pull in
                tr.withdraw_at = t + self.min_dwell
                return
        spec = self.termini[T]
        nxt_route = self._choose(T, tr)
        run = self._running(j)
        if j == tp.departure_stop:  # departure berth (also the arrival at a scissors)
            nxt = self._next_trip(tr)
            last = tr.last_arr[1] if tr.last_arr else t
            # the turnback link; the ATS keeps the timetable as the other bound
            earliest, run = self._first_departure(tr, nxt, max(
                last + spec.min_turnback_s,
                t + (lay.reversal_s if j == tp.reversal_stop else 0.0)))
        elif j == tp.reversal_stop:
            earliest = t + lay.reversal_s
        else:
            earliest = t
        tr.req = _Req(T, nxt_route, earliest - REQUEST_LEAD_S, j, earliest, run)

    def _scale(self, trip: Trip) -> float:
        """Planned over scheduled trip time of ``trip`` [-] (:meth:`trip_plan`)."""
        ks = self._trip_stops(trip)
        run = sum(float(self.sv.sched_running_s[k]) for k in range(ks[0], ks[-1]))
        row = _dwell_row(self.sv, trip.departure_s)
        dw = sum(float(row[k]) for k in ks[1:-1])
        return (trip.arrival_s - trip.departure_s) / (run + dw)

    def _first_departure(self, tr: _Train, trip: Trip, earliest_s: float
                         ) -> Tuple[float, float]:
        """(departure [s], running target [s]) of ``trip`` from its origin, from the ATS.

        ``earliest_s``: the turnback link (or the timetable after a pull-out); a hold of
        ``extra_dwell`` at the trip's origin station is added (a disturbance).
        """
        d = self.ats.first_departure(trip.trip_id, earliest_s)
        return d.departure_s + self.extra.get((tr.name, trip.trip_id, d.station), 0.0), \
            d.running_s

    def _next_trip(self, tr: _Train) -> Trip:
        return tr.blocks[tr.b].trips[tr.k]

    def _end_trip(self, tr: _Train, j: int, t: float) -> None:
        trip = tr.trip
        assert trip is not None
        tr.trip_log.setdefault(j, [math.nan, math.nan])[0] = t
        direction = "up" if self._term_of(trip.origin) == 0 else "down"
        for k, (sa, sd) in tr.trip_plan.items():
            arr, dep = tr.trip_log.get(k, [math.nan, math.nan])
            st = self.loop.stops[k].station
            self.stops.append(StopRecord(tr.name, trip.trip_id, direction, st, sa, sd,
                                         arr if math.isfinite(sa) else math.nan,
                                         dep if math.isfinite(sd) else math.nan))
        tr.last_arr = (trip, t)
        tr.trip = None
        self.trips_run += 1
        self.trip_energy_j[trip.trip_id] = \
            float(self.sim.energy.e_substation[tr.i]) - tr.energy0_j

    def _departure(self, tr: _Train, j: int, t: float) -> None:
        tp = self._terminus_at(j)
        if tp is not None and j == tp.departure_stop:  # a trip starts
            trip = self._next_trip(tr)
            tr.k += 1
            tr.trip = trip
            tr.trip_plan = self.trip_plan(trip)
            tr.trip_log = {j: [math.nan, t]}
            tr.energy0_j = float(self.sim.energy.e_substation[tr.i])
            self.ats.on_departure(trip.trip_id, self._direction(trip),
                                  self.loop.stops[j].station, t)
            if tr.last_arr is not None:
                prev, t_arr = tr.last_arr
                T = tp.index
                self.turnbacks.append(TurnbackRecord(
                    tr.name, self.termini[T].code, prev.trip_id, trip.trip_id, t_arr, t,
                    prev.arrival_s, trip.departure_s, self.termini[T].min_turnback_s))
            tr.last_arr = None
        elif tp is None and tr.trip is not None:
            tr.trip_log.setdefault(j, [math.nan, math.nan])[1] = t
            self.ats.on_departure(tr.trip.trip_id, self._direction(tr.trip),
                                  self.loop.stops[j].station, t)
        # the next stop: the arrival route of a terminus is requested when leaving the
        # platform before it
        nxt = self._norm(j + 1)
        for T, tq in enumerate(self.loop.termini):
            if nxt == tq.arrival_stop and (tp is None or tp.index != T):
                tr.itin[T] = []
                tr.req = _Req(T, self._choose(T, tr), t)

    # ------------------------------------------------------------------ authority

    def _inside_mask(self, x: Any) -> Any:
        """Which fronts ``x`` [m] (an array) lie inside a terminus (a bool array).

        Inside: from the entry signal until the rear is out of the departure route.  The
        departure route's sections are shared with the arrival routes of the parallel
        track (scissors), so a departing train is inside until its rear has left them.
        """
        out = np.zeros(x.shape, dtype=bool)
        for lo, hi in self._area:
            if lo < hi:
                out |= (x >= lo) & (x <= hi)
            else:  # A: across the wrap
                out |= (x >= lo) | (x <= hi)
        return out

    def _leaders(self, rows: Any) -> None:
        """Sorted fronts [m] of the trains that can lead: in service, outside the termini.

        ``rows``: the slots in service.  Inside a terminus parallel berths share path
        coordinates (the interlocking separates those trains); everywhere else the path
        order is the track order.
        """
        x = self.sim.fleet.x[rows]
        self.lead_s = np.sort(x[~self._inside_mask(x)])

    def _authorities(self, svc: List[_Train], rows: Any) -> None:
        """End of authority of the trains in service (slots ``rows``) into the plant.

        The nearest leader ahead (:attr:`lead_s`, one sorted search) and each train's cap:
        inside a terminus the end of its set route (else its berth), on the open line the
        entry signal of the terminus ahead until its arrival route is set.
        """
        if not svc:
            return
        fl = self.sim.fleet
        x = fl.x[rows]
        ahead = np.append(self.lead_s - self.length - self.margin, math.inf)
        lead = ahead[np.searchsorted(self.lead_s, x, side="right")]
        # the entry signal of the terminus ahead of each front (and its terminus)
        k = np.searchsorted(self._entry_sorted, x - 1.0, side="left")
        entry, term = self._entry_next[k], self._entry_term[k].tolist()
        cap = np.empty(len(svc))
        ends = self._route_end
        for n, tr in enumerate(svc):
            z = tr.zone
            if z >= 0:  # inside a terminus: its set route, else its berth (nan: below)
                rn = tr.route.get(z)
                cap[n] = ends[z][rn] if rn is not None else math.nan
            else:  # the entry signal ahead until the arrival route is set
                cap[n] = math.inf if term[n] in tr.route else entry[n]
        dwelling = fl.dwelling[rows]
        stop = fl.stop_x[rows]
        cap = np.where(np.isnan(cap), np.where(dwelling, x, stop), cap)
        ma = np.minimum(cap, lead)
        ma = np.where(dwelling, ma, clear_of_stop(ma, x, stop, self.tol_stop))
        self.sim.set_authority_ends(rows, ma)

    # ------------------------------------------------------------------ occupancy

    def _spans_of(self, tr: _Train, T: int) -> List[Tuple[str, float, float]]:
        tp = self.loop.termini[T]
        out: List[Tuple[str, float, float]] = []
        for rn in tr.itin.get(T, []):
            out.extend(tp.spans[rn].sections)
        return out

    def _occupancy(self) -> None:
        P = self.loop.period_m
        fl = self.sim.fleet
        # the trains with an itinerary or a set route at a terminus (few: those near one)
        near = [tr for tr in self.trains if tr.itin or tr.route]
        for T, il in enumerate(self.il):
            occ: Dict[str, int] = {}
            for tr in near:
                if not tr.in_service or not tr.itin.get(T):
                    continue
                i = tr.i
                x = float(fl.x[i])
                if fl.dwelling[i]:  # standing at a berth: its front is at the stop point
                    x = min(x, self.loop.stops[int(fl.cur_station[i])].s_m)
                hit = set()
                for sec, a, b in self._spans_of(tr, T):
                    for d in (0.0, P, -P):
                        lo, hi = x - self.length + d, x + d
                        if hi > a and lo < b:
                            hit.add(sec)
                for s in hit:
                    occ[s] = occ.get(s, 0) + 1
            for s, c in occ.items():
                key = (T, s)
                if c > 1 and key not in self._collide:
                    self.route_conflicts += 1
                    self._collide.add(key)
                    self.notes.append(f"t={self.t:.2f} s: section {s} of {il.layout.name} "
                                      f"occupied by {c} trains")
                elif c <= 1:
                    self._collide.discard(key)
            now = set(occ)
            for s in sorted(now - il.occupied):
                il.occupy(s)
            for s in sorted(il.occupied - now):
                il.clear(s)
            # a train whose departure route is released has left the terminus
            for tr in near:
                rn = tr.route.get(T)
                if rn is not None and rn not in il.set_routes:
                    del tr.route[T]
                    if tr.zone < 0:
                        tr.itin.pop(T, None)

    def _breakdowns_due(self) -> None:
        """Break down the trains whose :class:`Breakdown` is due now (once each)."""
        P = self.loop.period_m
        for bd in list(self.breakdowns):
            if bd.at_s > self.t + 1e-9:
                break
            tr = next(x for x in self.trains if x.name == bd.train)
            if not tr.in_service:
                continue
            x = float(self.sim.fleet.x[tr.i])
            if bd.section and not any(a <= x + d <= b for s, a, b in
                                      self._spans_of(tr, bd.terminus) if s == bd.section
                                      for d in (0.0, P, -P)):
                continue
            self.sim.breakdown(tr.i, bd.duration_s)
            self.breakdowns.remove(bd)
            self.notes.append(f"t={self.t:.2f} s: {tr.name} broke down at s={x:.0f} m for "
                              f"{bd.duration_s:.0f} s")

    def _checks(self) -> None:
        for il in self.il:
            why = check_safe(il)
            if why is not None:
                self.route_conflicts += 1
                self.notes.append(f"t={self.t:.2f} s: {il.layout.name}: {why}")
        # separation of the trains outside the termini (the plant's own monitor sees no
        # train ahead)
        _, rows = self._in_service()
        x = self.sim.fleet.x[rows]
        out = ~self._inside_mask(x)
        rows, x = rows[out], x[out]
        order = np.argsort(x, kind="stable")  # by front, then by slot (= by name)
        rows, x = rows[order], x[order]
        bad = (x[1:] - self.length) - x[:-1] < self.margin - 1e-6
        behind = rows[:-1]  # each train behind another
        self.sep_violations += int(np.count_nonzero(bad & ~self._in_sep[behind]))
        self._in_sep[behind] = bad
        if rows.size:
            self._in_sep[rows[-1]] = False


def clear_of_stop(ma_m: Any, x_m: Any, stop_m: Any, tol_m: float) -> Any:
    """End of movement authority [m] that never rests a train just short of its stop point.

    The ATO aims ``AUTHORITY_MARGIN_M`` short of the end of authority ``ma_m`` (its guard,
    :mod:`metro_atc.core.ato.onboard`); an authority ending less than that beyond the next
    stop point ``stop_m`` (e.g. the rear of a train leaving that platform, minus the ATP
    margin) brings the train ``x_m`` to rest short of the stop point, and a standstill
    inside the plant's stop window (+-``tol_m``) counts as the arrival, the shortfall as
    its stop error.  Such an authority ends ``2 tol_m`` further back (the train rests outside
    the window and runs on to the stop point once the authority reaches beyond it).  For a
    growing authority the result never decreases.  Positions along the path [m]: floats
    or arrays of one shape (numpy broadcasting).
    """
    near = stop_m + AUTHORITY_MARGIN_M
    pull = (x_m < stop_m) & (ma_m < near)
    return np.where(pull, np.minimum(ma_m, near - 2.0 * tol_m), ma_m)


def _dwell_row(sv: Any, t_s: float) -> Any:
    """Nominal dwells [s] per loop stop of the timetable period in force at ``t_s``."""
    return sv.sched_dwell[sv.flow.period(t_s)]


def day_trips(loop: LoopLine, sv: Any, codes: Tuple[str, str],
              periods: Sequence[Tuple[float, float, float]]) -> List[Trip]:
    """Trips of both directions from each terminus; ``periods``: (start, end, headway) [s].

    Departures every headway from each period's start until its end, both termini at the
    same instants.  Trip time: the loop scenario's scheduled running times and nominal
    dwells (``sv``: its :class:`metro_atc.core.line.service.ServicePlan`, the dwells of the
    period in force at the departure), rounded up to 1 s.  A simple day for tests and
    studies; the Taipei day's trips are :func:`metro_atc.core.service.day.trips`.
    """
    n = len(loop.up_stop)
    m = len(loop.stops)
    raw_a = loop.down_stop[0] if loop.termini[0].arrival_stop != 0 else m - 1
    legs = {"up": [loop.up_stop[j] for j in range(n)],
            "down": [loop.down_stop[j] for j in range(n - 1, 0, -1)] + [raw_a]}
    out: List[Trip] = []
    for d, (o, e) in (("up", codes), ("down", codes[::-1])):
        ks = legs[d]
        k = 0
        for start, end, hw in periods:
            z = float(start)
            while z < end - 1e-9:
                row = _dwell_row(sv, z)
                dur = sum(float(sv.sched_running_s[q]) for q in range(ks[0], ks[-1]))
                dur += sum(float(row[q]) for q in ks[1:-1])
                out.append(Trip(f"{d}{k:03d}", o, e, z, z + float(math.ceil(dur))))
                z += float(hw)
                k += 1
    return out


def plant_timed(loop: LoopLine, sv: Any, trips: Sequence[Trip], codes: Tuple[str, str]
                ) -> List[Trip]:
    """``trips`` with the trip times of the plant (same departures and ids).

    Trip time: the loop's scheduled running times and the nominal dwells of the period at
    the departure (``sv``: the loop scenario's ServicePlan), rounded up to 1 s, as
    :func:`day_trips`.
    """
    n = len(loop.up_stop)
    m = len(loop.stops)
    raw_a = loop.down_stop[0] if loop.termini[0].arrival_stop != 0 else m - 1
    legs = {codes[0]: [loop.up_stop[j] for j in range(n)],
            codes[1]: [loop.down_stop[j] for j in range(n - 1, 0, -1)] + [raw_a]}
    out = []
    for t in trips:
        ks = legs[t.origin]
        row = _dwell_row(sv, t.departure_s)
        dur = sum(float(sv.sched_running_s[q]) for q in range(ks[0], ks[-1]))
        dur += sum(float(row[q]) for q in ks[1:-1])
        out.append(dataclasses.replace(t, arrival_s=t.departure_s + float(math.ceil(dur))))
    return out


def fleet_scenario(loop_scn: Scenario, n_trains: int) -> Scenario:
    """The scenario of a day's fleet plant: the loop scenario with a slot per train.

    ``loop_scn``: the loop's scenario (:attr:`LoopLine.scenario`); ``n_trains``: the trains
    of the circulation.  The slots' train ids are this scenario's (``train_01`` ..), in
    the order of the circulation's train names (:class:`DayPlant`); an ATO node of the
    day builds its ATO from this scenario too.
    """
    return dataclasses.replace(loop_scn, trains=dataclasses.replace(loop_scn.trains,
                                                                    count=int(n_trains)))


def day_layout(scn: Scenario, plan: Any, stable_after_s: float = STABLE_AFTER_S,
               trip_times: str = "plan") -> Tuple[LoopLine, Circulation]:
    """The loop of ``scn``'s line with ``plan``'s termini and periods, and its circulation.

    The loop of the line with the plan's terminus layouts; its timetable periods are the
    plan's (boarding per direction scaled by the period's flow factors); the circulation
    is :func:`metro_atc.core.service.day.run_day`'s, with the plan's trip times
    (``trip_times="plan"``: Lin 2010a, eq. 5/10 on the ATR line data) or those the plant's
    timetable gives (``"plant"``: :func:`plant_timed`).  ValueError / DayError / LoopError
    in one line.
    """
    from .day import run_day, trips
    if trip_times not in ("plan", "plant"):
        raise ValueError(f"trip_times must be plan or plant, got {trip_times!r}")
    from .loop import build_loop, with_periods
    if [s.code for s in scn.line.stations][::len(scn.line.stations) - 1] != \
            [t.station for t in plan.termini]:
        raise ValueError(f"day {plan.name}: termini {[t.station for t in plan.termini]} are "
                         f"not the ends of scenario {scn.name}")
    loop = build_loop(scn, (plan.termini[0].layout, plan.termini[1].layout),
                      tsrs=plan.tsrs, track_limits=plan.track_limits,
                      track_curves=plan.track_curves)
    lscn = with_periods(scn, loop, [(p.start_s, p.headway_s, p.flow_up, p.flow_down, p.name)
                                    for p in plan.periods])
    end = plan.periods[-1].end_s + 7200.0
    lscn = dataclasses.replace(lscn, sim=dataclasses.replace(lscn.sim, duration_s=end))
    loop = dataclasses.replace(loop, scenario=lscn)
    timed = None
    if trip_times == "plant":
        sv = LineSim(lscn, trace_period_s=0.0).service
        codes = (plan.termini[0].station, plan.termini[1].station)
        timed = plant_timed(loop, sv, trips(plan), codes)
    # first in, first out: a tail track's single departure platform sends the trains out
    # in their arrival order (with the last-in choice a train standing at the platform
    # waits for a later trip while the one due first is held behind it in a siding)
    circ, _ = run_day(plan, stable_after_s, timed, "longest_wait")
    return loop, circ


def service_day(scn: Scenario, plan: Any, planner: str = "ectp", tracker: str = "fuzzy",
                seed: int = 0, stable_after_s: float = STABLE_AFTER_S,
                trip_times: str = "plan",
                holds: Optional[Mapping[Tuple[str, int], float]] = None,
                breakdowns: Sequence[Breakdown] = (), records: bool = True,
                regulator: str = "none",
                weights: Optional[Mapping[str, str]] = None) -> DayPlant:
    """The plant of a day: ``scn``'s line and stock, ``plan`` a :class:`DayPlan`.

    The loop and the circulation of :func:`day_layout`.  ``holds[(trip id, station
    index)]`` [s]: extra dwell of that trip's call (whichever train runs it; at the trip's
    origin station: a delay of its first departure); ``breakdowns``, ``records``: see
    :class:`DayPlant`.  ``regulator``: the ATS regulator of both directions
    (:class:`metro_atc.core.service.dayats.DayAts`), each on its direction's traffic model
    at the peak (:func:`metro_atc.core.service.regulation.peak_lines` of ``scn``'s ATR
    line); ``weights[direction]``: a weights file for ``aoc`` / ``dhp`` (default: the
    shipped ones of that direction).  DayError / LoopError / ValueError in one line.
    """
    loop, circ = day_layout(scn, plan, stable_after_s, trip_times)
    termini = [DayTerminus(t.station, t.min_turnback_s, t.depot is not None)
               for t in plan.termini]
    owner = {tr.trip_id: b.train for b in circ.blocks for tr in b.trips}
    last = len(scn.line.stations) - 1
    origin = {tr.trip_id: 0 if tr.origin == termini[0].code else last
              for b in circ.blocks for tr in b.trips}
    extra = {}
    for (trip_id, station), d in (holds or {}).items():
        if trip_id not in owner:
            raise ValueError(f"day {plan.name}: hold of trip {trip_id!r}: no such trip")
        if not (math.isfinite(d) and d >= 0.0) or not (
                0 < int(station) < last or int(station) == origin[trip_id]):
            raise ValueError(f"day {plan.name}: hold of trip {trip_id} at station "
                             f"{station}: needs an intermediate station or the trip's "
                             f"origin ({origin[trip_id]}) and a finite hold >= 0 s, got "
                             f"{d!r} s")
        extra[(owner[trip_id], trip_id, int(station))] = float(d)
    ats = None
    if regulator != "none" or weights:
        import functools

        from metro_atc.core.atr.lines import atr_line_for

        from .dayats import DayAts
        from .regulation import peak_lines
        ats = functools.partial(DayAts, regulator=regulator,
                                lines=peak_lines(plan, atr_line_for(scn)), scenario=scn,
                                weights=weights)
    return DayPlant(loop, circ, termini, planner, tracker, seed, extra, breakdowns,
                    records=records, ats=ats)


def rss_mb() -> float:
    """Resident set size of this process now [MB] (nan where /proc is not there)."""
    try:
        with open("/proc/self/statm", encoding="ascii") as f:
            pages = int(f.read().split()[1])
    except (OSError, ValueError, IndexError):
        return math.nan
    return pages * os.sysconf("SC_PAGE_SIZE") / 1e6


def peak_rss_mb() -> float:
    """Peak resident set size of this process so far [MB] (``getrusage``; Linux KiB)."""
    import resource
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024 / 1e6


def main(argv: Optional[Sequence[str]] = None) -> int:
    """``python -m metro_atc.core.service.dayplant``: the Taipei Blue day on the plant.

    Prints one JSON line per simulated hour (progress) and the summary; exit 0 only when
    the whole day ran (every trip, every train back in the depot) without a violation or
    route conflict.  ``--regulator``: the ATS regulator of both directions
    (:class:`metro_atc.core.service.dayats.DayAts`); ``--delay-s``: Lin 2010a,
    Experiment 2 on the day: the first departure of one trip from the first station is
    delayed (``--delay-trip``, default the first up trip of the peak period), reported
    with its terminal delay, the turnback and the train's next trip.
    """
    import argparse
    import json
    import sys

    from metro_atc.core.line.scenario import load_scenario

    from metro_atc.core.atr.registry import REGULATORS

    from .day import load_day, trips
    from .dayats import first_trip_from, incident_report
    from .regulation import peak_period
    ap = argparse.ArgumentParser(prog="python -m metro_atc day")
    ap.add_argument("--scenario", default="taipei_blue")
    ap.add_argument("--day", default=None, help="period table (default: the Taipei Blue day)")
    ap.add_argument("--end-h", type=float, default=None, help="stop at this hour [h]")
    ap.add_argument("--max-wall-s", type=float, default=math.inf)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--trip-times", choices=("plan", "plant"), default="plant",
                    help="the plant's timetable's trip times (default) or the period "
                         "table's (Lin 2010a, eq. 5/10: shorter than the plant can run)")
    ap.add_argument("--out", default=None,
                    help="write the day's KPIs (day_kpis.json/.txt) and pictures here")
    ap.add_argument("--sensors", action="store_true",
                    help="read the brake sensor samples of every step (speed figures)")
    ap.add_argument("--no-records", action="store_true",
                    help="count the stop / turnback / depot records, keep none (memory "
                         "figures; not with --out)")
    ap.add_argument("--regulator", choices=REGULATORS.names, default="none",
                    help="ATS regulator of both directions (" + REGULATORS.help() + ")")
    ap.add_argument("--delay-s", type=float, default=0.0,
                    help="delay the first departure of one trip from the first station by "
                         "this much [s] (Lin 2010a, Experiment 2: 180)")
    ap.add_argument("--delay-trip", default=None,
                    help="trip id to delay (default: the first up trip leaving the first "
                         "station in the peak period)")
    a = ap.parse_args(argv)
    if a.no_records and a.out is not None:
        print("error: --no-records leaves nothing to write to --out", file=sys.stderr)
        return 2
    if not (math.isfinite(a.delay_s) and 0.0 <= a.delay_s <= 3600.0):
        print(f"error: --delay-s must lie in [0, 3600] s, got {a.delay_s}", file=sys.stderr)
        return 2
    if a.delay_trip is not None and a.delay_s == 0.0:
        print("error: --delay-trip needs --delay-s", file=sys.stderr)
        return 2
    if a.delay_s > 0.0 and a.no_records:
        print("error: --delay-s reports from the records: not with --no-records",
              file=sys.stderr)
        return 2
    try:
        plan = load_day(a.day)
        holds = {}
        delayed = None
        if a.delay_s > 0.0:
            start = plan.termini[0].station
            day_trips_ = trips(plan)
            if a.delay_trip is None:
                delayed = first_trip_from(day_trips_, start,
                                          plan.periods[peak_period(plan)].start_s)
            else:
                delayed = next((t for t in day_trips_ if t.trip_id == a.delay_trip), None)
                if delayed is None:
                    raise ValueError(f"--delay-trip {a.delay_trip!r}: no such trip")
            st = 0 if delayed.origin == start else len(plan.line.station_codes) - 1
            holds[(delayed.trip_id, st)] = float(a.delay_s)
            h, m = divmod(int(delayed.departure_s) // 60, 60)
            print(json.dumps({"delay": {"trip_id": delayed.trip_id, "delay_s": a.delay_s,
                                        "origin": delayed.origin,
                                        "sched_departure_s": delayed.departure_s,
                                        "sched_departure": f"{h:02d}:{m:02d}"}}),
                  flush=True)
        dp = service_day(load_scenario(a.scenario), plan, seed=a.seed,
                         trip_times=a.trip_times, records=not a.no_records,
                         holds=holds, regulator=a.regulator)
    except (ValueError, FileNotFoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2

    def progress(d: DayPlant) -> None:
        print(json.dumps({"t_h": round(d.t / 3600.0, 2), "trips_run": d.trips_run,
                          "in_service": sum(tr.in_service for tr in d.trains),
                          "route_conflicts": d.route_conflicts,
                          "rss_mb": round(rss_mb(), 1)}), flush=True)

    res = dp.run(None if a.end_h is None else a.end_h * 3600.0, a.max_wall_s, progress,
                 sensors=a.sensors)
    late = [tb.terminal_delay_s for tb in res.turnbacks]
    sp = {k: round(v, 1) for k, v in res.speed().items()}
    extra: Dict[str, Any] = {"regulator": a.regulator}
    if not a.no_records:
        from .daykpi import day_kpis
        k = day_kpis(plan, res.stops, res.turnbacks, res.depot)
        extra["punctuality"] = k["punctuality"]
    if delayed is not None:
        extra["incident"] = incident_report(res.stops, res.turnbacks, delayed.trip_id) \
            if any(r.trip_id == delayed.trip_id for r in res.stops) else None
    print(json.dumps({**res.row(), "fleet_used": dp.circ.fleet,
                      "terminal_delay_max_s": max(late, default=math.nan),
                      "terminal_delay_mean_s": float(np.mean(late)) if late else math.nan,
                      **sp, "sensor_samples": res.sensor_samples,
                      "peak_rss_mb": round(peak_rss_mb(), 1), **extra,
                      "notes": res.notes[:5]}), flush=True)
    if a.out is not None:
        from pathlib import Path

        from .dayplots import write_day_outputs
        try:
            wrote = write_day_outputs(plan, res.stops, res.turnbacks, res.depot, Path(a.out),
                                      energy_j=dp.trip_energy_j)
        except OSError as exc:
            print(f"error: the day's outputs could not be written: {exc}", file=sys.stderr)
            return 4
        print(f"wrote {', '.join(str(v) for v in wrote.values())}", file=sys.stderr)
    ok = (res.finished and res.trips_run == res.trips_planned and res.atp_violations == 0
          and res.route_conflicts == 0 and res.missed_stops == 0)
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())


__all__ = ["Breakdown", "DayPlant", "DayResult", "DayTerminus", "PULL_OUT_LEAD_S",
           "REQUEST_LEAD_S", "STABLE_AFTER_S", "clear_of_stop", "day_layout", "day_trips",
           "fleet_scenario", "main",
           "peak_rss_mb", "plant_timed", "rss_mb", "service_day"]
