"""The metro line plant: :class:`LineSim` sequences the plant modules (ROS-free, SI units).

One control period per :meth:`LineSim.step`, one compiled call over the trains.

Per step: timed discrete events (:mod:`.incidents`, :mod:`.stations`) -> ATP supervision and
safety monitors (:mod:`.atp`) -> jerk-limited demand -> traction / blended brake / adhesion
(:mod:`.braking`) -> RK4 with energy quadrature (:mod:`.dynamics`, :mod:`.energy`) -> sensor
snapshot (:mod:`.sensors`) -> arrivals and overruns (:mod:`.stations`).  The static line
(geometry, rolling stock, timetable) is :mod:`metro_atc.core.line`; the KPIs are computed
from :meth:`LineSim.run_log` (:mod:`.kpi`).  The effort is held constant over a control
period and its rate is jerk limited (Ke 2010, 1.0 m/s^3; the emergency brake builds up at
``emergency_jerk_mps3``).  The continuous part of a step (ATP to energy) is one compiled
call (:mod:`.fast`, :mod:`.kernel`, :mod:`.kernel_step`) whose physics is
:mod:`metro_atc.core.laws`; ``NUMBA_DISABLE_JIT=1`` runs the same source uncompiled.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from metro_atc.core.line.adhesion import CURVES, AdhesionCurve
from metro_atc.core.line.rolling_stock import KMH, PRESETS, train_params_for
from metro_atc.core.line.scenario import Scenario
from metro_atc.core.line.service import describe
from metro_atc.core.line.vehicle import TrainParams

from .atp import AtpSupervisor
from .braking import N_AXLES_SENSED, Brakes
from .driver import simple_driver
from .energy import EnergyMeter
from .fast import FastSensors, NumbaStepper
from .fast_run import DrivenRun, run_compiled
from .fleet import (DONE, MODE_ACCEL, MODE_ATP, MODE_BRAKE, MODE_COAST, MODE_CRUISE,
                    MODE_DWELL, MODE_OUT, RUN, Fleet, Status)
from .incidents import Incidents
from .kpi import RunLog, compute_kpis
from .sensors import BrakeSensorSample, SensorBlock, Sensors, StepResult
from .stations import Stations, TrainEvent
from .tables import VehicleTables
from .views import plant_run_log, plant_states

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]

__all__ = ["DrivenRun", "KMH", "MODE_ACCEL", "MODE_ATP", "MODE_BRAKE", "MODE_COAST", "MODE_CRUISE",
           "MODE_DWELL", "MODE_OUT", "N_AXLES_SENSED", "PRESETS", "BrakeSensorSample",
           "LineSim", "SensorBlock", "Status", "StepResult", "TrainEvent", "train_params_for"]


class LineSim:
    """Lockstep simulator of one metro line scenario (see module docstring).

    The components are public: ``fleet``, ``atp``, ``brakes``, ``energy``, ``stations``,
    ``incidents``, ``sensors`` and the static ``geometry``/``service``/``p``; their state is
    read and written there (``sim.fleet.x``, ``sim.atp.eb``, ``sim.service.sched_dep``), or
    through the read-only views of :mod:`.views`.  LineSim forwards none of their attributes.
    """

    checkpoint_transient = ("_car_mass",)
    """A cache of the load-weigh signal (recomputed when the masses change)."""
    _car_mass: tuple[Any, ...] = (None, None, None)

    def __init__(self, scn: Scenario, seed: int = 0, params: TrainParams | None = None,
                 trace_period_s: float = 1.0) -> None:
        """Build the line, timetable and fleet of ``scn``; ``seed`` drives all randomness.

        ``params`` replaces the scenario's rolling stock (tests); ``trace_period_s`` > 0
        records positions/speeds every that many seconds for the plots (0 disables).
        """
        self.scn = scn
        self.seed = int(seed)
        self.rng = np.random.default_rng(self.seed)
        self.description = d = describe(scn, params)
        self.p = p = d.params
        self.geometry = g = d.geometry
        self.service = sv = d.service
        self.control_period_s = dt = float(scn.sim.control_period_s)
        self.substeps = int(scn.sim.physics_substeps)
        self.duration_s = float(scn.sim.duration_s)
        self.t = 0.0
        self.step_count = 0
        self.n = n = scn.trains.count
        self.train_ids = scn.train_ids
        self.n_st = len(scn.line.stations)
        self.station_names = sv.station_names
        self.station_codes = sv.station_codes
        self.station_positions_m = g.station_positions_m
        self.curve: AdhesionCurve = CURVES[scn.line.adhesion]
        self.length_m = g.length_m
        self.tol_stop = g.tol_stop
        self.tables = VehicleTables(p, self.curve)
        self.fleet = Fleet(n, p, g, scn.trains.initial_load_pax)
        self.brakes = Brakes(n, p, self.curve, self.tables, dt)
        self.atp = AtpSupervisor(scn, p, g, self.tables, self.curve, sv.b_drive)
        self.energy = EnergyMeter(n, p, scn.energy.regen_receptivity, dt)
        self.incidents = Incidents(scn, self.n_st)
        self.stations = Stations(scn, sv, g, self.fleet, self.incidents.extra_hold, self.rng)
        self.sensors: Sensors = FastSensors(scn, self.seed, self.incidents.sensor_faults)
        self._t_next = 0.0
        self._refresh_tsr(force=True)
        self._masks()
        self.trace_every = (max(int(round(trace_period_s / dt)), 1)
                            if trace_period_s > 0 else 0)
        self.trace: dict[str, list[Any]] = {"t": [], "x": [], "v": [], "run": [],
                                            "atp": []}
        self.stepper = NumbaStepper(self)
        self._car_mass = (None, None, None)  # (mass, meff, mass / cars)

    # ------------------------------------------------------------------ public API

    @property
    def done(self) -> bool:
        """True when every train has completed its service or the duration is reached."""
        return self.fleet.n_done == self.n or self.t >= self.duration_s - 1e-9

    @property
    def fx(self) -> FloatArray:
        """Rail force on each sensed axle F_x [N] ([n, 4]; > 0 retards the train; eq. 4)."""
        return self.brakes.ax.get()[0]

    @property
    def clamp(self) -> FloatArray:
        """Clamp force of each sensed axle F_c [N] ([n, 4])."""
        return self.brakes.ax.get()[1]

    @property
    def slip(self) -> FloatArray:
        """Slip ratio of each sensed axle [-] ([n, 4])."""
        return self.brakes.ax.get()[2]

    def active_mask(self) -> BoolArray:
        """Trains in service that must send a command this step (not turning back)."""
        return np.asarray(self.fleet.status == RUN)

    def set_departure(self, train_idx: int, station_idx: int, departure_time_s: float,
                      target_running_time_s: float = math.nan,
                      dwell_limit_s: float = math.nan) -> None:
        """ATS command for a train at a station (NaN = unset).

        ``departure_time_s``: the train is held at the platform until then (and until its
        passenger exchange is done); ``target_running_time_s``: the run to the next station
        (the ATO's target, recorded for the KPIs); ``dwell_limit_s``: the ATS cuts the dwell
        -- the doors close ``dwell_limit_s`` after the arrival (never before the minimum
        dwell nor before ``departure_time_s``) even if passengers are still boarding; those
        left behind wait for the next train.  The departure disturbance drawn at the
        arrival is added in every case.
        """
        if not 0 <= train_idx < self.n or not 0 <= station_idx < self.n_st:
            raise IndexError(f"train {train_idx} / station {station_idx} out of range")
        for val in (departure_time_s, target_running_time_s, dwell_limit_s):
            if math.isinf(val):
                raise ValueError("departure command values must be finite or NaN")
        if self.stations.command(train_idx, station_idx, departure_time_s,
                                 target_running_time_s, dwell_limit_s):
            self._t_next = min(self._t_next, float(self.fleet.release_t[train_idx]))

    def tsrs_changed(self) -> None:
        """``incidents.tsrs`` changed (a dispatcher's TSR): new calendar, grids at ``t``."""
        self.incidents.reschedule_tsrs()
        self._refresh_tsr(force=True)
        self._t_next = min(self._t_next, self.incidents.next_t())

    def hold_changed(self, train_idx: int, station_idx: int) -> None:
        """``incidents.extra_hold[train_idx, station_idx]`` changed (a dispatcher's hold).

        A train dwelling there gets its departure time again (an infinite hold: none).
        """
        fl = self.fleet
        if fl.dwelling[train_idx] and fl.cur_station[train_idx] == station_idx \
                and fl.status[train_idx] == RUN:
            self.stations.set_release(train_idx, station_idx, redraw=False)
            self._t_next = min(self._t_next, float(fl.release_t[train_idx]))

    def breakdown(self, train_idx: int, duration_s: float) -> None:
        """Train ``train_idx`` breaks down now for ``duration_s`` [s] (then recovers).

        As a scenario's ``breakdown`` incident (:mod:`.incidents`): it stops and stays.
        """
        if not 0 <= train_idx < self.n:
            raise IndexError(f"train {train_idx} out of range")
        if not (math.isfinite(duration_s) and duration_s > 0.0):
            raise ValueError("breakdown duration must be finite and > 0 s")
        self.incidents.push(self.t, "breakdown", train=int(train_idx), dur=float(duration_s))
        self._t_next = min(self._t_next, self.t)

    def enter(self, train_idx: int, station_idx: int) -> None:
        """Train ``train_idx`` enters service now at station ``station_idx`` (a pull-out).

        The timetabled entries are then switched off (:meth:`external_entries`).
        """
        self.stations.enter(int(train_idx), int(station_idx), self.t)
        self._masks()

    def pull_in(self, train_idx: int) -> None:
        """Train ``train_idx`` leaves service now from where it stands (to the depot)."""
        self.stations.pull_in(int(train_idx), self.t)
        self._masks()

    def external_entries(self, wrap_m: float = 0.0) -> None:
        """No timetabled entries (:meth:`enter` places trains); ``wrap_m`` [m]: loop period.

        A loop line's last stop is its first again (:attr:`.stations.Stations.wrap_m`).
        """
        self.stations.next_entry = self.n
        self.stations.wrap_m = float(wrap_m)
        self._masks()

    def external_authority(self) -> None:
        """Each train's end of authority comes from outside (:meth:`set_authority_ends`).

        For a fleet whose index order is not its track order (a service day's loop): no
        train ahead by index, so the caller also checks the separation.
        """
        self.atp.lead_ext = True
        self.stepper.set_constant("lead_ext", 1.0)

    def set_authority_ends(self, train_idx: Any, x_m: Any) -> None:
        """End of movement authority of trains ``train_idx`` from outside [m] (array-like).

        Read by the compiled step from the next step on (inf: none; the train ahead and the
        line's end bound it as well).  ValueError on NaN or a length mismatch.
        """
        if np.isnan(x := np.asarray(x_m, dtype=float)).any():
            raise ValueError("authority ends must not be NaN")
        self.atp.eoa_ext[train_idx] = x

    def train_streams(self, seeds: Any) -> None:
        """Each train draws its disturbances from its own stream ``default_rng(seeds[i])``.

        Departure delays and running-time noise do not depend on the other trains' draws.
        """
        if len(seeds) != self.n:
            raise ValueError(f"{len(seeds)} seeds for {self.n} trains")
        self.stations.train_rng = [np.random.default_rng(int(s)) for s in seeds]

    def withdraw(self, train_idx: int, station_idx: int) -> None:
        """A dispatcher withdraws train ``train_idx`` at station ``station_idx`` (ahead).

        It runs there, its passengers alight (all, as at the terminus), nobody boards, and
        it leaves service at its departure (:meth:`Stations.leave_service`).
        """
        self.stations.withdraw_at[train_idx] = station_idx

    def skip_stop(self, train_idx: int, station_idx: int) -> None:
        """A dispatcher has train ``train_idx`` run through station ``station_idx`` (ahead).

        Nobody alights or boards there; a train heading for it now heads for the stop after
        (its ATO plans the run past it from the state's ``next_station``).
        """
        st, fl = self.stations, self.fleet
        st.skip[train_idx, station_idx] = True
        if int(fl.next_stop[train_idx]) == station_idx and fl.status[train_idx] == RUN:
            k = st.next_served(train_idx, station_idx - 1)
            fl.next_stop[train_idx] = k
            if not fl.dwelling[train_idx]:
                fl.stop_x = fl.stop_x.copy()
                fl.stop_x[train_idx] = self.geometry.station_positions_m[k]

    def next_stop_position(self) -> FloatArray:
        """Chainage of each train's next stop point [m] (tail stop while turning back)."""
        return self.fleet.stop_x.copy()

    def states(self) -> dict[str, Any]:
        """Per-train state arrays (copies); ``mode`` uses the TrainState.MODE_* values."""
        return plant_states(self)

    def event_log(self) -> list[TrainEvent]:
        """All events so far in time order."""
        return list(self.stations.events)

    def energy_breakdown(self) -> dict[str, FloatArray]:
        """Per-train energy terms [J] (wheel traction, braking, resistance, grade, ...)."""
        fl = self.fleet
        return self.energy.breakdown(0.5 * (fl.mass + fl.m_rot) * fl.v ** 2 * (fl.status != DONE))

    def run_log(self) -> RunLog:
        """What the KPIs need from this run (copies; :func:`.views.plant_run_log`)."""
        return plant_run_log(self)

    def kpis(self) -> dict[str, Any]:
        """KPI dictionary (JSON-serialisable); see :func:`metro_atc.core.plant.kpi.compute_kpis`.

        The safety monitors check the last state first.
        """
        self.atp.monitor_now(self.fleet)
        return compute_kpis(self.run_log())

    # ------------------------------------------------------------------ discrete logic

    def _refresh_tsr(self, force: bool = False) -> None:
        """Recompute the supervision grids when a TSR becomes known / in force / lifted."""
        inc, g = self.incidents, self.geometry
        if inc.tsr_changed(self.t, force):
            self.atp.refresh(inc.ceiling(g, self.t, self.atp.tsr_notice_s),
                             inc.ceiling(g, self.t, 0.0))

    def _masks(self) -> None:
        """Recompute the discrete-state masks and the next discrete time."""
        fl = self.fleet
        fl.update_masks(self.t)
        self.sensors.set_running(fl.run)
        self._t_next = min(fl.next_discrete_t(), self.incidents.next_t(),
                           self.stations.next_entry_t())

    def _discrete(self, t: float) -> None:
        """Timed discrete events due at ``t``: faults, TSRs, entries, departures, turnbacks."""
        inc, fl, st = self.incidents, self.fleet, self.stations
        if inc.queue and inc.queue[0][0] <= t + 1e-9:
            inc.process_queue(t, fl, self.brakes)
        if t >= inc.next_tsr_t - 1e-9:
            self._refresh_tsr()
        rel = fl.dwelling & (fl.release_t <= t + 1e-9)
        for i in np.flatnonzero(rel):
            st.depart(int(i), t)
        st.finish_turnbacks(t)
        blocked = False
        if st.next_entry < self.n:
            blocked = not st.try_entry(t, self.atp.fixed_block, self.atp.margin)
        self._masks()
        if blocked and self._t_next > t:
            self._t_next = t + 0.5 * self.control_period_s  # keep trying every step

    # ------------------------------------------------------------------ stepping

    def step(self, u: Any) -> StepResult:
        """Advance one control period with normalised commands ``u`` [n_trains] in [-1, 1].

        NaN entries keep the previous command; values are clipped to [-1, 1].  Trains at a
        platform, broken down or out of service ignore their command; ATP may override it.
        """
        return self._step(u, True)

    def _step(self, u: Any, discrete: bool) -> StepResult:  # False: discrete events done
        fl, atp, p = self.fleet, self.atp, self.p
        ua = np.asarray(u, dtype=float)
        if ua.shape != (self.n,):
            raise ValueError(f"u must have shape ({self.n},), got {ua.shape}")
        events: list[TrainEvent] = []
        self.stations.events_out = events
        t = self.t
        dt = self.control_period_s
        if discrete and t >= self._t_next - 1e-9:
            self._discrete(t)
        v = fl.v
        t_new = t + dt
        sen = self.sensors
        due = sen.due(t_new)
        ts = sen.sample_times(t_new) if due else None
        # the compiled step also drives the turning-back trains (auto_u None)
        n_int, hit, d = self.stepper.advance(self, ua, None, due, ts)
        v1 = fl.v
        self.t = t_new
        self.step_count += 1
        if self.trace_every and self.step_count % self.trace_every == 0:
            tr = self.trace
            tr["t"].append(t_new)
            tr["x"].append(fl.x.copy())
            tr["v"].append(v1.copy())
            tr["run"].append(fl.run)
            tr["atp"].append(atp.atp_limit.copy())
        # sensors (snapshot now, samples generated on demand)
        snap = None
        if ts is not None:
            br = self.brakes
            cm = self._car_mass
            if cm[0] is not fl.mass or cm[1] is not fl.meff:  # masses change at stations
                cm = self._car_mass = (fl.mass, fl.meff, fl.mass / p.cars)
            snap = sen.snapshot(ts, t, t_new, br.ax_prev, br.ax, br.r_w, fl.acc, v, v1,
                                cm[2])
        # stations
        if hit is not None:
            self.stations.station_logic(t_new, hit, d)
            self._masks()
        return StepResult(events, snap, n_int, sen)

    def run_driven(self, until_s: float, samples: bool = True) -> DrivenRun:
        """``while not done and t < until_s: step(simple_driver(self))``, samples read if asked.

        Several steps per compiled call (:mod:`.fast_run`).
        """
        out, st = DrivenRun(), self.stations
        while not self.done and self.t < until_s:
            u = simple_driver(self)  # before the step's discrete events, as in the loop
            if self.t >= self._t_next - 1e-9:
                st.events_out = out.events
                self._discrete(self.t)
            lim = self.t + 0.5 * self.control_period_s if self.done else until_s  # 1 step
            k, hit, d = run_compiled(self, u, self._t_next, lim, samples, out)
            if not k:
                out.add(self._step(u, False), samples)
            elif hit is not None:
                st.events_out = out.events
                st.station_logic(self.t, hit, d)
                self._masks()
        return out
