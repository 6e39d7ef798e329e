"""The metro line plant: train dynamics, stations, dwell, ATP, energy and sensors (ROS-free).

:class:`LineSim` advances all trains of a scenario in lockstep, one control period per
:meth:`LineSim.step`, vectorised over trains with numpy.

Modelling choices (SI units throughout):

* **Dynamics** -- RK4 (seed 004) on ``M_eff dv/dt = F_trac - F_brake - F_r(v) - F_grade -
  F_curve`` with ``M_eff = m + lambda m_nominal`` (rotary allowance on the tare+nominal
  mass, passengers add non-rotating mass), Davis resistance (seed 002 eq. 1-2), traction
  curve (seed 002 eq. 3-5) times the per-run traction level, grade and Roeckl curve
  resistance averaged over the train length.  Effort is held constant over a control period
  (``physics_substeps`` RK4 steps) and its rate is jerk limited (seed 001, 1.0 m/s^3; the
  emergency brake builds up at ``emergency_jerk_mps3``).  Trains never roll back.
* **Braking** -- blended brake-by-wire: the electric (regenerative) brake on the motored
  axles up to its power/force/fade limits, friction brake for the rest spread over all
  axles, the emergency brake is friction only.  Each axle's rail force is limited by the
  slip-adhesion curve (dry/wet); wheel-slide protection (WSP) keeps a sliding axle at
  least at the locked-wheel adhesion.  The *instrumented car* (a 4-axle trailer car, so no
  traction/electric-brake torque on its axles) is modelled axle by axle with seed 000
  (2nd paper) eq. 4 ``J_w dw/dt = -2 mu_b R_b F_c + r_w F_x`` where **F_x > 0 retards the
  train**; pad-friction and wheel faults act there.
* **Energy** -- per train: traction work at the wheel, rail braking work split into
  electric (regenerated x efficiency x receptivity) and friction, resistance, curve and
  grade work, kinetic energy; substation energy = wheel traction / efficiency + auxiliary
  - regenerated.  The balance closes to RK4 accuracy (test_plant_energy.py).
* **ATP** -- see :mod:`metro_atc.core.plant.track` (seed 001 Fig. 1): moving-block end of
  authority = rear of the train ahead minus the safety margin (fixed block: entry of the
  first occupied block minus the margin), static/temporary speed-limit supervision, service
  brake intervention ``sbi_lead_s`` before the emergency-brake intervention, EB latched to
  standstill.  ATP is independent of the driver/ATO command.  Separation and overspeed are
  monitored separately and counted as *violations* (must stay 0).
"""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .adhesion import CURVES, AdhesionCurve
from .scenario import Scenario, ScenarioError
from .timetable import (PassengerFlow, dispatch_times, nominal_dwells, required_dwell,
                        schedule)
from .track import (G, braking_envelope, cell_min, curve_resistance_per_kg,
                    step_profile, window_min_ahead, window_min_behind)
from .vehicle import (THSR_700T, TAIPEI_MRT_6CAR, TrainParams, max_traction_accel,
                      train_params_from_spec)

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]

KMH = 1.0 / 3.6
"""km/h -> m/s."""

MODE_OUT, MODE_DWELL, MODE_ACCEL, MODE_CRUISE, MODE_COAST, MODE_BRAKE, MODE_ATP = range(7)

_ST_WAIT, _ST_RUN, _ST_TURNBACK, _ST_DONE = 0, 1, 2, 3

PRESETS: dict[str, TrainParams] = {"taipei_mrt_6car": TAIPEI_MRT_6CAR, "thsr_700t": THSR_700T}
"""Rolling-stock presets by scenario name."""

N_AXLES_SENSED = 4
"""Axles of the instrumented car published in the brake sensor samples."""

_cnz = np.count_nonzero


@dataclass(frozen=True)
class TrainEvent:
    """Arrival at / departure from a station.

    ``delay_s`` is actual minus timetable time; ``boarded``/``alighted`` and ``dwell_s`` are
    filled on departures (arrivals carry 0).
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


@dataclass(frozen=True)
class BrakeSensorSample:
    """One brake-by-wire sensor sample of a train's instrumented car (NaN = dropout)."""

    train_idx: int
    t_s: float
    wheel_omega_radps: tuple[float, float, float, float]
    clamp_force_n: tuple[float, float, float, float]
    accel_x_mps2: float
    ref_speed_mps: float
    car_mass_kg: float = math.nan
    """Load-weigh signal of the instrumented car: train mass / cars [kg]."""


@dataclass
class _SensorBlock:
    """Vectorised sensor samples of one step (converted to objects on demand)."""

    t: FloatArray
    trains: IntArray
    omega: FloatArray  # [n_samples, n_trains_sensed, 4]
    clamp: FloatArray
    accel: FloatArray  # [n_samples, n_trains_sensed]
    vref: FloatArray
    car_mass: FloatArray  # [n_trains_sensed] load-weigh signal [kg]


class _AxleState:
    """Instrumented-car axle state of one step: (F_x, clamp force, slip) per axle [n, 4].

    In the common case (no axle sliding, no WSP action) only the per-train friction share
    and demand are stored and the per-axle arrays are derived on first use (sensor samples,
    tests); sliding steps store the integrated arrays directly.
    """

    __slots__ = ("f_fa", "a_d", "w_axle", "coef", "arrays")

    def __init__(self, f_fa: FloatArray, a_d: FloatArray, w_axle: FloatArray,
                 coef: tuple[Any, ...],
                 arrays: tuple[FloatArray, FloatArray, FloatArray] | None = None) -> None:
        """Store the step's inputs (or the explicit arrays of a sliding step)."""
        self.f_fa, self.a_d, self.w_axle, self.coef = f_fa, a_d, w_axle, coef
        self.arrays = arrays

    def get(self) -> tuple[FloatArray, FloatArray, FloatArray]:
        """(fx, clamp, slip), each [n_trains, 4]."""
        if self.arrays is None:
            fc_per_n, tb_coef, inv_rw2, adh, jw, tab_mu, tab_slip = self.coef
            fc = self.f_fa[:, None] * fc_per_n * np.ones_like(tb_coef)
            fx = fc * tb_coef + (jw * np.minimum(self.a_d, 0.0))[:, None] * inv_rw2
            slip = np.interp(fx / (self.w_axle[:, None] * adh), tab_mu, tab_slip)
            self.arrays = (fx, fc, slip)
        return self.arrays


@dataclass
class _SensorSnap:
    """Noise-free truth of one step for the sensor samples (built lazily)."""

    ts: FloatArray
    t0: float
    t1: float
    mask: BoolArray
    ax0: _AxleState
    ax1: _AxleState
    r_w: FloatArray
    acc: FloatArray
    v0: FloatArray
    v1: FloatArray
    car_mass: FloatArray


class StepResult:
    """Outcome of one :meth:`LineSim.step` (events, sensor samples, ATP interventions).

    Sensor samples are generated (noise, faults) on first access of :attr:`sensors` or
    :attr:`sensor_arrays`, from a separate random stream, so reading them or not never
    changes the plant trajectory.
    """

    def __init__(self, events: list[TrainEvent], snap: _SensorSnap | None,
                 atp_interventions: int, sim: "LineSim") -> None:
        """Wrap the step outputs; sensor samples are built lazily on first access."""
        self.events = events
        self.atp_interventions = atp_interventions
        self._snap = snap
        self._sim = sim
        self._block: _SensorBlock | None = None
        self._sensors: list[BrakeSensorSample] | None = None

    @property
    def sensor_arrays(self) -> _SensorBlock | None:
        """Vectorised samples: t [s], trains, omega/clamp [s, train, 4], accel/vref [s, train]."""
        if self._block is None and self._snap is not None:
            self._block = self._sim._sensor_block(self._snap)
            self._snap = None
        return self._block

    @property
    def sensors(self) -> list[BrakeSensorSample]:
        """Brake sensor samples taken during this step, in time order."""
        if self._sensors is None:
            out: list[BrakeSensorSample] = []
            b = self.sensor_arrays
            if b is not None:
                for s in range(b.t.size):
                    for ii, tr in enumerate(b.trains):
                        om = b.omega[s, ii]
                        cf = b.clamp[s, ii]
                        out.append(BrakeSensorSample(
                            int(tr), float(b.t[s]),
                            (float(om[0]), float(om[1]), float(om[2]), float(om[3])),
                            (float(cf[0]), float(cf[1]), float(cf[2]), float(cf[3])),
                            float(b.accel[s, ii]), float(b.vref[s, ii]),
                            float(b.car_mass[ii])))
            self._sensors = out
        return self._sensors


@dataclass
class _TimedEvent:
    t: float
    kind: str
    data: dict[str, Any] = field(default_factory=dict)


def train_params_for(scn: Scenario) -> TrainParams:
    """Rolling stock of a scenario: preset with the scenario's data applied."""
    return train_params_from_spec(PRESETS[scn.trains.preset], scn.trains, scn.energy)


class LineSim:
    """Lockstep simulator of one metro line scenario (see module docstring)."""

    def __init__(self, scn: Scenario, seed: int = 0, params: TrainParams | None = None,
                 trace_period_s: float = 1.0) -> None:
        """Build the line, timetable and fleet of ``scn``; ``seed`` drives all randomness.

        ``params`` replaces the scenario's rolling stock (tests); ``trace_period_s`` > 0
        records positions/speeds every that many seconds for the plots (0 disables).
        """
        self.scn = scn
        self.seed = int(seed)
        self.rng = np.random.default_rng(self.seed)
        self.rng_sensors = np.random.default_rng([self.seed, 1])
        self.p = p = params if params is not None else train_params_for(scn)
        self.control_period_s = float(scn.sim.control_period_s)
        self.substeps = int(scn.sim.physics_substeps)
        self.duration_s = float(scn.sim.duration_s)
        self.t = 0.0
        self.step_count = 0
        self.n = scn.trains.count
        self.train_ids = scn.train_ids
        st = scn.line.stations
        self.n_st = len(st)
        self.station_names = [s.name for s in st]
        self.station_codes = [s.code for s in st]
        self.station_positions_m = np.array([s.position_m for s in st], dtype=float)
        self.curve: AdhesionCurve = CURVES[scn.line.adhesion]
        self._mu_pk = self.curve.mu_peak
        self._mu_wsp = 0.5 * (self.curve.mu_peak + self.curve.mu_slide)
        self.length_m = float(p.length_m)
        self.tol_stop = float(scn.line.stop_tolerance_m)
        self._build_track()
        self._build_fleet()
        self._build_atp()
        self._build_timetable()
        self._build_incidents_and_faults()
        self._build_sensors()
        self._refresh_tsr(force=True)
        self._masks()
        self.trace_every = (max(int(round(trace_period_s / self.control_period_s)), 1)
                            if trace_period_s > 0 else 0)
        self.trace: dict[str, list[Any]] = {"t": [], "x": [], "v": [], "run": [],
                                            "atp": []}

    # ------------------------------------------------------------------ construction

    def _build_track(self) -> None:
        """Grid of limits, grades and curve resistance (see :mod:`.track`)."""
        scn, p = self.scn, self.p
        ln = scn.line
        self.dx = dx = float(scn.sim.grid_m)
        self.x_first_stop = float(self.station_positions_m[0])
        self.x_last_stop = float(self.station_positions_m[-1])
        self.x0 = self.x_first_stop - self.length_m - 500.0
        self.x_end = self.x_last_stop + ln.tail_track_m  # buffer stop
        self.x_tail_stop = self.x_end - 15.0
        self.x_switch = self.x_last_stop + 30.0
        self.n_sid = int(ln.turnback_sidings)
        if self.x_tail_stop - self.length_m <= self.x_switch + 10.0:
            raise ScenarioError(f"scenario {scn.source_file}: line.tail_track_m: expected >= "
                                f"train length + 55 m = {self.length_m + 55.0:g}, "
                                f"got {ln.tail_track_m:g}")
        self.eoa_end = self.x_end - 5.0
        n_cells = int(math.ceil((self.x_end + 200.0 - self.x0) / dx)) + 1
        self.n_cells = n_cells
        nodes: FloatArray = self.x0 + dx * np.arange(n_cells + 1, dtype=float)
        self.grid_x = nodes[:-1]
        self.inv_dx = 1.0 / dx
        self.x_park = self.x_end + 100.0  # where completed trains are kept (inside the grid)
        lim = step_profile([s.start_m for s in ln.speed_limits],
                           [s.limit_kmh * KMH for s in ln.speed_limits],
                           ln.line_speed_kmh * KMH, nodes)
        lim = np.minimum(lim, p.max_speed_mps)
        lim = np.where(nodes > self.x_last_stop + 1.0, np.minimum(lim, ln.tail_speed_kmh * KMH),
                       lim)
        self.static_limit = cell_min(lim)  # per cell [m/s]
        grade = step_profile([g.start_m for g in ln.gradients],
                             [g.grade_permille / 1000.0 for g in ln.gradients], 0.0,
                             nodes[:-1] + 0.5 * dx)
        self.max_down = float(max(0.0, -float(np.min(grade)))) if grade.size else 0.0
        curv = np.zeros(n_cells)
        xc = nodes[:-1] + 0.5 * dx
        for c in ln.curves:
            m = (xc >= c.start_m) & (xc < c.end_m)
            curv[m] = curve_resistance_per_kg(c.radius_m)
        self.n_len = max(int(round(self.length_m / dx)), 1)
        self.grade_cell = grade
        # averages over the train length behind the front (mass distributed along it)
        self.sin_avg = self._avg_behind(np.sin(np.arctan(grade)))
        self.gsin_avg = G * self.sin_avg
        self.curve_avg = self._avg_behind(curv)
        self.ceiling_tol = scn.signalling.overspeed_margin_kmh * KMH

    def _avg_behind(self, c: FloatArray) -> FloatArray:
        cs = np.concatenate([[0.0], np.cumsum(c)])
        k = np.arange(c.size)
        lo = np.maximum(k + 1 - self.n_len, 0)
        return np.asarray((cs[k + 1] - cs[lo]) / (k + 1 - lo))

    def _build_fleet(self) -> None:
        """Per-train state arrays."""
        n, p = self.n, self.p
        self.x = np.full(n, self.x_first_stop)
        self.x_done = np.full(n, math.nan)
        self.v = np.zeros(n)
        self.acc = np.zeros(n)
        self.a_dem = np.zeros(n)
        self.u_last = np.zeros(n)
        self.status = np.zeros(n, dtype=np.int64)
        self.mode = np.zeros(n, dtype=np.int64)
        self.next_stop = np.zeros(n, dtype=np.int64)
        self.cur_station = np.full(n, -1, dtype=np.int64)
        self.stop_x = np.full(n, self.x_first_stop)
        self.dwelling = np.zeros(n, dtype=bool)
        self.release_t = np.full(n, math.inf)
        self.arr_t = np.full(n, math.nan)
        self.broken_until = np.full(n, -math.inf)
        self.trac_level = np.ones(n)
        self.load = np.full(n, float(self.scn.trains.initial_load_pax))
        self.mass = p.mass_kg + (self.load - p.nominal_load_pax) * p.pax_mass_kg
        self.m_rot = p.rotary_allowance * p.mass_kg
        self.eb = np.zeros(n, dtype=bool)
        self.sb = np.zeros(n, dtype=bool)
        self.interventions = np.zeros(n, dtype=np.int64)
        self.violations = np.zeros(n, dtype=np.int64)
        self.in_violation = np.zeros(n, dtype=bool)
        self.any_violation = False
        self.any_atp = False
        self.any_slide = False
        self.any_wsp = False
        self.eoa = np.full(n, self.eoa_end)
        self.atp_limit = np.full(n, p.max_speed_mps)
        self.speed_code = np.full(n, p.max_speed_mps)
        self.min_sep = math.inf
        self.skipped_stops = 0
        # energy [J]
        self.e_trac = np.zeros(n)
        self.e_elec = np.zeros(n)
        self.e_fric = np.zeros(n)
        self.e_res = np.zeros(n)
        self.e_curve = np.zeros(n)
        self.e_grade = np.zeros(n)
        self.n_in_service = np.zeros(n, dtype=np.int64)  # steps in service (auxiliary load)
        self.e_stop_corr = np.zeros(n)  # |brake work re-assigned in steps ending at rest|
        # axles
        n_ax = p.cars * p.axles_per_car
        self.n_ax = n_ax
        self.n_mot = int(round(p.motored_axle_fraction * n_ax))
        self.n_trail_plain = n_ax - self.n_mot - N_AXLES_SENSED
        if self.n_trail_plain < 0:
            raise ValueError("the instrumented 4-axle car must be a trailer car: "
                             "motored_axle_fraction too high")
        self.pad_mu = np.full((n, N_AXLES_SENSED), p.pad_mu_nominal)
        self.adh_factor = np.ones((n, N_AXLES_SENSED))
        self.r_w = np.full((n, N_AXLES_SENSED), p.wheel_radius_m)
        self.sliding = np.zeros((n, N_AXLES_SENSED), dtype=bool)
        self.wsp = np.zeros((n, N_AXLES_SENSED), dtype=bool)
        self.omega = np.zeros((n, N_AXLES_SENSED))
        z4 = np.zeros((n, N_AXLES_SENSED))
        self._ax = _AxleState(np.zeros(n), np.zeros(n), np.ones(n), (), (z4, z4, z4))
        self._ax_prev = self._ax
        # speed tables: traction phi(v) [m/s^2] (seed 002 eq. 3-5), max electric brake [N]
        self._tab_v = np.linspace(0.0, p.max_speed_mps * 1.2 + 5.0, 4001)
        self._tab_phi = max_traction_accel(p, self._tab_v)
        vv = np.maximum(self._tab_v, 1e-3)
        self._tab_ebrake = np.minimum(p.max_service_brake_mps2 * p.mass_kg,
                                      p.max_regen_power_w / vv) \
            * np.minimum(self._tab_v / p.regen_fade_speed_mps, 1.0)
        # inverse adhesion curve on the stable branch: mu -> slip
        cur = self.curve
        self._tab_slip = np.linspace(0.0, cur.slip_peak, 400)
        self._tab_mu = cur.mu(self._tab_slip)
        self._g_per_axle = G / n_ax
        self._trac_adh = cur.mu_peak * self.n_mot
        self._jw = p.wheel_inertia_kgm2
        self._fc_per_n = p.wheel_radius_m / (2.0 * p.pad_mu_nominal * p.brake_radius_m)
        self._jerk_dt = p.max_jerk_mps3 * self.control_period_s
        self._jerk_eb_dt = p.emergency_jerk_mps3 * self.control_period_s
        self._aux_dt = p.aux_power_w * self.control_period_s
        self._regen_eff = p.regen_efficiency * self.scn.energy.regen_receptivity
        self._axle_coefs()
        self.events: list[TrainEvent] = []
        self._events_out: list[TrainEvent] = []
        self._delay_draw = np.zeros(n)

    def _build_atp(self) -> None:
        """ATP constants (seed 001 Fig. 1) and the worst-case assumptions."""
        scn, p = self.scn, self.p
        sg = scn.signalling
        b_lvl = sg.guaranteed_decel_mps2
        if b_lvl is None:
            # adhesion-limited guarantee: locked-wheel adhesion with 10 % margin
            # (empty train: smallest adhesion mass relative to the rotating allowance)
            tare = max(p.mass_kg - p.nominal_load_pax * p.pax_mass_kg, 0.3 * p.mass_kg)
            b_lvl = min(p.emergency_brake_mps2,
                        0.9 * self.curve.mu_slide * G * tare / (tare + self.m_rot))
        self.b_guar_level = float(b_lvl)
        self.b_g = float(b_lvl - G * self.max_down)
        if self.b_g <= 0.05:
            raise ValueError("guaranteed emergency braking is not positive on the steepest "
                             "downhill grade")
        self.a_w = float(p.a1_mps2 + G * self.max_down)
        self.t_r = float(sg.response_time_s)
        self.margin = float(sg.safety_margin_m)
        self.t_sbi = float(sg.sbi_lead_s)
        self.fixed_block = sg.mode == "fixed_block"
        self.block_len = float(scn.line.block_length_m)
        d_r = p.max_speed_mps * self.t_r + 0.5 * self.a_w * self.t_r ** 2
        self.n_resp = int(math.ceil(d_r / self.dx)) + 1
        self.n_sbi = int(math.ceil(p.max_speed_mps * self.t_sbi / self.dx)) + 1
        # v_ebi(D) = sqrt(c0 + c1 D) - c2 (track.ebi_speed with target 0) with the worst-case
        # response acceleration at the current speed, a_w(v) = phi(v) + g max_down (traction
        # only falls as the speed rises during the response time, so this is conservative)
        b, tr = self.b_g, self.t_r
        self._c0a = (b * tr) ** 2
        self._c0b = b * tr * tr
        self._c1 = 2.0 * b
        self._c2a = b * tr
        self._g_down = G * self.max_down
        # worst case at standstill (used by the reference driver)
        self._c0 = self._c0a + self._c0b * self.a_w
        self._c2 = self._c2a + self.a_w * tr
        # static curve: v + a_w(v) t_r <= E  ->  v = g^-1(E), g monotone on the speed table
        aw_tab = self._tab_phi + self._g_down
        g_tab = np.maximum.accumulate(self._tab_v + aw_tab * tr)
        self._ebi_g_tab = g_tab
        self._aw0_tr = float(aw_tab[0] * tr)
        self.b_drive = 0.6 * p.max_service_brake_mps2

    def _build_timetable(self) -> None:
        """Dispatch times, minimum and scheduled running times, dwells (seed 000 eq. 10)."""
        scn, p = self.scn, self.p
        per = scn.timetable.periods
        self.flow = PassengerFlow([q.start_s for q in per],
                                  np.array([q.boarding_pph for q in per], dtype=float))
        self.headways = [q.headway_s for q in per]
        ps = scn.passengers
        self.alight_frac = np.array(ps.alight_fraction, dtype=float)
        self.alight_frac[-1] = 1.0
        self.sched_dwell, _ = nominal_dwells(
            self.flow, self.headways, self.alight_frac, p.capacity_pax,
            scn.trains.initial_load_pax, ps.boarding_s_per_pax, ps.alighting_s_per_pax,
            ps.door_overhead_s, ps.min_dwell_s)
        self.dispatch = dispatch_times(scn.timetable.first_departure_s, self.n, self.flow,
                                       self.headways)
        self._refresh_drive_envelope(self.static_limit)
        self.min_running_s = self._min_running_times()
        self.sched_running_s = self.min_running_s * (1.0 + scn.timetable.running_time_margin)
        self.sched_arr, self.sched_dep = schedule(self.dispatch, self.sched_dwell,
                                                  self.sched_running_s, self.flow)
        self.cmd_dep = np.full((self.n, self.n_st), math.nan)
        self.cmd_dwell_limit = np.full((self.n, self.n_st), math.nan)
        self.dwell_cut = np.zeros(self.n, dtype=bool)
        self.cmd_rt = np.full((self.n, self.n_st), math.nan)
        self.act_arr = np.full((self.n, self.n_st), math.nan)
        self.act_dep = np.full((self.n, self.n_st), math.nan)
        self.boarded = np.zeros((self.n, self.n_st))
        self.left_behind = np.zeros(self.n_st)
        # as if a punctual train had left one scheduled headway before the first one
        self.last_dep_t = np.array([self.sched_dep[0, j] - self.headways[
            self.flow.period(self.sched_dep[0, j])] for j in range(self.n_st)])
        self.pending_board = np.zeros(self.n)
        self.pending_alight = np.zeros(self.n)
        self.next_entry = 0
        self.n_done = 0
        self.done_t = np.full(self.n, math.inf)
        self.extra_hold = np.zeros((self.n, self.n_st))

    def _min_running_times(self) -> FloatArray:
        """Flat-out running time per inter-station section [s] on the driving envelope.

        Forward pass ``v_{k+1}^2 = v_k^2 + 2 a(v_k) dx`` with full traction minus resistance
        and grade, capped by the driving envelope (limits and braking to the stop point).
        """
        p, dx = self.p, self.dx
        m = p.mass_kg
        meff = m + self.m_rot
        out = np.zeros(self.n_st - 1)
        for j in range(self.n_st - 1):
            k0 = self._cell(self.station_positions_m[j])
            k1 = self._cell(self.station_positions_m[j + 1])
            xs = self.grid_x[k0:k1 + 1]
            cap = np.minimum(self.drive_env[k0:k1 + 1],
                             np.sqrt(2.0 * self.b_drive * np.maximum(
                                 self.station_positions_m[j + 1] - xs, 0.0)))
            v = 0.0
            tsum = 0.0
            for k in range(k1 - k0):
                fa = (m * float(max_traction_accel(p, v)) - p.davis_a_n - p.davis_b_n_per_mps * v
                      - p.davis_c_n_per_mps2 * v * v
                      - m * G * (self.sin_avg[k0 + k] + self.curve_avg[k0 + k])) / meff
                v2 = math.sqrt(max(v * v + 2.0 * max(fa, 0.0) * dx, 0.0))
                v2 = min(v2, float(cap[k + 1]))
                tsum += 2.0 * dx / max(v + v2, 0.05)
                v = v2
            out[j] = tsum
        return out

    def _build_incidents_and_faults(self) -> None:
        """Timed-event queue from incidents and faults."""
        scn = self.scn
        self._queue: list[tuple[float, int, _TimedEvent]] = []
        self._qseq = 0
        tid = {t: i for i, t in enumerate(self.train_ids)}
        self.tsrs: list[tuple[float, float, float, float, float]] = []
        for t in scn.line.temporary_speed_limits:
            self.tsrs.append((t.start_m, t.end_m, t.limit_kmh * KMH, t.from_s, t.to_s))
        for inc in scn.incidents:
            if inc.kind == "tsr":
                self.tsrs.append((inc.start_m, inc.end_m, inc.limit_kmh * KMH, inc.at_s,
                                  inc.at_s + inc.duration_s))
            elif inc.kind == "hold":
                j = scn.station_index(inc.station)
                self.extra_hold[tid[inc.train], j] += inc.duration_s
            elif inc.kind == "breakdown":
                self._push(inc.at_s, "breakdown", train=tid[inc.train], dur=inc.duration_s)
        notice = scn.signalling.tsr_notice_s
        self._tsr_times = sorted({max(f - notice, 0.0) for (_, _, _, f, _) in self.tsrs}
                                 | {f for (_, _, _, f, _) in self.tsrs}
                                 | {e for (_, _, _, _, e) in self.tsrs if math.isfinite(e)})
        self._tsr_ptr = 0
        self.sensor_faults: list[dict[str, Any]] = []
        for fl in scn.faults:
            i = tid[fl.train]
            axes = list(range(N_AXLES_SENSED)) if fl.axle == 0 else [fl.axle - 1]
            if fl.kind in ("pad_mu", "wheel"):
                self._push(fl.at_s, "fault_on", train=i, axles=axes, spec=fl)
                if math.isfinite(fl.duration_s):
                    self._push(fl.at_s + fl.duration_s, "fault_off", train=i, axles=axes,
                               spec=fl)
            else:
                self.sensor_faults.append({"train": i, "axles": axes, "kind": fl.kind,
                                           "channel": fl.channel, "t0": fl.at_s,
                                           "t1": fl.at_s + fl.duration_s, "stuck": None})

    def _build_sensors(self) -> None:
        scn = self.scn
        tid = {t: i for i, t in enumerate(self.train_ids)}
        ids = scn.sensors.trains or self.train_ids
        self.sensed = np.array(sorted(tid[t] for t in ids), dtype=np.int64)
        self.sensed_mask = np.zeros(self.n, dtype=bool)
        self.sensed_mask[self.sensed] = True
        self.sensor_dt = 1.0 / scn.sensors.rate_hz
        self.next_sample_t = self.sensor_dt
        self.run = np.zeros(self.n, dtype=bool)
        self._next_tsr_t = 0.0
        self._t_next = 0.0

    def _axle_coefs(self) -> None:
        """Per-axle coefficients of the instrumented car (refreshed when faults change)."""
        p = self.p
        self._tb_coef = 2.0 * self.pad_mu * p.brake_radius_m / self.r_w  # F_x per clamp N
        self._inv_rw2 = 1.0 / (self.r_w * self.r_w)
        self._cap_coef = self._mu_pk * self.adh_factor
        adh = self.adh_factor.copy()
        self._ax_coef = (self._fc_per_n, self._tb_coef, self._inv_rw2, adh, self._jw,
                         self._tab_mu, self._tab_slip)
        # fast path: tread of the 4 sensed axles = f_fa * inst_sum; a slide is possible only
        # where f_fa * slide_ratio exceeds the axle load (the J_w term only lowers F_x)
        inst = self._fc_per_n * self._tb_coef
        self._inst_sum = inst.sum(axis=1)
        self._fric_mult = (self.n_ax - N_AXLES_SENSED) + self._inst_sum
        self._slide_ratio = np.max(inst / self._cap_coef, axis=1)

    @property
    def e_brake_rail(self) -> FloatArray:
        """Braking work at the wheels, electric + friction [J] per train."""
        return np.asarray(self.e_elec + self.e_fric)

    @property
    def e_regen(self) -> FloatArray:
        """Regenerated energy returned to the line [J] per train."""
        return np.asarray(self.e_elec * self._regen_eff)

    @property
    def e_aux(self) -> FloatArray:
        """Auxiliary energy drawn while in service [J] per train."""
        return np.asarray(self.n_in_service * self._aux_dt)

    @property
    def fx(self) -> FloatArray:
        """Rail force on each sensed axle F_x [N] ([n, 4]; > 0 retards the train; eq. 4)."""
        return self._ax.get()[0]

    @property
    def clamp(self) -> FloatArray:
        """Clamp force of each sensed axle F_c [N] ([n, 4])."""
        return self._ax.get()[1]

    @property
    def slip(self) -> FloatArray:
        """Slip ratio of each sensed axle [-] ([n, 4])."""
        return self._ax.get()[2]

    def _push(self, t: float, kind: str, **data: Any) -> None:
        self._qseq += 1
        heapq.heappush(self._queue, (t, self._qseq, _TimedEvent(t, kind, data)))

    def _cell(self, x: float) -> int:
        return int(min(max((x - self.x0) / self.dx, 0), self.n_cells - 1))

    # ------------------------------------------------------------------ ATP curves

    def _tsr_ceiling(self, t: float, notice: float) -> FloatArray:
        """Per-cell limit incl. TSRs in force at ``t`` (known ``notice`` s ahead) [m/s]."""
        lim = self.static_limit.copy()
        for (a, b, v, f, e) in self.tsrs:
            if f - notice <= t < e:
                k0 = int(math.floor((a - self.x0) / self.dx))
                k1 = int(math.ceil((b - self.x0) / self.dx))
                k0, k1 = max(k0, 0), min(k1, self.n_cells)
                lim[k0:k1] = np.minimum(lim[k0:k1], v)
        return lim

    def _refresh_tsr(self, force: bool = False) -> None:
        """Recompute the supervision grids when a TSR becomes known / in force / lifted."""
        changed = force
        while self._tsr_ptr < len(self._tsr_times) and self._tsr_times[self._tsr_ptr] <= self.t:
            self._tsr_ptr += 1
            changed = True
        if not changed:
            return
        self._next_tsr_t = (self._tsr_times[self._tsr_ptr]
                            if self._tsr_ptr < len(self._tsr_times) else math.inf)
        notice = self.scn.signalling.tsr_notice_s
        lim_atp = self._tsr_ceiling(self.t, notice)
        lim_phys = self._tsr_ceiling(self.t, 0.0)
        ceil_atp = window_min_behind(lim_atp, self.n_len) + self.ceiling_tol
        env = braking_envelope(ceil_atp, self.dx, self.b_g)
        e_min = window_min_ahead(env, self.n_resp)
        self.ebi_static = np.where(e_min < self._ebi_g_tab[0], e_min - self._aw0_tr,
                                   np.interp(e_min, self._ebi_g_tab, self._tab_v))
        self.sbi_static = window_min_ahead(self.ebi_static, self.n_sbi)
        self.limit_eff = window_min_behind(lim_atp, self.n_len)
        self.ceiling_phys = window_min_behind(lim_phys, self.n_len) + self.ceiling_tol
        self._refresh_drive_envelope(lim_atp)

    def _refresh_drive_envelope(self, lim: FloatArray) -> None:
        """Service-brake envelope of (limit - 2 km/h) used by the reference driver [m/s]."""
        target = np.maximum(window_min_behind(lim, self.n_len) - 2.0 * KMH, 1.0)
        self.drive_env = braking_envelope(target, self.dx, self.b_drive)

    # ------------------------------------------------------------------ public API

    @property
    def done(self) -> bool:
        """True when every train has completed its service or the duration is reached."""
        return self.n_done == self.n or self.t >= self.duration_s - 1e-9

    def active_mask(self) -> BoolArray:
        """Trains in service that must send a command this step (not turning back)."""
        return np.asarray(self.status == _ST_RUN)

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
        self.cmd_dep[train_idx, station_idx] = departure_time_s
        self.cmd_rt[train_idx, station_idx] = target_running_time_s
        self.cmd_dwell_limit[train_idx, station_idx] = dwell_limit_s
        if self.dwelling[train_idx] and self.cur_station[train_idx] == station_idx \
                and self.status[train_idx] == _ST_RUN:
            self._set_release(train_idx, station_idx, redraw=False)
            self._t_next = min(self._t_next, float(self.release_t[train_idx]))

    def next_stop_position(self) -> FloatArray:
        """Chainage of each train's next stop point [m] (tail stop while turning back)."""
        return self.stop_x.copy()

    def states(self) -> dict[str, Any]:
        """Per-train state arrays (copies); ``mode`` uses the TrainState.MODE_* values."""
        run = self.run
        return {
            "x_m": np.where(self.status == _ST_DONE, self.x_done, self.x),
            "v_mps": self.v.copy(), "a_mps2": self.acc.copy(),
            "mode": self._modes(), "current_station": self.cur_station.copy(),
            "next_station": np.where(run | (self.status == _ST_WAIT),
                                     np.where(self.next_stop < self.n_st, self.next_stop, -1),
                                     -1),
            "traction_energy_j": self.e_trac.copy(), "regen_energy_j": self.e_regen.copy(),
            "atp_limit_mps": np.maximum(self.atp_limit, 0.0),
            "movement_authority_m": self.eoa.copy(),
            "speed_code_mps": self.speed_code.copy(),
            "atp_interventions": self.interventions.copy(), "load_pax": self.load.copy(),
            "in_service": run.copy(),
            "target_running_time_s": self._target_rt(),
            "departure_time_s": self._target_dep(),
        }

    def _target_dep(self) -> FloatArray:
        """Commanded (else scheduled) departure time from the current station [s]."""
        j = np.clip(self.cur_station, 0, self.n_st - 1)
        rows = np.arange(self.n)
        dep = self.cmd_dep[rows, j]
        return np.where(np.isfinite(dep), dep, self.sched_dep[rows, j])

    def _target_rt(self) -> FloatArray:
        j = np.clip(self.cur_station, 0, self.n_st - 2)
        rt = self.cmd_rt[np.arange(self.n), j]
        return np.where(np.isfinite(rt), rt, self.sched_running_s[j])

    def event_log(self) -> list[TrainEvent]:
        """All events so far in time order."""
        return list(self.events)

    # ------------------------------------------------------------------ stepping

    def _masks(self) -> None:
        """Recompute the discrete-state masks after any discrete change."""
        st = self.status
        self.run = (st == _ST_RUN) | (st == _ST_TURNBACK)
        self.broken = self.broken_until > self.t
        self.hold = self.dwelling | self.broken | ~self.run
        self.cand = self.run & ~self.dwelling
        self.auto = (st == _ST_TURNBACK) & ~self.dwelling
        self.any_auto = bool(self.auto.any())
        self.any_turnback = bool((st == _ST_TURNBACK).any())
        self._lead_add = np.where(self.run[:-1], 0.0, math.inf)
        self.any_sensed = bool((self.run & self.sensed_mask).any())
        self.any_broken = bool(self.broken.any())
        self.n_done = int(np.count_nonzero(st == _ST_DONE))
        nxt = min(float(self.release_t.min()), float(self.done_t.min()), self._next_tsr_t)
        if self._queue:
            nxt = min(nxt, self._queue[0][0])
        if self.any_broken:
            nxt = min(nxt, float(self.broken_until[self.broken].min()))
        if self.next_entry < self.n:
            nxt = min(nxt, float(self.sched_arr[self.next_entry, 0]))
        self._t_next = nxt

    def _discrete(self, t: float) -> None:
        """Timed discrete events due at ``t``: faults, TSRs, entries, departures, turnbacks."""
        if self._queue and self._queue[0][0] <= t + 1e-9:
            self._process_queue(t)
        if t >= self._next_tsr_t - 1e-9:
            self._refresh_tsr()
        rel = self.dwelling & (self.release_t <= t + 1e-9)
        for i in np.flatnonzero(rel):
            self._depart(int(i), t)
        tb_done = (self.status == _ST_TURNBACK) & (self.done_t <= t + 1e-9)
        for i in np.flatnonzero(tb_done):
            self.status[i] = _ST_DONE
            self.x_done[i] = self.x[i]
            self._set_xv(int(i), self.x_park, 0.0)
            self.dwelling[i] = False
            self.done_t[i] = math.inf
            self.cur_station[i] = self.n_st - 1
        blocked = False
        if self.next_entry < self.n:
            blocked = not self._try_entry(t)
        self._masks()
        if blocked and self._t_next > t:
            self._t_next = t + 0.5 * self.control_period_s  # keep trying every step

    def step(self, u: Any) -> StepResult:
        """Advance one control period with normalised commands ``u`` [n_trains] in [-1, 1].

        NaN entries keep the previous command; values are clipped to [-1, 1].  Trains at a
        platform, broken down or out of service ignore their command; ATP may override it.
        """
        ua = np.asarray(u, dtype=float)
        if ua.shape != (self.n,):
            raise ValueError(f"u must have shape ({self.n},), got {ua.shape}")
        nan = np.isnan(ua)
        if _cnz(nan):
            ua = np.where(nan, self.u_last, ua)
        ua = np.minimum(np.maximum(ua, -1.0), 1.0)
        self.u_last = ua
        events: list[TrainEvent] = []
        self._events_out = events
        t = self.t
        dt = self.control_period_s
        if t >= self._t_next - 1e-9:
            self._discrete(t)
        if self.any_auto:
            from .driver import driver_command
            ua = np.where(self.auto, driver_command(self), ua)
        p = self.p
        x, v = self.x, self.v
        run = self.run
        # ---------------- ATP supervision (independent of the command) + safety monitors
        obst = self._obstacle_rear(False)
        obst_sig = self._obstacle_rear(True) if self.fixed_block else obst
        self.eoa = eoa = np.minimum(obst_sig - self.margin, self.eoa_end)
        k = ((x - self.x0) * self.inv_dx).astype(np.int64)
        dist = eoa - x
        phi = np.interp(v, self._tab_v, self._tab_phi)
        aw = phi + self._g_down
        c0 = self._c0a + self._c0b * aw
        c2 = self._c2a + self.t_r * aw
        v_ma = np.sqrt(np.maximum(c0 + self._c1 * dist, 0.0)) - c2
        v_ebi = np.minimum(self.ebi_static[k], v_ma)
        v_sb_ma = np.sqrt(np.maximum(c0 + self._c1 * (dist - self.t_sbi * v), 0.0)) - c2
        v_sbi = np.minimum(self.sbi_static[k], v_sb_ma) - 0.3
        self.atp_limit = v_ebi
        if self.fixed_block:
            self._speed_codes(eoa)
            v_sbi = np.minimum(v_sbi, self.speed_code + 0.5 * self.ceiling_tol)
        over = run & (v > v_sbi)
        n_int = 0
        if self.any_atp or _cnz(over):
            moving = v > 0.0
            eb_prev, sb_prev = self.eb, self.sb
            eb = run & ((eb_prev & moving) | (v > v_ebi))
            sb = ~eb & (over | (sb_prev & moving & run & (v > v_sbi - 0.5)))
            onset = moving & ((eb & ~eb_prev) | (sb & ~sb_prev & ~eb_prev))
            n_int = int(np.count_nonzero(onset))
            if n_int:
                self.interventions += onset
            self.eb, self.sb = eb, sb
            self.any_atp = bool(_cnz(eb) or _cnz(sb))
        self._monitor(obst, k)
        # ---------------- demanded acceleration (jerk limited)
        mass = self.mass
        meff = mass + self.m_rot
        f_trac_max = phi * mass * self.trac_level
        bs = p.max_service_brake_mps2
        a_tgt = np.where(ua >= 0.0, ua * f_trac_max / meff, ua * bs)
        a_tgt = np.where(self.hold, -bs, a_tgt)
        jmax: Any = self._jerk_dt
        if self.any_atp or self.any_broken:
            eb = self.eb | self.broken
            a_tgt = np.where(self.sb, np.minimum(a_tgt, -bs), a_tgt)
            a_tgt = np.where(eb, -p.emergency_brake_actual_mps2, a_tgt)
            jmax = np.where(eb, self._jerk_eb_dt, jmax)
            eb_mask = eb
        else:
            eb_mask = None
        a_prev = self.a_dem
        a_d = np.minimum(np.maximum(a_tgt, a_prev - jmax), a_prev + jmax)
        self.a_dem = a_d
        # ---------------- forces: traction, blended electric/friction brake, adhesion
        w_axle = mass * self._g_per_axle
        f_trac = np.minimum(np.minimum(np.maximum(a_d, 0.0) * meff, f_trac_max),
                            w_axle * self._trac_adh)
        f_bdem = np.maximum(-a_d, 0.0) * meff
        f_e = np.minimum(f_bdem, np.interp(v, self._tab_v, self._tab_ebrake))
        if eb_mask is not None:
            f_e = np.where(eb_mask, 0.0, f_e)
        f_f = f_bdem - f_e
        f_brake = self._brake_rail_force(f_e, f_f, w_axle, a_d)
        # ---------------- RK4 (seed 004) with energy quadrature
        x0, v0 = x, v
        h = dt / self.substeps
        h2, h6 = 0.5 * h, h / 6.0
        inv_m = 1.0 / meff
        # accelerations: k(v) = q - v (cb + cc v), q = (F_const - F_g - F_c - A) / M_eff
        cb = p.davis_b_n_per_mps * inv_m
        cc = p.davis_c_n_per_mps2 * inv_m
        f_const = f_trac - f_brake - p.davis_a_n
        xs, vs = x, v
        w_res: Any = 0.0
        w_grade: Any = 0.0
        w_curve: Any = 0.0
        clamped = None
        for _ in range(self.substeps):
            kk = ((xs - self.x0) * self.inv_dx).astype(np.int64)
            f_g = mass * self.gsin_avg[kk]
            f_c = mass * self.curve_avg[kk]
            q = (f_const - f_g - f_c) * inv_m
            k1 = q - vs * (cb + cc * vs)
            v2 = vs + h2 * k1
            k2 = q - v2 * (cb + cc * v2)
            v3 = vs + h2 * k2
            k3 = q - v3 * (cb + cc * v3)
            v4 = vs + h * k3
            k4 = q - v4 * (cb + cc * v4)
            vn = vs + h6 * (k1 + 2.0 * (k2 + k3) + k4)
            dxs = h6 * (vs + 2.0 * (v2 + v3) + v4)
            # resistance work: Davis force = A + M_eff (q_A - k) with q_A = q + A / M_eff;
            # int F_r v dt by the same RK4 quadrature (the A term integrates to A dx)
            pr = ((q * dxs - h6 * (k1 * vs + 2.0 * (k2 * v2 + k3 * v3) + k4 * v4)) * meff
                  + p.davis_a_n * dxs)
            stop = vn <= 0.0
            if _cnz(stop):
                # standstill reached (or kept) inside the sub-step: no roll-back; the
                # distance is that of a uniform deceleration to rest (bounded by RK4's).
                # stopping distance at the deceleration of the sub-step start (exact for a
                # constant deceleration), bounded by the distance covered at constant speed
                vn = np.where(stop, 0.0, vn)
                d_stop = np.minimum(vs * vs / (-2.0 * np.minimum(k1, -1e-9)), h * vs)
                dxs = np.where(stop, d_stop, dxs)
                r1 = p.davis_a_n + vs * (p.davis_b_n_per_mps + p.davis_c_n_per_mps2 * vs)
                pr = np.where(stop, r1 * d_stop, pr)
                clamped = stop if clamped is None else (clamped | stop)
            w_res = w_res + pr
            w_grade = w_grade + f_g * dxs
            w_curve = w_curve + f_c * dxs
            xs = xs + dxs
            vs = vn
        x1, v1 = xs, vs
        dxt = x1 - x0
        # ---------------- energy metering
        w_trac = f_trac * dxt
        w_brk = f_brake * dxt
        if clamped is not None:
            # the friction brake absorbs what is left when the train comes to rest (its force
            # drops to the static holding value), so the balance closes exactly
            resid = w_trac - w_grade - w_curve - w_res - 0.5 * meff * (v1 * v1 - v0 * v0)
            w_new = np.where(clamped, np.maximum(resid, 0.0), w_brk)
            self.e_stop_corr += np.abs(w_new - w_brk)
            w_brk = w_new
        w_e = w_brk * (f_e / np.maximum(f_bdem, 1e-9))
        self.e_trac += w_trac
        self.e_elec += w_e
        self.e_fric += w_brk - w_e
        self.e_res += w_res
        self.e_curve += w_curve
        self.e_grade += w_grade
        self.n_in_service += run
        self.acc = (v1 - v0) * (1.0 / dt)
        self.x, self.v = x1, v1
        t_new = t + dt
        self.t = t_new
        self.step_count += 1
        if self.trace_every and self.step_count % self.trace_every == 0:
            tr = self.trace
            tr["t"].append(t_new)
            tr["x"].append(x1)
            tr["v"].append(v1)
            tr["run"].append(run)
            tr["atp"].append(v_ebi)
        # ---------------- sensors (snapshot now, samples generated on demand)
        snap = None
        if self.next_sample_t <= t_new + 1e-9 and self.any_sensed:
            snap = self._sensor_snapshot(t, t_new, v0, v1)
        # ---------------- stations
        d = x1 - self.stop_x
        hit = self.cand & ((d > self.tol_stop) | ((v1 <= 0.0) & (d >= -self.tol_stop)))
        if _cnz(hit):
            self._station_logic(t_new, hit, d)
        return StepResult(events, snap, n_int, self)

    def _monitor(self, obst: FloatArray, k: IntArray) -> None:
        """Independent safety monitors: separation and overspeed violations, min separation.

        Checks the state at the start of the step (= the end of the previous one) against the
        physical limits (not the ATP's anticipated ones); :meth:`kpis` checks the last state.
        """
        x, v, run = self.x, self.v, self.run
        gap = obst - x
        gmin = float(np.min(np.where(run, gap, math.inf)))
        if gmin < self.min_sep:
            self.min_sep = gmin
        bad = run & ((gap < self.margin - 1e-6) | (v > self.ceiling_phys[k] + 1e-6))
        if self.any_violation or _cnz(bad):
            new = bad & ~self.in_violation
            if new.any():
                self.violations += new
            self.in_violation = bad
            self.any_violation = bool(bad.any())

    def _modes(self) -> IntArray:
        """Operating mode per train from the last step (TrainState.MODE_* values)."""
        v, acc, a_d = self.v, self.acc, self.a_dem
        m = np.full(self.n, MODE_BRAKE)
        m = np.where(a_d > 0.02, np.where(acc > 0.05, MODE_ACCEL, MODE_CRUISE), m)
        m = np.where(np.abs(a_d) <= 0.02, MODE_COAST, m)
        m = np.where((a_d < -0.02) & (np.abs(acc) < 0.05) & (v > 0.5), MODE_CRUISE, m)
        m = np.where(self.eb | self.sb, MODE_ATP, m)
        m = np.where(self.dwelling, MODE_DWELL, m)
        return np.asarray(np.where(self.run, m, MODE_OUT))

    def _brake_rail_force(self, f_e: FloatArray, f_f: FloatArray, w_axle: FloatArray,
                          a_d: FloatArray) -> FloatArray:
        """Total braking force on the train [N] with adhesion limits (tread efforts).

        Plain axles: achieved = demand up to the peak adhesion, otherwise wheel-slide
        protection holds them at ``(mu_peak + mu_slide) / 2``.  The instrumented trailer car
        follows eq. 4 per axle (:meth:`_instrumented_axles`).  Fast path when no axle can
        reach the peak adhesion (the usual case): everything demanded is achieved.
        """
        n_ax, n_mot = self.n_ax, self.n_mot
        f_fa = f_f * (1.0 / n_ax)  # friction share per axle
        cap_pk = self._mu_pk * w_axle
        d_mot = f_e * (1.0 / max(n_mot, 1)) + f_fa  # the most loaded plain axle
        if not (self.any_slide or self.any_wsp or _cnz(d_mot > cap_pk)
                or _cnz(f_fa * self._slide_ratio > w_axle)):
            self._ax_prev, self._ax = self._ax, _AxleState(f_fa, a_d, w_axle, self._ax_coef)
            return np.asarray(f_e + f_fa * self._fric_mult)
        cap_wsp = self._mu_wsp * w_axle
        ach_mot = np.where(d_mot <= cap_pk, d_mot, cap_wsp)
        ach_tr = np.where(f_fa <= cap_pk, f_fa, cap_wsp)
        f_inst = self._instrumented_axles(f_fa, w_axle, a_d)
        return np.asarray(n_mot * ach_mot + self.n_trail_plain * ach_tr + f_inst)

    def _instrumented_axles(self, f_fa: FloatArray, w_axle: FloatArray,
                            a_d: FloatArray) -> FloatArray:
        """Per-axle eq. 4 for the 4 sensed axles; returns their total retarding force [N].

        Brake-by-wire sets the clamp force for the *nominal* pad friction, so a degraded pad
        (``pad_mu``) gives less torque.  Rolling axles are quasi-static (the wheel follows the
        train, ``w_dot = a / r_w``; the stiff creep dynamics settle in ~10 ms):
        ``F_x = (2 mu_b R_b F_c + J_w a / r_w) / r_w`` and the slip is read off the rising
        branch of the adhesion curve; demand above the peak adhesion starts a slide.
        """
        fc = f_fa[:, None] * self._fc_per_n  # [n, 4] (WSP below)
        if self.any_wsp:
            fc = np.where(self.wsp, 0.3 * fc, fc)
        tread = fc * self._tb_coef  # brake torque / r_w
        fx_roll = tread + (self._jw * np.minimum(a_d, 0.0))[:, None] * self._inv_rw2
        nload = w_axle[:, None]
        cap = nload * self._cap_coef
        if self.any_slide or _cnz(fx_roll > cap):
            return self._slide_axles(f_fa[:, None] * self._fc_per_n, fx_roll, cap, nload)
        slip = np.interp(fx_roll / (nload * self.adh_factor), self._tab_mu, self._tab_slip)
        self._ax_prev, self._ax = self._ax, _AxleState(f_fa, a_d, w_axle, self._ax_coef,
                                                       (fx_roll, fc, slip))
        # the train equation uses M_eff (wheelset inertia in the rotary allowance), so a rolling
        # axle contributes its tread effort T_b / r_w; F_x = tread + J_w a / r_w^2 is the rail
        # force of eq. 4 that the sensors/observer see.
        return np.asarray(tread.sum(axis=1))

    def _slide_axles(self, fc_raw: FloatArray, fx_roll: FloatArray, cap: FloatArray,
                     nload: FloatArray) -> FloatArray:
        """Integrate eq. 4 explicitly (5 ms) for sliding axles with wheel-slide protection.

        WSP dumps the clamp force to 30 % above 15 % slip and re-applies it below 1.5 x the
        peak slip; an axle returns to the quasi-static rolling model when its slip is back on
        the stable branch and the demand is below the peak adhesion.
        """
        cur = self.curve
        rw = self.r_w
        jw = self.p.wheel_inertia_kgm2
        v = np.maximum(self.v[:, None], 0.05)
        slide0 = self.sliding | (fx_roll > cap)
        s0 = np.where(self.sliding, self.slip, cur.slip_peak)
        omega = v * (1.0 - s0) / rw
        n_sub = max(int(round(self.control_period_s / 0.005)), 1)
        h = self.control_period_s / n_sub
        wsp = self.wsp.copy()
        tb_coef = 2.0 * self.pad_mu * self.p.brake_radius_m
        fx = fx_roll
        for _ in range(n_sub):
            s = np.clip(1.0 - omega * rw / v, 0.0, 1.0)
            wsp = np.where(s > 0.15, True, np.where(s < 1.5 * cur.slip_peak, False, wsp))
            tbm = tb_coef * fc_raw * np.where(wsp, 0.3, 1.0)
            fx = cur.mu(s) * self.adh_factor * nload
            omega = np.maximum(omega + h * (-tbm + rw * fx) / jw, 0.0)
        s = np.clip(1.0 - omega * rw / v, 0.0, 1.0)
        fc_now = fc_raw * np.where(wsp, 0.3, 1.0)
        demand = fc_now * self._tb_coef + (self._jw * np.minimum(self.a_dem, 0.0))[:, None] \
            * self._inv_rw2
        still = slide0 & ((s > cur.slip_peak) | (demand > cap))
        s_roll = np.interp(demand / (nload * self.adh_factor), self._tab_mu, self._tab_slip)
        self.sliding = still
        self.wsp = wsp & still
        self.any_slide = bool(still.any())
        self.any_wsp = bool(self.wsp.any())
        slip = np.where(still, s, s_roll)
        fx_all = np.where(still, fx, np.where(slide0, demand, fx_roll))
        clamp = np.where(slide0, fc_now, fc_raw)
        self._ax_prev, self._ax = self._ax, _AxleState(
            fc_raw[:, 0] / self._fc_per_n, self.a_dem, nload[:, 0], self._ax_coef,
            (fx_all, clamp, slip))
        tread = clamp * self._tb_coef
        # sliding axles transmit their adhesion force; rolling ones their tread effort
        return np.asarray(np.where(still, fx, tread).sum(axis=1))

    def _obstacle_rear(self, blocks: bool) -> FloatArray:
        """Chainage of the nearest obstacle ahead of each train's front [m] (inf if none).

        The train ahead on the running line (its rear; with ``blocks`` the entry of the block
        holding its rear), or -- beyond the terminus -- the train still standing in the
        turnback siding this train will use (siding ``i % turnback_sidings``); trains on a
        siding are off the running line for the others.
        """
        x, n, ns, run = self.x, self.n, self.n_sid, self.run
        rear = x - self.length_m
        if not (blocks or self.any_turnback):  # fast path: nobody near the sidings
            obst = np.empty(n)
            obst[0] = math.inf
            np.add(rear[:-1], self._lead_add, out=obst[1:])
            return obst
        obst = np.full(n, math.inf)
        on_siding = (self.status == _ST_TURNBACK) & (rear > self.x_switch)
        if n > 1:
            lead_main = run[:-1] & ~on_siding[:-1]
            r1 = rear[:-1]
            if blocks:
                r1 = self.x0 + np.floor((r1 - self.x0) / self.block_len) * self.block_len
            obst[1:] = np.where(lead_main, r1, math.inf)
        if n > ns:
            same = on_siding[:-ns] & run[:-ns]
            obst[ns:] = np.minimum(obst[ns:], np.where(same, rear[:-ns], math.inf))
        return obst

    def _speed_codes(self, eoa: FloatArray) -> None:
        """Fixed-block speed code of each train's current block [m/s] (5 km/h steps).

        The code allows a service-brake stop at the end of authority from the block entry.
        """
        x = self.x
        start = self.x0 + np.floor((x - self.x0) / self.block_len) * self.block_len
        code = np.sqrt(2.0 * self.p.max_service_brake_mps2 * np.maximum(eoa - start, 0.0))
        code = np.floor(code / (5.0 * KMH)) * (5.0 * KMH)
        k = ((x - self.x0) * self.inv_dx).astype(np.int64)
        self.speed_code = np.minimum(code, self.limit_eff[k])

    # ------------------------------------------------------------------ discrete logic

    def _process_queue(self, t: float) -> None:
        while self._queue and self._queue[0][0] <= t:
            _, _, ev = heapq.heappop(self._queue)
            d = ev.data
            if ev.kind == "breakdown":
                self.broken_until[d["train"]] = ev.t + d["dur"]
                if self.dwelling[d["train"]]:
                    self.release_t[d["train"]] = max(self.release_t[d["train"]],
                                                     ev.t + d["dur"])
            elif ev.kind in ("fault_on", "fault_off"):
                fl = d["spec"]
                i = d["train"]
                for a in d["axles"]:
                    on = ev.kind == "fault_on"
                    if fl.kind == "pad_mu":
                        self.pad_mu[i, a] = fl.mu_b if on else self.p.pad_mu_nominal
                    else:
                        self.adh_factor[i, a] = fl.adhesion_factor if on else 1.0
                        self.r_w[i, a] = self.p.wheel_radius_m * (fl.radius_factor if on else 1.0)
                self._axle_coefs()

    def _emit(self, i: int, j: int, kind: str, t: float, boarded: float = 0.0,
              alighted: float = 0.0, dwell: float = 0.0) -> None:
        sched = self.sched_arr[i, j] if kind == "arrival" else self.sched_dep[i, j]
        ev = TrainEvent(i, j, kind, t, int(round(boarded)), int(round(alighted)), dwell,
                        t - sched, float(sched))
        self.events.append(ev)
        self._events_out.append(ev)

    def _set_xv(self, i: int, x: float, v: float) -> None:
        """Set one train's position/speed without mutating arrays shared with the trace."""
        self.x = self.x.copy()
        self.v = self.v.copy()
        self.x[i] = x
        self.v[i] = v

    def _try_entry(self, t: float) -> bool:
        """Put the next train on the first platform when due and the platform is clear.

        Returns False while a due train is blocked by the one ahead (platform occupied).
        """
        i = self.next_entry
        if t < self.sched_arr[i, 0] - 1e-9:
            return True
        if i > 0 and self.status[i - 1] in (_ST_RUN, _ST_TURNBACK):
            rear_lead = float(self.x[i - 1]) - self.length_m
            if self.fixed_block:  # the block holding the rear must be clear of the platform
                rear_lead = self.x0 + math.floor((rear_lead - self.x0) / self.block_len) \
                    * self.block_len
            if rear_lead < self.x_first_stop + self.margin + 1.0:
                return False
        self.next_entry += 1
        self.status[i] = _ST_RUN
        self._set_xv(i, self.x_first_stop, 0.0)
        self.a_dem[i] = -self.p.max_service_brake_mps2
        self.stop_x[i] = self.x_first_stop
        self._arrive(i, 0, t)
        return True

    def _arrive(self, i: int, j: int, t: float) -> None:
        """Doors open at station j: alighting, boarding forecast, departure hold time."""
        self.dwelling[i] = True
        self._set_xv(i, float(self.x[i]), 0.0)
        self.cur_station[i] = j
        self.next_stop[i] = j + 1
        self.act_arr[i, j] = t
        self.arr_t[i] = t
        alight = self.load[i] * self.alight_frac[j]
        self.pending_alight[i] = alight
        self._emit(i, j, "arrival", t)
        self._set_release(i, j, redraw=True)

    def _set_release(self, i: int, j: int, redraw: bool) -> None:
        """Departure time = max(ATS/timetable, passenger dwell done) + holds + delay."""
        scn = self.scn
        ps = scn.passengers
        t_arr = float(self.arr_t[i])
        room = self.p.capacity_pax - (self.load[i] - self.pending_alight[i])
        if j == self.n_st - 1:
            d_req = max(ps.door_overhead_s + ps.alighting_s_per_pax * self.pending_alight[i],
                        ps.min_dwell_s)
            board = 0.0
        else:
            waiting = self.left_behind[j] + self.flow.arrivals(j, self.last_dep_t[j], t_arr)
            d_req, board = required_dwell(waiting, self.flow.rate(j, t_arr),
                                          self.pending_alight[i], room,
                                          ps.boarding_s_per_pax, ps.alighting_s_per_pax,
                                          ps.door_overhead_s, ps.min_dwell_s)
        self.pending_board[i] = board
        cand = t_arr + d_req
        cut = self.cmd_dwell_limit[i, j]
        if math.isfinite(cut):  # ATS dwell cut: doors close at the limit (>= minimum dwell)
            cand = min(cand, t_arr + max(float(cut), ps.min_dwell_s))
        cmd = self.cmd_dep[i, j]
        hold = cmd if math.isfinite(cmd) else float(self.sched_dep[i, j])
        cand = max(cand, hold)
        self.dwell_cut[i] = cand < t_arr + d_req - 1e-9
        if redraw:
            dis = scn.disturbances
            delay = 0.0
            if j < self.n_st - 1 and self.rng.random() < dis.departure_delay_prob:
                delay = float(self.rng.exponential(dis.departure_delay_mean_s))
            self._delay_draw[i] = delay
        cand += float(self._delay_draw[i]) + float(self.extra_hold[i, j])
        cand = max(cand, float(self.broken_until[i]))
        self.release_t[i] = cand

    def _depart(self, i: int, t: float) -> None:
        """Doors closed: boarding bookkeeping, departure event, start the next run."""
        j = int(self.cur_station[i])
        self.dwelling[i] = False
        self.release_t[i] = math.inf
        dwell = t - float(self.arr_t[i])
        alight = float(self.pending_alight[i])
        self.load[i] -= alight
        board = 0.0
        if j < self.n_st - 1:
            waiting = self.left_behind[j] + self.flow.arrivals(j, self.last_dep_t[j], t)
            room = max(self.p.capacity_pax - self.load[i], 0.0)
            board = min(waiting, room)
            if self.dwell_cut[i]:  # doors closed by the ATS: boarding time ran out
                ps = self.scn.passengers
                t_board = dwell - ps.door_overhead_s - ps.alighting_s_per_pax * alight
                board = min(board, max(t_board, 0.0) / max(ps.boarding_s_per_pax, 1e-9))
            self.left_behind[j] = waiting - board
            self.last_dep_t[j] = t
            self.load[i] += board
        self.dwell_cut[i] = False
        self.boarded[i, j] = board
        self.mass[i] = self.p.mass_kg + (self.load[i] - self.p.nominal_load_pax) * \
            self.p.pax_mass_kg
        self.act_dep[i, j] = t
        self._emit(i, j, "departure", t, board, alight, dwell)
        if j == self.n_st - 1:
            self.status[i] = _ST_TURNBACK
            self.next_stop[i] = self.n_st
            self.stop_x[i] = self.x_tail_stop
        else:
            self.stop_x[i] = self.station_positions_m[j + 1]
            sig = self.scn.disturbances.running_time_noise
            self.trac_level[i] = 1.0 - abs(float(self.rng.normal(0.0, sig))) if sig > 0 else 1.0

    def _station_logic(self, t: float, hit: BoolArray, d: FloatArray) -> None:
        """Arrivals (standstill within tolerance of the stop point) and overruns."""
        for ii in np.flatnonzero(hit):
            i = int(ii)
            if self.v[i] <= 0.0 and abs(d[i]) <= self.tol_stop:
                if self.status[i] == _ST_TURNBACK:
                    self.dwelling[i] = True  # in the siding: turnback time runs
                    self.done_t[i] = t + self.scn.line.turnback_s
                else:
                    self._arrive(i, int(self.next_stop[i]), t)
            elif d[i] > self.tol_stop:
                if self.status[i] == _ST_TURNBACK:
                    continue  # the buffer-stop authority stops it; accept any standstill
                j = int(self.next_stop[i])
                self.skipped_stops += 1
                self.cur_station[i] = j
                if j >= self.n_st - 1:
                    # overran the terminus: passengers alight in the tail track
                    self.status[i] = _ST_TURNBACK
                    self.next_stop[i] = self.n_st
                    self.stop_x[i] = self.x_tail_stop
                else:
                    self.next_stop[i] = j + 1
                    self.stop_x[i] = self.station_positions_m[j + 1]
            elif self.status[i] == _ST_TURNBACK and self.v[i] <= 0.0 and d[i] < -self.tol_stop:
                pass  # stopped short in the tail: the turnback driver creeps on
        self._masks()

    # ------------------------------------------------------------------ sensors

    def _sensor_snapshot(self, t0: float, t1: float, v0: FloatArray,
                         v1: FloatArray) -> _SensorSnap | None:
        """Noise-free truth needed for the samples in (t0, t1] (samples built on demand)."""
        ts = []
        while self.next_sample_t <= t1 + 1e-9:
            ts.append(self.next_sample_t)
            self.next_sample_t += self.sensor_dt
        mask = self.run & self.sensed_mask
        return _SensorSnap(np.array(ts), t0, t1, mask, self._ax_prev, self._ax,
                           self.r_w.copy(), self.acc, v0, v1.copy(), self.mass / self.p.cars)

    def _sensor_block(self, sn: _SensorSnap) -> _SensorBlock:
        """Samples with noise and injected sensor faults from a snapshot."""
        sen = self.scn.sensors
        rng = self.rng_sensors
        idx = np.flatnonzero(sn.mask)
        rw = sn.r_w[idx]
        _, clamp1, slip1 = sn.ax1.get()
        slip0 = sn.ax0.get()[2]
        om0 = (sn.v0[idx][:, None] * (1.0 - slip0[idx])) / rw
        om1 = (sn.v1[idx][:, None] * (1.0 - slip1[idx])) / rw
        frac = ((sn.ts - sn.t0) / (sn.t1 - sn.t0))[:, None]
        ns, m = sn.ts.size, idx.size
        omega = om0[None] + frac[:, :, None] * (om1 - om0)[None]
        omega = omega + rng.normal(0.0, sen.wheel_omega_noise_radps, omega.shape)
        noise_c = rng.normal(0.0, sen.clamp_force_noise_n, (ns, m, N_AXLES_SENSED))
        clamp = np.maximum(clamp1[idx][None] + noise_c, 0.0)
        accel = sn.acc[idx][None] + rng.normal(0.0, sen.accel_noise_mps2, (ns, m))
        vs = sn.v0[idx][None] + frac * (sn.v1 - sn.v0)[idx][None]
        vref = vs + rng.normal(0.0, sen.ref_speed_noise_mps, (ns, m))
        if self.sensor_faults:
            self._apply_sensor_faults(sn.ts, idx, omega, clamp, accel, vref)
        return _SensorBlock(sn.ts, idx, omega, clamp, accel, vref, sn.car_mass[idx])

    def _apply_sensor_faults(self, tt: FloatArray, idx: IntArray, omega: FloatArray,
                             clamp: FloatArray, accel: FloatArray, vref: FloatArray) -> None:
        """Dropout (NaN) or stuck (value frozen at the fault onset) channels, in place."""
        pos = {int(tr): c for c, tr in enumerate(idx)}
        chans = {"wheel_omega": omega, "clamp_force": clamp, "accel": accel, "ref_speed": vref}
        for f in self.sensor_faults:
            c = pos.get(f["train"])
            if c is None:
                continue
            act = (tt >= f["t0"]) & (tt < f["t1"])
            if not act.any():
                continue
            names = list(chans) if f["channel"] == "all" else [f["channel"]]
            for name in names:
                arr = chans[name]
                if f["kind"] == "sensor_dropout":
                    val: Any = math.nan
                else:
                    if f.get("stuck_" + name) is None:  # first faulty sample seen
                        first = int(np.flatnonzero(act)[0])
                        f["stuck_" + name] = arr[first, c].copy()
                    val = f["stuck_" + name]
                if arr.ndim == 3:
                    for a in f["axles"]:
                        arr[act, c, a] = val if np.ndim(val) == 0 else val[a]
                else:
                    arr[act, c] = val

    # ------------------------------------------------------------------ outputs

    def energy_breakdown(self) -> dict[str, FloatArray]:
        """Per-train energy terms [J] (wheel traction, braking, resistance, grade, ...)."""
        meff = self.mass + self.m_rot
        return {
            "traction_wheel": self.e_trac.copy(), "brake_rail": self.e_brake_rail.copy(),
            "electric_brake": self.e_elec.copy(), "friction_brake": self.e_fric.copy(),
            "resistance": self.e_res.copy(), "curve": self.e_curve.copy(),
            "grade": self.e_grade.copy(), "aux": self.e_aux.copy(),
            "regen_to_line": self.e_regen.copy(), "stop_correction": self.e_stop_corr.copy(),
            "kinetic": 0.5 * meff * self.v ** 2 * (self.status != _ST_DONE),
            "substation": self.e_trac / self.p.traction_efficiency + self.e_aux - self.e_regen,
        }

    def kpis(self) -> dict[str, Any]:
        """KPI dictionary (JSON-serialisable); see :func:`metro_atc.core.plant.kpi.compute`."""
        from .kpi import compute_kpis
        self._monitor(self._obstacle_rear(False),
                      ((self.x - self.x0) * self.inv_dx).astype(np.int64))
        return compute_kpis(self)
