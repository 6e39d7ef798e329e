"""The on-board ATO of one train as the ``ato_controller`` node runs it (ROS-free).

:class:`OnboardAto` is the whole per-train decision logic of the node: it keeps the ATS
departure commands, plans each inter-station run (:class:`AtoCore`) definitively at the
departure from the state (pre-planning while standing), and turns every lockstep state into
an effort u in [-1, 1] and an intended mode.  The node only converts messages and publishes;
the ROS-free closed loop (:mod:`metro_atc.core.closed_loop`) calls the same object, so both
drive the plant identically.

States are the plain dicts of :func:`metro_atc.nodes.conversions.state_from_msg` (keys
``step``, ``t_s``, ``x_m``, ``v_mps``, ``mode``, ``current_station``, ``next_station``,
``departure_time_s``, ``target_running_time_s``, ``supervision_speed_mps`` (the ATP's
emergency-brake intervention speed, inf when unknown), ``movement_authority_m``; SI units).

Every control step runs the compiled step (:mod:`metro_atc.core.ato.control_kernel_step`,
the one source of the control law); :meth:`OnboardAto.control` validates the state first
(a state with a time, position or speed that is not a finite number in range, or a time not
after the last step's, is rejected: :class:`StateRejected`, counted, nothing changes) and
holds a train that has no plan yet.  Guards on top of the planned profile only ever *lower*
the tracker's command:

- **end of movement authority** (train ahead): a braking curve, at the deceleration the
  service brake achieves on the steepest downhill grade of the remaining run, to a point
  ``authority_margin_m`` short of the end of authority;
- **temporary speed restrictions** the ATO knows from the line description (the same
  notice as the ATP, ``signalling.tsr_notice_s``): a braking curve to ``limit`` at the zone
  entry and the limit inside it, for the whole train length;
- **stopping guard**: above the curve that still ends at the stopping point at the
  achievable deceleration, brake with the deceleration that ends there;
- **supervision speed**: stay ``SPEED_MARGIN_MPS`` below the ATP intervention speed.

The speed dip and the TSR hold (no re-motoring toward a speed a known TSR's curve takes back)
and the authority's speed (a moving end of authority: the train ahead) shape the caps.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any, Optional, Sequence

import numpy as np

from metro_atc.core.ato.control_kernel import (HOLD_BRAKE, REASONS, SAFE_BRAKE, STATE_INDEX,
                                               SPEED_MARGIN as SPEED_MARGIN_MPS)
from metro_atc.core.ato.control_kernel_pack import (ATP_FIELDS, CORE_FIELDS, control_step_fn,
                                                    pack_constants, pack_line, pack_plan,
                                                    sbi_speed_to_fn)
from metro_atc.core.ato.controller import AtoCore
from metro_atc.core.ato.envelope import OperatingLimits
from metro_atc.core.ato.planner import Profile
from metro_atc.core.ato.tsr_plan import tsrs_for_run
from metro_atc.core.bridge import ato_limits_for
from metro_atc.core.laws import ebi_coef
from metro_atc.core.line.atp_constants import SBI_OFFSET_MPS, atp_constants
from metro_atc.core.line.geometry import build_geometry
from metro_atc.core.line.track import braking_envelope, window_min_ahead, window_min_behind
from metro_atc.core.line.vehicle import Track, TrainParams, max_traction_accel

MODE_DWELL = 1
"""TrainState.MODE_DWELL (msg_defs/TrainState.msg)."""
MODE_ACCELERATE = 2
"""TrainState.MODE_ACCELERATE."""
MODE_COAST = 4
"""TrainState.MODE_COAST."""
MODE_BRAKE = 5
"""TrainState.MODE_BRAKE."""
MODE_OUT_OF_SERVICE = 0
"""TrainState.MODE_OUT_OF_SERVICE."""

T_MAX_S, X_MAX_M, V_MAX_MPS = 1e15, 1e12, 1e6
"""The range of a valid state's time [s], position [m] and speed [m/s] (absolute values)."""


class StateRejected(ValueError):
    """A state :meth:`OnboardAto.control` does not act on (nothing changed; counted)."""


@dataclass(frozen=True)
class TsrZone:
    """A temporary speed restriction as the ATO knows it (chainage [m], speed [m/s], [s])."""

    start_m: float
    end_m: float
    limit_mps: float
    known_s: float
    from_s: float
    to_s: float


@dataclass(frozen=True)
class PlanEvent:
    """A run planned during :meth:`OnboardAto.control` / :meth:`OnboardAto.on_departure`."""

    station: int
    target_s: float
    profile: Profile
    stamp_s: float
    late: bool
    to_station: int = -1
    """The stop the run ends at (-1: ``station + 1``; further when a dispatcher has the
    train skip the stops between)."""


class OnboardAto:
    """Per-train ATO decision logic (module docstring).

    Parameters: train, track; ``stations_m`` stop-point chainages [m]; planner / tracker
    names and extra planner parameters (:class:`AtoCore`); ``control_period_s`` [s];
    ``limits`` planning limits; ``shared`` cache shared by the trains of a process;
    ``tsrs`` the temporary speed restrictions of the scenario.
    """

    def __init__(self, train: TrainParams, track: Track,
                 stations_m: "Sequence[float] | np.ndarray",
                 planner: str = "ectp", tracker: str = "fuzzy", control_period_s: float = 0.25,
                 limits: Optional[OperatingLimits] = None,
                 shared: Optional[dict[str, Any]] = None,
                 tsrs: Sequence[TsrZone] = (), atp: Optional["AtpModel"] = None,
                 **planner_params: Any) -> None:
        """Build the :class:`AtoCore` and load the compiled step."""
        self.core = AtoCore(train, track, planner=planner, tracker=tracker,
                            control_period_s=control_period_s, limits=limits, shared=shared,
                            **planner_params)
        self.train = train
        self.base_train = train
        """The rolling stock at its reference mass (``train`` is it at the load-weigh mass)."""
        self.base_limits = self.core.limits
        self.mass_rejected = 0
        """Load-weigh masses ignored (not finite or outside empty .. 1.5 x crush) [-]."""
        self.rejected = 0
        """States rejected by :meth:`control` (:class:`StateRejected`) [-]."""
        self.last_rejection = ""
        """Why the last rejected state was rejected."""
        self.track = track
        self.stations = np.asarray(stations_m, dtype=float)
        self._tsrs = tuple(tsrs)
        self.atp = atp if atp is not None else AtpModel(
            b_g=0.5 * train.emergency_brake_mps2, t_r=1.0, t_sbi=2.0,
            g_down=0.0, sbi_offset_mps=SBI_OFFSET_MPS, train=train)
        self.commands: dict[int, tuple[float, float]] = {}
        self._b_run: Any = None
        self._b_tab = np.zeros(1)
        self.planned_from = -1
        self.planned_to = -1
        self.cur_station = -1
        self.last_mode = -1
        self._kstep: Any = control_step_fn()
        """The compiled step (:func:`.control_kernel_step.control_step`)."""
        self._kconst: Any = None
        self._kline: Any = None
        self._kplan: Any = (None, None, None)

    @property
    def tsrs(self) -> tuple[TsrZone, ...]:
        """The TSRs the ATO knows (scripted and a dispatcher's).

        Setting them repacks the line tables of the compiled step.
        """
        return self._tsrs

    @tsrs.setter
    def tsrs(self, zones: Sequence[TsrZone]) -> None:
        self._tsrs = tuple(zones)
        self._kline = None

    # ------------------------------------------------------------------ planning
    def on_departure(self, station: int, departure_s: float, running_s: float,
                     stamp_s: float) -> Optional[PlanEvent]:
        """Record an ATS departure command; pre-plan while standing (returns the plan)."""
        st = int(station)
        if st + 1 >= len(self.stations) or st < self.cur_station:
            return None  # the terminus, or a station already left (an ATS replaying history)
        self.commands[st] = (float(departure_s), float(running_s))
        if self.last_mode in (-1, MODE_OUT_OF_SERVICE, MODE_DWELL):
            return self.plan(st, float(running_s), stamp_s)
        return None

    def set_load_mass(self, mass_kg: float) -> bool:
        """Plan and track from the next plan on with the train at ``mass_kg`` [kg].

        The load-weigh mass of the train: traction, service brake and effective mass of
        :meth:`TrainParams.at_mass` (the plant's force limits at that mass), the planning
        limits scaled with them (:func:`limits_at_mass`).  A mass that is not finite or
        outside the empty train .. 1.5 x the crush-loaded train is ignored and counted
        (``mass_rejected``); returns whether the mass was taken.
        """
        b = self.base_train
        m = float(mass_kg)
        if not (math.isfinite(m)
                and b.tare_mass_kg <= m <= 1.5 * b.mass_at_load(b.capacity_pax)):
            self.mass_rejected += 1
            return False
        if m == self.train.mass_kg:
            return True
        train = b.at_mass(m)
        self.train = train
        self.core.set_train(train, limits_at_mass(self.base_limits, b, train))
        self._kconst = None  # the compiled step's constants hold the train
        return True

    def _load_weigh(self, s: dict[str, Any]) -> None:
        """Take the state's load-weigh mass ``mass_kg`` [kg] when it has one (not NaN)."""
        m = s.get("mass_kg")
        if m is not None and m == m:
            self.set_load_mass(m)

    def plan(self, st: int, target_s: float, stamp_s: float, late: bool = False,
             to: int = -1) -> PlanEvent:
        """Plan the run from station ``st`` to ``to`` (-1: ``st + 1``; a skipped stop)."""
        to = to if to > st else st + 1
        x0, x1 = float(self.stations[st]), float(self.stations[to])
        # the TSRs known now are limits of the run (no motoring into their curve)
        prof = self.core.plan(x0, x1, target_s, tsrs_for_run(self.tsrs, x0, x1,
                                                             self.train.length_m, stamp_s))
        self.planned_from, self.planned_to = st, to
        return PlanEvent(st, float(target_s), prof, float(stamp_s), late, to)

    # ------------------------------------------------------------------ control
    def _reject(self, why: str, t: float, x: float, v: float) -> StateRejected:
        """Count a rejected state; the exception to raise (nothing else changes)."""
        self.rejected += 1
        self.last_rejection = f"{why} (t {t!r} s, x {x!r} m, v {v!r} m/s)"
        return StateRejected(self.last_rejection)

    def control(self, s: dict[str, Any]) -> tuple[float, int, Optional[PlanEvent]]:
        """Effort in [-1, 1], intended mode and the run planned at this state (if any).

        Raises :class:`StateRejected` (counted in ``rejected``, nothing else changes) for a
        state whose time, position or speed is not a finite number within ``T_MAX_S``,
        ``X_MAX_M``, ``V_MAX_MPS`` or whose time is not after the last control step's
        (going backwards, or a duplicate).  A train with no plan yet (not departed from a
        stop) is held: the holding brake at rest, the full service brake moving.
        """
        t, x, v = float(s["t_s"]), float(s["x_m"]), float(s["v_mps"])
        if not (abs(t) <= T_MAX_S and abs(x) <= X_MAX_M and abs(v) <= V_MAX_MPS):
            raise self._reject("time, position or speed not a finite number in range",
                               t, x, v)
        core = self.core
        st = core.state
        if st[STATE_INDEX["has_t"]] != 0.0 and t <= st[STATE_INDEX["t"]]:
            raise self._reject("state time went backwards"
                               if t < st[STATE_INDEX["t"]] - 1e-9 else "duplicate state time",
                               t, x, v)
        departing = self.last_mode == MODE_DWELL
        self.last_mode = int(s["mode"])
        self.cur_station = max(self.cur_station, int(s["current_station"]))
        if s["mode"] == MODE_DWELL:
            return HOLD_BRAKE, MODE_DWELL, None
        cur, nxt = int(s["current_station"]), int(s["next_station"])
        planned: Optional[PlanEvent] = None
        if departing and 0 <= cur < nxt:
            # plan the run definitively at departure from the state (deterministic in the
            # lockstep): the ATS target fixes the arrival (departure + running time), so a
            # late departure shortens the target (down to flat-out); rounded to 1 s when
            # late so the trains of a process share plans
            target = float(s["target_running_time_s"])
            late = t - float(s["departure_time_s"])
            if math.isfinite(late) and late > 1.0:
                target = float(max(round(target - late), 1.0))
            self._load_weigh(s)
            planned = self.plan(cur, target, t, late=late > 1.0, to=nxt)
        elif (self.planned_from != cur or self.planned_to != nxt) and 0 <= cur < nxt:
            # started mid-run (e.g. the node was restarted) or the next stop changed (a
            # dispatcher's skip): plan from here
            self._load_weigh(s)
            planned = self.plan(cur, float(s["target_running_time_s"]), t, to=nxt)
        kp = core.kernel_plan()
        if kp is None:
            core.last_reason = "no plan: holding brake"
            return (SAFE_BRAKE if v > 0.0 else HOLD_BRAKE), MODE_BRAKE, planned
        if self._kconst is None or self._kline is None:
            self._pack(core)
        if self._b_run is not core.run:
            self._decel_table()
        if self._kplan[0] is not kp or self._kplan[1] is not self._b_tab:
            self._kplan = (kp, self._b_tab,
                           pack_plan(kp[0], kp[1], kp[2], kp[3], kp[4], kp[5], kp[6],
                                     self._b_tab))
        # a stop index beyond the line (or none) is no stop: the kernel reads stops in range
        n = min(max(nxt, -1), len(self.stations))
        u, code = self._kstep(self._kconst, self._kplan[2], self._kline, st, t, x, v,
                              float(s["supervision_speed_mps"]),
                              float(s["movement_authority_m"]), n)
        core.last_reason = REASONS[code]
        mode = MODE_ACCELERATE if u > 0.05 else (MODE_BRAKE if u < -0.05 else MODE_COAST)
        return u, mode, planned

    def _pack(self, core: AtoCore) -> None:
        """Pack the compiled step's constants (train, ATP, controller) and line tables."""
        atp = self.atp
        self._kconst = pack_constants(self.train, atp.train, core.kernel_constants(),
                                      atp.kernel_fields())
        self._kline = pack_line(atp.sbi_table(),
                                np.asarray(self.track.grade_starts_m, dtype=float),
                                np.asarray(self.track.grades, dtype=float), self.stations,
                                np.asarray([(z.start_m, z.end_m, z.limit_mps, z.known_s,
                                             z.to_s) for z in self.tsrs], dtype=float))

    def _decel_table(self) -> None:
        """The run's planned-deceleration table of the compiled step (``plan_decel``).

        The lowest planned deceleration over [s - 50, s + 400] m on a 10 m grid of the run
        [m/s^2].
        """
        run = self.core.run
        assert run is not None
        ss = np.arange(-50.0, run.length_m + 410.0, 10.0)
        b = run.brake_decel(np.clip(ss, 0.0, run.length_m))
        k = 45
        pad = np.concatenate((b, np.full(k, b[-1])))
        self._b_tab = np.lib.stride_tricks.sliding_window_view(pad, k + 1).min(axis=1)
        self._b_run = run

    @property
    def authority_speed_mps(self) -> float:
        """Speed at which the end of movement authority moves ahead (the train ahead) [m/s]."""
        return float(self.core.state[STATE_INDEX["v_ma"]])


@dataclass(frozen=True)
class AtpModel:
    """What the ATO knows of the ATP's supervision (Ke 2010, Fig. 1; SI units).

    b_g: guaranteed deceleration on the steepest downhill [m/s^2]; t_r: response time [s];
    t_sbi: service-brake-intervention lead time [s]; g_down: g x the steepest downhill
    [m/s^2]; sbi_offset_mps: the SBI speed lies this far below the EBI curve [m/s];
    train: rolling stock (traction for the worst-case response acceleration).
    """

    b_g: float
    t_r: float
    t_sbi: float
    g_down: float
    sbi_offset_mps: float
    train: TrainParams
    grid_x0_m: float = 0.0
    grid_dx_m: float = 1.0
    sbi_static_mps: Optional[np.ndarray] = None
    tol_mps: float = 0.0
    resp_dist_m: float = 0.0
    sbi_dist_m: float = 0.0

    def __post_init__(self) -> None:
        """A static SBI table must be numbers (+inf: no limit there): one-line error."""
        tab = self.sbi_static_mps
        if tab is not None and (np.size(tab) < 1
                                or bool(np.isnan(np.asarray(tab, dtype=float)).any())):
            raise ValueError("AtpModel: the static SBI table is empty or has NaN")

    def kernel_fields(self) -> list[float]:
        """The ATP's constants of the compiled step (``control_kernel_pack.ATP_FIELDS``)."""
        b, tr = float(self.b_g), float(self.t_r)
        bt2 = float(ebi_coef(b, tr, 0.0)[0])  # (b_g t_r)^2, as the ATP curve's c0
        out = [self.g_down, self.sbi_offset_mps, bt2, b * tr, b * tr * tr, tr, 2.0 * b,
               self.t_sbi, self.grid_x0_m, self.grid_dx_m, self.tol_mps, self.resp_dist_m,
               self.sbi_dist_m, b]
        assert len(out) == len(ATP_FIELDS)
        return [float(f) for f in out]

    def sbi_table(self) -> np.ndarray:
        """The static SBI table [m/s] the compiled step reads.

        [+inf] (no limit known) when the model has none.
        """
        if self.sbi_static_mps is None:
            return np.full(1, np.inf)
        return np.asarray(self.sbi_static_mps, dtype=float)

    def sbi_speed_to(self, dist_m: float, target_mps: float) -> float:
        """Static SBI speed [m/s] ``dist_m`` before a point where the limit is ``target``.

        The compiled step's (``control_kernel_step.sbi_speed_to``): the plant's static
        construction (:mod:`metro_atc.core.line.track`), braking envelope
        ``E^2 = (target + tol)^2 + 2 b_g D`` evaluated past the response and SBI look-ahead
        distances, ``v + a_w(v) t_r = E`` (one fixed-point step), less the SBI offset.
        """
        c = pack_constants(self.train, self.train, [0.0] * len(CORE_FIELDS),
                           self.kernel_fields())
        return float(sbi_speed_to_fn()(c, float(dist_m), float(target_mps)))


def atp_model_for(scn: Any, train: TrainParams) -> AtpModel:
    """The ATP constants of a scenario as the plant derives them (a pure function of it)."""
    geom = build_geometry(scn, train)
    c = atp_constants(scn, train, geom)
    # the static supervision without TSRs (the ATO follows those by its own curves)
    lim = np.asarray(geom.static_limit, dtype=float)
    ceil = window_min_behind(lim, geom.n_len) + geom.ceiling_tol
    env = braking_envelope(ceil, geom.dx, c.b_g)
    e_min = window_min_ahead(env, c.n_resp)
    a_w = max_traction_accel(train, e_min) + c.g_down
    # v + a_w(v) t_r = E solved with a_w at E (a_w falls with speed: conservative)
    ebi = e_min - a_w * c.t_r
    sbi = window_min_ahead(ebi, c.n_sbi)
    return AtpModel(b_g=c.b_g, t_r=c.t_r, t_sbi=c.t_sbi, g_down=c.g_down,
                    sbi_offset_mps=SBI_OFFSET_MPS, train=train, grid_x0_m=float(geom.x0),
                    grid_dx_m=float(geom.dx), sbi_static_mps=np.asarray(sbi, dtype=float),
                    tol_mps=float(geom.ceiling_tol), resp_dist_m=float(c.n_resp * geom.dx),
                    sbi_dist_m=float(c.n_sbi * geom.dx))


def limits_at_mass(limits: OperatingLimits, base: TrainParams,
                   train: TrainParams) -> OperatingLimits:
    """Planning limits ``limits`` of the stock ``base`` for ``train`` (``base.at_mass``).

    The planned braking deceleration keeps its share of the service brake (scaled by the
    service rate at the mass over the reference one when that is lower) and the net
    acceleration limit is at most the train's constant-torque traction a_1 at the mass;
    ``limits`` itself when neither is lower.
    """
    brake, accel = limits.brake_decel_mps2, limits.accel_max_mps2
    if train.max_service_brake_mps2 < base.max_service_brake_mps2:
        brake = brake * (train.max_service_brake_mps2 / base.max_service_brake_mps2)
    accel = min(accel, train.a1_mps2)
    if brake == limits.brake_decel_mps2 and accel == limits.accel_max_mps2:
        return limits
    return dataclasses.replace(limits, brake_decel_mps2=brake, accel_max_mps2=accel)


def envelope_limits(scn: Any, train: TrainParams) -> OperatingLimits:
    """Planning limits of the ATO for a scenario: the rolling stock's, inside the envelope.

    :func:`metro_atc.core.bridge.ato_limits_for` plus grade-aware braking curves, the
    tracking margin ``SPEED_MARGIN_MPS`` below the civil limit and a restriction lead of
    the distance run at the maximum speed during the ATP's SBI lead and response times.
    """
    sg = scn.signalling
    lead = train.max_speed_mps * (float(sg.sbi_lead_s) + float(sg.response_time_s))
    return dataclasses.replace(ato_limits_for(train), grade_aware_braking=True,
                               speed_margin_mps=SPEED_MARGIN_MPS, restriction_lead_m=lead)


def tsr_zones(scn: Any) -> list[TsrZone]:
    """TSRs of a scenario as the ATO knows them (``signalling.tsr_notice_s`` in advance)."""
    notice = float(scn.signalling.tsr_notice_s)
    out = []
    for t in scn.line.temporary_speed_limits:
        out.append(TsrZone(t.start_m, t.end_m, t.limit_kmh / 3.6, max(t.from_s - notice, 0.0),
                           t.from_s, t.to_s))
    for inc in scn.incidents:
        if inc.kind == "tsr":
            out.append(TsrZone(inc.start_m, inc.end_m, inc.limit_kmh / 3.6,
                               max(inc.at_s - notice, 0.0), inc.at_s,
                               inc.at_s + inc.duration_s))
    return out
