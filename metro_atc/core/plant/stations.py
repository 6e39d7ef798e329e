"""Stations and passengers: entries, arrivals, dwell, departures, overruns, turnback.

Dwell (Lin 2010a, eq. 10 with boarding during the dwell, :mod:`metro_atc.core.line.timetable`):
the doors close at max(ATS / timetable departure, passenger exchange done) plus the holds and
the departure disturbance drawn at the arrival; an ATS dwell cut closes them earlier (never
before the minimum dwell) and those left behind wait for the next train.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from metro_atc.core.line.geometry import LineGeometry
from metro_atc.core.line.scenario import Scenario
from metro_atc.core.line.service import ServicePlan
from metro_atc.core.line.timetable import required_dwell

from .fleet import DONE, RUN, TURNBACK, Fleet

HELD_S = 1.0e9
"""A commanded departure at or after this instant [s] holds the train at its platform until
a later command (a service day's berth waiting for its route): no departure is decided yet,
and the published state says so (departure time NaN, :mod:`.views`)."""

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]


@dataclass(frozen=True)
class TrainEvent:
    """Arrival at / departure from a station.

    ``delay_s`` is actual minus timetable time; ``boarded``/``alighted`` and ``dwell_s`` are
    filled on departures (arrivals carry 0).  ``stop_error_m`` is the berthing error of an
    arrival: train front minus the stop point at the standstill [m] (+ overrun); NaN for
    departures and for a train placed at its first platform on entry.
    """

    train_idx: int
    station_idx: int
    kind: str
    t_s: float
    boarded: int
    alighted: int
    dwell_s: float
    delay_s: float
    scheduled_t_s: float = math.nan
    stop_error_m: float = math.nan


class Stations:
    """Platform logic and passenger bookkeeping of a line; ATS commands per train/station."""

    def __init__(self, scn: Scenario, sv: ServicePlan, geom: LineGeometry, fl: Fleet,
                 extra_hold: FloatArray, rng: np.random.Generator) -> None:
        """No train entered yet; ``rng`` is the plant's stream (departure disturbances)."""
        self.scn = scn
        self.sv = sv
        self.geom = geom
        self.fl = fl
        self.rng = rng
        self.extra_hold = extra_hold
        n, n_st = scn.trains.count, len(scn.line.stations)
        self.n, self.n_st = n, n_st
        self.cmd_dep = np.full((n, n_st), math.nan)
        self.cmd_dwell_limit = np.full((n, n_st), math.nan)
        self.cmd_rt = np.full((n, n_st), math.nan)
        self.dwell_cut = np.zeros(n, dtype=bool)
        self.act_arr = np.full((n, n_st), math.nan)
        self.act_dep = np.full((n, n_st), math.nan)
        self.boarded = np.zeros((n, n_st))
        self.left_behind = np.zeros(n_st)
        # as if a punctual train had left one scheduled headway before the first one
        self.last_dep_t = np.array([sv.sched_dep[0, j] - sv.headways[
            sv.flow.period(sv.sched_dep[0, j])] for j in range(n_st)])
        self.pending_board = np.zeros(n)
        self.pending_alight = np.zeros(n)
        self.next_entry = 0
        self.skipped_stops = 0
        self.withdraw_at = np.full(n, -1, dtype=np.int64)
        """Station a dispatcher withdraws each train at (-1: none; it leaves service there
        after its passengers alighted, as at the terminus)."""
        self.withdrawn = np.zeros(n, dtype=bool)
        """Trains the dispatcher withdrew (out of service before the terminus)."""
        self.skip = np.zeros((n, n_st), dtype=bool)
        """Stops a dispatcher has each train run through (train, station)."""
        self.delay_draw = np.zeros(n)
        self.train_rng: list[np.random.Generator] | None = None
        """One stream per train for its disturbances (None: ``rng`` for all trains;
        :meth:`metro_atc.core.plant.line.LineSim.train_streams`)."""
        self.events: list[TrainEvent] = []
        self.keep_log = True
        """Keep every event in :attr:`events` (False: only the step's ``events_out``; a
        caller that records what it needs itself, e.g. a service day)."""
        self.events_out: list[TrainEvent] = []
        self.wrap_m = 0.0
        """Period of a loop line [m] (0: one-way): a train arriving at the last stop stands
        at the first one again, its position shifted by ``-wrap_m``
        (:mod:`metro_atc.core.service.loop`)."""

    def command(self, i: int, j: int, departure_time_s: float, target_running_time_s: float,
                dwell_limit_s: float) -> bool:
        """Store an ATS command; True when it moved the release of a train dwelling at j."""
        self.cmd_dep[i, j] = departure_time_s
        self.cmd_rt[i, j] = target_running_time_s
        self.cmd_dwell_limit[i, j] = dwell_limit_s
        fl = self.fl
        if fl.dwelling[i] and fl.cur_station[i] == j and fl.status[i] == RUN:
            self.set_release(i, j, redraw=False)
            return True
        return False

    def next_entry_t(self) -> float:
        """Scheduled entry of the next train [s] (inf when all entered)."""
        if self.next_entry < self.n:
            return float(self.sv.sched_arr[self.next_entry, 0])
        return math.inf

    def emit(self, i: int, j: int, kind: str, t: float, boarded: float = 0.0,
             alighted: float = 0.0, dwell: float = 0.0,
             stop_error_m: float = math.nan) -> None:
        """Record an arrival/departure event."""
        sched = self.sv.sched_arr[i, j] if kind == "arrival" else self.sv.sched_dep[i, j]
        ev = TrainEvent(i, j, kind, t, int(round(boarded)), int(round(alighted)), dwell,
                        t - sched, float(sched), float(stop_error_m))
        if self.keep_log:
            self.events.append(ev)
        self.events_out.append(ev)

    def try_entry(self, t: float, fixed_block: bool, margin: float) -> bool:
        """Put the next train on the first platform when due and the platform is clear.

        Returns False while a due train is blocked by the one ahead (platform occupied).
        """
        fl, g = self.fl, self.geom
        i = self.next_entry
        if t < self.sv.sched_arr[i, 0] - 1e-9:
            return True
        if i > 0 and fl.status[i - 1] in (RUN, TURNBACK):
            rear_lead = float(fl.x[i - 1]) - g.length_m
            if fixed_block:  # the block holding the rear must be clear of the platform
                rear_lead = g.x0 + math.floor((rear_lead - g.x0) / g.block_len) * g.block_len
            if rear_lead < g.x_first_stop + margin + 1.0:
                return False
        self.next_entry += 1
        self.enter(i, 0, t)
        return True

    def enter(self, i: int, j: int, t: float) -> None:
        """Train i enters service standing at the stop of station j (doors open at ``t``)."""
        fl, g = self.fl, self.geom
        x = float(g.station_positions_m[j])
        fl.status[i] = RUN
        fl.set_xv(i, x, 0.0)
        fl.a_dem[i] = -fl.p.max_service_brake_mps2
        fl.stop_x[i] = x
        self.arrive(i, j, t)

    def pull_in(self, i: int, t: float) -> None:
        """Train i leaves service from where it stands (to a depot; parked, empty).

        It may :meth:`enter` again later (the same train, its state kept).
        """
        fl = self.fl
        fl.status[i] = DONE
        fl.x_done[i] = fl.x[i]
        fl.set_xv(i, self.geom.x_park, 0.0)
        fl.dwelling[i] = False
        fl.release_t[i] = math.inf
        fl.done_t[i] = math.inf
        fl.load[i] = 0.0
        fl.set_mass_from_load(i)

    def arrive(self, i: int, j: int, t: float, stop_error_m: float = math.nan) -> None:
        """Doors open at station j: alighting, boarding forecast, departure hold time.

        ``stop_error_m``: train front minus the stop point at the standstill [m].
        """
        fl = self.fl
        fl.dwelling[i] = True
        fl.set_xv(i, float(fl.x[i]), 0.0)
        fl.cur_station[i] = j
        fl.next_stop[i] = self.next_served(i, j)
        self.act_arr[i, j] = t
        fl.arr_t[i] = t
        alight = fl.load[i] * (1.0 if self.withdraw_at[i] == j else self.sv.alight_frac[j])
        self.pending_alight[i] = alight
        self.emit(i, j, "arrival", t, stop_error_m=stop_error_m)
        self.set_release(i, j, redraw=True)

    def next_served(self, i: int, j: int) -> int:
        """The first stop of train i after station j it does not skip (never the terminus)."""
        k = j + 1
        while k < self.n_st - 1 and self.skip[i, k]:
            k += 1
        return k

    def last_stop(self, i: int, j: int) -> bool:
        """Whether station j ends train i's service (the terminus, or its withdrawal)."""
        return j == self.n_st - 1 or int(self.withdraw_at[i]) == j

    def set_release(self, i: int, j: int, redraw: bool) -> None:
        """Departure time = max(ATS/timetable, passenger dwell done) + holds + delay."""
        fl, sv = self.fl, self.sv
        ps = self.scn.passengers
        t_arr = float(fl.arr_t[i])
        room = fl.p.capacity_pax - (fl.load[i] - self.pending_alight[i])
        last = self.last_stop(i, j)
        if last:
            d_req = max(ps.door_overhead_s + ps.alighting_s_per_pax * self.pending_alight[i],
                        ps.min_dwell_s)
            board = 0.0
        else:
            waiting = self.left_behind[j] + sv.flow.arrivals(j, self.last_dep_t[j], t_arr)
            d_req, board = required_dwell(waiting, sv.flow.rate(j, t_arr),
                                          self.pending_alight[i], room,
                                          ps.boarding_s_per_pax, ps.alighting_s_per_pax,
                                          ps.door_overhead_s, ps.min_dwell_s)
        self.pending_board[i] = board
        cand = t_arr + d_req
        cut = self.cmd_dwell_limit[i, j]
        if math.isfinite(cut):  # ATS dwell cut: doors close at the limit (>= minimum dwell)
            cand = min(cand, t_arr + max(float(cut), ps.min_dwell_s))
        cmd = self.cmd_dep[i, j]
        hold = cmd if math.isfinite(cmd) else float(sv.sched_dep[i, j])
        cand = max(cand, hold)
        self.dwell_cut[i] = cand < t_arr + d_req - 1e-9
        if redraw:
            dis = self.scn.disturbances
            delay = 0.0
            rng = self.rng if self.train_rng is None else self.train_rng[i]
            if not last and rng.random() < dis.departure_delay_prob:
                delay = float(rng.exponential(dis.departure_delay_mean_s))
            self.delay_draw[i] = delay
        cand += float(self.delay_draw[i]) + float(self.extra_hold[i, j])
        cand = max(cand, float(fl.broken_until[i]))
        fl.release_t[i] = cand

    def depart(self, i: int, t: float) -> None:
        """Doors closed: boarding bookkeeping, departure event, start the next run."""
        fl, sv, g = self.fl, self.sv, self.geom
        j = int(fl.cur_station[i])
        fl.dwelling[i] = False
        fl.release_t[i] = math.inf
        dwell = t - float(fl.arr_t[i])
        alight = float(self.pending_alight[i])
        fl.load[i] -= alight
        board = 0.0
        last = self.last_stop(i, j)
        if not last:
            waiting = self.left_behind[j] + sv.flow.arrivals(j, self.last_dep_t[j], t)
            room = max(fl.p.capacity_pax - fl.load[i], 0.0)
            board = min(waiting, room)
            if self.dwell_cut[i]:  # doors closed by the ATS: boarding time ran out
                ps = self.scn.passengers
                t_board = dwell - ps.door_overhead_s - ps.alighting_s_per_pax * alight
                board = min(board, max(t_board, 0.0) / max(ps.boarding_s_per_pax, 1e-9))
            self.left_behind[j] = waiting - board
            self.last_dep_t[j] = t
            fl.load[i] += board
        self.dwell_cut[i] = False
        self.boarded[i, j] = board
        fl.set_mass_from_load(i)
        self.act_dep[i, j] = t
        self.emit(i, j, "departure", t, board, alight, dwell)
        if last and j < self.n_st - 1:  # withdrawn by the dispatcher: out of service here
            self.withdrawn[i] = True
            self.leave_service(i, j)
        elif j == self.n_st - 1:
            fl.status[i] = TURNBACK
            fl.next_stop[i] = self.n_st
            fl.stop_x[i] = g.x_tail_stop
        else:
            k = self.next_served(i, j)
            fl.next_stop[i] = k
            fl.stop_x[i] = g.station_positions_m[k]
            sig = self.scn.disturbances.running_time_noise
            rng = self.rng if self.train_rng is None else self.train_rng[i]
            fl.trac_level[i] = 1.0 - abs(float(rng.normal(0.0, sig))) if sig > 0 else 1.0

    def station_logic(self, t: float, hit: BoolArray, d: FloatArray) -> None:
        """Arrivals (standstill within tolerance of the stop point) and overruns."""
        fl, g = self.fl, self.geom
        tol = g.tol_stop
        for ii in np.flatnonzero(hit):
            i = int(ii)
            if fl.v[i] <= 0.0 and abs(d[i]) <= tol:
                if fl.status[i] == TURNBACK:
                    fl.dwelling[i] = True  # in the siding: turnback time runs
                    fl.done_t[i] = t + self.scn.line.turnback_s
                else:
                    j = int(fl.next_stop[i])
                    if self.wrap_m and j == self.n_st - 1:  # the loop's last stop is stop 0
                        fl.set_xv(i, float(fl.x[i]) - self.wrap_m, 0.0)
                        j = 0
                    self.arrive(i, j, t, float(d[i]))
            elif d[i] > tol:
                if fl.status[i] == TURNBACK:
                    continue  # the buffer-stop authority stops it; accept any standstill
                j = int(fl.next_stop[i])
                self.skipped_stops += 1
                fl.cur_station[i] = j
                if self.withdraw_at[i] == j:  # overran its withdrawal: the next one (if any)
                    self.withdraw_at[i] = j + 1 if j + 1 < self.n_st - 1 else -1
                if j >= self.n_st - 1:
                    # overran the terminus: passengers alight in the tail track
                    fl.status[i] = TURNBACK
                    fl.next_stop[i] = self.n_st
                    fl.stop_x[i] = g.x_tail_stop
                else:
                    k = self.next_served(i, j)
                    fl.next_stop[i] = k
                    fl.stop_x[i] = g.station_positions_m[k]
            # stopped short in the tail track (TURNBACK, v = 0, d < -tol): the turnback
            # driver creeps on

    def finish_turnbacks(self, t: float) -> None:
        """Trains whose turnback time is over leave service (parked beyond the grid end)."""
        fl = self.fl
        tb_done = (fl.status == TURNBACK) & (fl.done_t <= t + 1e-9)
        for i in np.flatnonzero(tb_done):
            self.leave_service(int(i), self.n_st - 1)

    def leave_service(self, i: int, j: int) -> None:
        """Train i leaves service at station j (parked beyond the grid end)."""
        fl, g = self.fl, self.geom
        fl.status[i] = DONE
        fl.x_done[i] = fl.x[i]
        fl.set_xv(i, g.x_park, 0.0)
        fl.dwelling[i] = False
        fl.done_t[i] = math.inf
        fl.cur_station[i] = j
