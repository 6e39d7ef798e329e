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

Guards on top of the planned profile only ever *lower* the tracker's command:

- **end of movement authority** (train ahead): a braking curve, at the deceleration the
  service brake achieves on the steepest downhill grade of the remaining run, to a point
  ``authority_margin_m`` short of the end of authority;
- **temporary speed restrictions** the ATO knows from the line description (the same
  notice as the ATP, ``signalling.tsr_notice_s``): a braking curve to ``limit`` at the zone
  entry and the limit inside it, for the whole train length;
- **stopping guard**: above the curve that still ends at the stopping point at the
  achievable deceleration, brake with the deceleration that ends there;
- **supervision speed**: stay ``SPEED_MARGIN_MPS`` below the ATP intervention speed.
"""

from __future__ import annotations

import dataclasses
import math
from bisect import bisect_right
from dataclasses import dataclass
from typing import Any, Optional, Sequence

import numpy as np

from metro_atc.core.ato.controller import (JOIN_BAND_MPS, JOIN_MIN_SPEED_MPS, PREVIEW_PERIODS,
                                           AtoCore)
from metro_atc.core.ato.control_kernel import REASONS, STATE_FIELDS, STATE_INDEX
from metro_atc.core.ato.control_kernel_pack import (control_step_fn, pack_constants, pack_line,
                                                    pack_plan)
from metro_atc.core.ato.envelope import OperatingLimits
from metro_atc.core.ato.planner import Profile
from metro_atc.core.ato.tsr_plan import tsrs_for_run
from metro_atc.core.bridge import ato_limits_for
from metro_atc.core.laws import braking_speed, ebi_coef, ebi_speed_from
from metro_atc.core.line.atp_constants import SBI_OFFSET_MPS, atp_constants
from metro_atc.core.line.geometry import build_geometry
from metro_atc.core.line.track import (braking_envelope, ebi_speed_at, window_min_ahead,
                                       window_min_behind)
from metro_atc.core.line.vehicle import (G_MPS2, Track, TrainParams, max_traction_accel,
                                         max_traction_accel_at)

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

STOP_GUARD = 0.85
"""Deceleration needed to stop at the platform, as a share of the achievable service brake,
above which the stopping guard brakes [-]."""
SPEED_MARGIN_MPS = 0.5
"""Margin kept below the ATP supervision (emergency-brake intervention) speed [m/s]."""
AUTHORITY_MARGIN_M = 10.0
"""Distance the ATO aims to stop short of the end of movement authority [m]."""
GUARD_GAIN = 0.8
"""Effort per m/s of speed above a guard curve [1/(m/s)]."""
GUARD_SLACK_MPS = 0.3
"""The hard guard brakes only when the speed is this far above a cap [m/s] (below it the
tracker follows the cap)."""
CAP_LOOKAHEAD_S = 2.0
"""The speed cap takes the lowest static SBI speed over the distance run in this time [s]."""


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
        """Build the :class:`AtoCore` and the guard state.

        Every control step the compiled step (:mod:`metro_atc.core.ato.control_kernel`)
        takes runs there; the others run :meth:`control`'s Python path.
        """
        self.core = AtoCore(train, track, planner=planner, tracker=tracker,
                            control_period_s=control_period_s, limits=limits, shared=shared,
                            **planner_params)
        self.train = train
        self.base_train = train
        """The rolling stock at its reference mass (``train`` is it at the load-weigh mass)."""
        self.base_limits = self.core.limits
        self.mass_rejected = 0
        """Load-weigh masses ignored (not finite or outside empty .. 1.5 x crush) [-]."""
        self.track = track
        self.stations = np.asarray(stations_m, dtype=float)
        self._stations_list: list[float] = self.stations.tolist()  # read per step (floats)
        self.tsrs = tuple(tsrs)
        self.atp = atp if atp is not None else AtpModel(
            b_g=0.5 * train.emergency_brake_mps2, t_r=1.0, t_sbi=2.0,
            g_down=0.0, sbi_offset_mps=SBI_OFFSET_MPS, train=train)
        self.commands: dict[int, tuple[float, float]] = {}
        self._grade_lists = (np.asarray(track.grade_starts_m, dtype=float).tolist(),
                             np.asarray(track.grades, dtype=float).tolist())
        self._b_run: Any = None
        self._b_tab = np.zeros(1)
        self._b_list: list[float] = [0.0]
        self._b_n = 1
        self.planned_from = -1
        self.planned_to = -1
        self.cur_station = -1
        self.last_mode = -1
        self._ma_prev: Optional[tuple[float, float]] = None
        self.authority_speed_mps = 0.0
        """Speed at which the end of movement authority moves ahead (the train ahead) [m/s]."""
        self._peak_mps = 0.0
        self._next_stop_m = math.inf
        self._held_mps = 0.0
        self._kstep: Any = control_step_fn()
        """The compiled step; None once the tracker proved not to be the kernel's (then every
        step runs the Python path)."""
        self._kconst: Any = None
        self._kline: Any = None
        self._kplan: Any = (None, None, None)
        self.kernel_steps = 0
        """Control steps the compiled kernel took (the others ran the Python path)."""

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
    def control(self, s: dict[str, Any]) -> tuple[float, int, Optional[PlanEvent]]:
        """Effort in [-1, 1], intended mode and the run planned at this state (if any)."""
        departing = self.last_mode == MODE_DWELL
        self.last_mode = int(s["mode"])
        self.cur_station = max(self.cur_station, int(s["current_station"]))
        if s["mode"] == MODE_DWELL:
            return -0.5, MODE_DWELL, None
        cur, nxt = int(s["current_station"]), int(s["next_station"])
        planned: Optional[PlanEvent] = None
        if departing and 0 <= cur < nxt:
            # plan the run definitively at departure from the state (deterministic in the
            # lockstep): the ATS target fixes the arrival (departure + running time), so a
            # late departure shortens the target (down to flat-out); rounded to 1 s when
            # late so the trains of a process share plans
            target = float(s["target_running_time_s"])
            late = float(s["t_s"]) - float(s["departure_time_s"])
            if math.isfinite(late) and late > 1.0:
                target = float(max(round(target - late), 1.0))
            self._load_weigh(s)
            planned = self.plan(cur, target, float(s["t_s"]), late=late > 1.0, to=nxt)
        elif (self.planned_from != cur or self.planned_to != nxt) and 0 <= cur < nxt:
            # started mid-run (e.g. the node was restarted) or the next stop changed (a
            # dispatcher's skip): plan from here
            self._load_weigh(s)
            planned = self.plan(cur, float(s["target_running_time_s"]), float(s["t_s"]),
                                to=nxt)
        if self._kstep is not None:
            out = self._kernel_control(s)
            if out is not None:
                return out[0], out[1], planned
        # caps at the tracker's preview position and a little beyond (their slope is the
        # feedforward acceleration while a cap sets the reference)
        v = float(s["v_mps"])
        xp = float(s["x_m"]) + PREVIEW_PERIODS * v * self.core.period
        h = max(v * self.core.period, 0.5)
        ctx = self._cap_context(s)  # the position-independent part of the caps, once
        cap_p = self._cap_at(ctx, xp, True)
        if cap_p - v > JOIN_BAND_MPS and v > JOIN_MIN_SPEED_MPS \
                and self.core.last_effort > 0.0:
            # in traction below a falling cap: aim where the swing to braking would end
            xp += v * self.core.swing_s
            cap_p = min(cap_p, self._cap_at(ctx, xp, True))
        dip = self._speed_dip(s, v)
        hold = bool(ctx[4]) and v > JOIN_MIN_SPEED_MPS and cap_p > v \
            and self._tsr_hold(ctx, xp, v, min(cap_p, self.core.reference_speed(xp)), dip)
        if hold:
            # hold the speed (not above the one the hold began at: on a descent the held
            # speed would creep up, a minimum) and follow the TSR curve down when it comes
            cap_p = min(v, self._held_mps) if self._held_mps > 0.0 else v
            self._held_mps = cap_p
        else:
            self._held_mps = 0.0
        cap_h = cap_p if hold else self._cap_at(ctx, xp + h, True)
        slope = (cap_h * cap_h - cap_p * cap_p) / (2.0 * h) \
            if math.isfinite(cap_p) and math.isfinite(cap_h) else 0.0
        v_ma = self._authority_speed(float(s["t_s"]), float(s["movement_authority_m"]))
        if slope < 0.0 and v_ma > 0.0 and v > 0.0 \
                and cap_p < self._cap_at(ctx, xp, False) - 1e-9:
            # the authority curve sets the cap and its end moves ahead at v_ma: along the
            # train's path the cap falls at dcap/dx (v - v_ma), not dcap/dx v (a static
            # curve's slope would brake a train following at the leader's speed: hunting)
            slope *= min(max(1.0 - v_ma / v, 0.0), 1.0)
        u_trk = float(self.core.command(s["t_s"], s["x_m"], v, r_cap_mps=cap_p,
                                        cap_accel_mps2=slope))
        u = min(u_trk, self.guard(s, ctx))
        if u < u_trk:
            self.core.applied(u)
        mode = MODE_ACCELERATE if u > 0.05 else (MODE_BRAKE if u < -0.05 else MODE_COAST)
        return u, mode, planned

    def _kernel_control(self, s: dict[str, Any]) -> Optional[tuple[float, int]]:
        """The rest of :meth:`control` by the compiled step; None: run the Python path.

        The kernel takes the state from (and gives it back to) this object, its core and
        tracker at every step, so either path continues where the other stopped.
        """
        t = float(s["t_s"])
        atp = self.atp
        core = self.core
        kp = core.kernel_plan()
        if kp is None or atp._sbi_list is None:
            return None
        ks = core.kernel_state()
        if ks is None:
            return None
        if self._kconst is None:
            cc = core.kernel_constants()
            if cc is None:
                self._kstep = None
                return None
            b, tr = float(atp.b_g), float(atp.t_r)
            bt2 = float(ebi_coef(b, tr, 0.0)[0])  # (b_g t_r)^2, as the ATP curve's c0
            self._kconst = pack_constants(
                self.train, atp.train, cc,
                [atp.g_down, atp.sbi_offset_mps, bt2, b * tr, b * tr * tr, tr,
                 2.0 * b, atp.t_sbi, atp.grid_x0_m, atp.grid_dx_m, atp.tol_mps,
                 atp.resp_dist_m, atp.sbi_dist_m, b])
            self._kline = pack_line(np.asarray(atp._sbi_list, dtype=float),
                                    np.asarray(self._grade_lists[0], dtype=float),
                                    np.asarray(self._grade_lists[1], dtype=float), self.stations,
                                    np.asarray([(z.start_m, z.end_m, z.limit_mps, z.known_s,
                                                 z.to_s) for z in self.tsrs], dtype=float))
        if self._b_run is not core.run:
            self._plan_decel(float(s["x_m"]))  # builds the run's deceleration table
        if self._kplan[0] is not kp or self._kplan[1] is not self._b_list:
            self._kplan = (kp, self._b_list,
                           pack_plan(kp[0], kp[1], kp[2], kp[3], kp[4], kp[5], kp[6],
                                     np.asarray(self._b_list, dtype=float)))
        nxt = int(s["next_station"])
        if not -2 ** 62 < nxt < 2 ** 62:
            return None
        ma = self._ma_prev
        own = {"has_ma": 0.0 if ma is None else 1.0, "ma_t": 0.0 if ma is None else ma[0],
               "ma": 0.0 if ma is None else ma[1], "v_ma": self.authority_speed_mps,
               "peak": self._peak_mps, "next_stop": self._next_stop_m,
               "held": self._held_mps}
        st = np.array(ks + [own[f] for f in STATE_FIELDS[len(ks):]])
        u, code = self._kstep(self._kconst, self._kplan[2], self._kline, st, t,
                              float(s["x_m"]), float(s["v_mps"]),
                              float(s["supervision_speed_mps"]),
                              float(s["movement_authority_m"]), nxt)
        if code < 0:
            return None
        vals = st.tolist()
        core.set_kernel_state(vals, REASONS[code])
        i = STATE_INDEX
        self._ma_prev = (vals[i["ma_t"]], vals[i["ma"]])
        self.authority_speed_mps = vals[i["v_ma"]]
        self._peak_mps = vals[i["peak"]]
        self._next_stop_m = vals[i["next_stop"]]
        self._held_mps = vals[i["held"]]
        self.kernel_steps += 1
        mode = MODE_ACCELERATE if u > 0.05 else (MODE_BRAKE if u < -0.05 else MODE_COAST)
        return u, mode

    def _speed_dip(self, s: dict[str, Any], v: float) -> bool:
        """Whether the speed has fallen since its last peak off the run's envelope.

        The peak [m/s] restarts at 0 at a station and follows the speed up; a train riding
        the run's envelope (a civil limit or a braking curve to one, within
        ``JOIN_BAND_MPS``) restarts it at its speed, so a speed lowered by a limit is no dip.
        True when the speed is ``JOIN_BAND_MPS`` below the peak: the plan coasted (or the
        tracker braked) and traction now would make a speed minimum here.
        """
        nxt = int(s["next_station"])
        st = self._stations_list
        self._next_stop_m = st[nxt] if 0 <= nxt < len(st) else math.inf
        run = self.core.run
        if s["mode"] == MODE_DWELL or run is None:
            self._peak_mps = 0.0
            return False
        c = math.sqrt(2.0 * max(self.core.ceiling_e_at(run, run.run_coordinate_at(
            float(s["x_m"]))), 0.0))
        if v >= c - JOIN_BAND_MPS or v > self._peak_mps:
            self._peak_mps = v
        return v < self._peak_mps - JOIN_BAND_MPS

    def _tsr_dip_hold(self, ctx: tuple[Any, ...], xp: float, v: float) -> bool:
        """No re-motoring out of a speed dip before a known TSR below the speed.

        A TSR ahead of the preview position ``xp`` [m], before the next stopping point,
        whose target speed is below v [m/s]: whatever the distance, the gain of re-motoring
        now would be braked away before the zone, after a speed minimum here (hunting:
        the plan's coast-and-motor cycle before the TSR's braking curve).
        """
        lead = self.core.limits.restriction_lead_m
        x_stop = self._next_stop_m
        for z, lim in ctx[4]:
            if xp < z.start_m - lead < x_stop and lim + JOIN_BAND_MPS < v:
                return True
        return False

    def _tsr_hold(self, ctx: tuple[Any, ...], xp: float, v: float, r: float,
                  dip: bool = False) -> bool:
        """No traction toward r [m/s] when a known TSR's curve takes the gain back.

        Accelerating from v to r and braking back to v (the swing between them included)
        takes ``H = (r^2 - v^2) / (2 a) + v swing_s + (r^2 - v^2) / (2 b)`` metres at the net
        acceleration a of full traction here (:meth:`AtoCore.net_accel`) and the planned
        deceleration b.  When the braking curve of a TSR ahead falls below v within H of
        the preview position ``xp`` [m], the gain would be braked away before the zone: a
        speed minimum before the TSR's own (hunting, e.g. a coast-and-motor cycle of the
        plan just before the curve).  The train then holds its speed instead.  ``dip``
        (:meth:`_speed_dip`): the speed has fallen since its peak; then any TSR ahead before
        the next stop whose target is below v holds it, whatever the distance
        (:meth:`_tsr_dip_hold`).
        """
        if r <= v + JOIN_BAND_MPS:
            return False
        if dip and self._tsr_dip_hold(ctx, xp, v):
            return True
        a = self.core.net_accel(xp, v)
        b = self._plan_decel(xp)
        dv2 = r * r - v * v
        reach = v * self.core.swing_s + dv2 / (2.0 * b) \
            + (dv2 / (2.0 * a) if a > 1e-3 else math.inf)
        lead = self.core.limits.restriction_lead_m
        rear = xp - self.train.length_m
        for z, _ in ctx[4]:
            if rear >= z.end_m:
                continue
            x_e = min(xp + reach, max(z.start_m - lead, xp))
            if self._cap_at(ctx, x_e, False) < v:
                return True
        return False

    def _authority_speed(self, t: float, ma: float) -> float:
        """Speed [m/s] of the end of movement authority from the last two states.

        0 when unknown, non-finite or shrinking (then the curve is treated as static).
        """
        prev = self._ma_prev
        self._ma_prev = (t, ma)
        if prev is None or not (math.isfinite(ma) and math.isfinite(prev[1])):
            self.authority_speed_mps = 0.0
        elif 0.0 < t - prev[0] <= 2.0:
            self.authority_speed_mps = max((ma - prev[1]) / (t - prev[0]), 0.0)
        return self.authority_speed_mps

    def _brake_capability(self, x_from: float, x_to: float) -> float:
        """Service deceleration [m/s^2] achievable on the steepest downhill of [x_from, x_to].

        Full service brake minus the grade's pull (resistance neglected: conservative).
        """
        a, b = (x_from, x_to) if x_from <= x_to else (x_to, x_from)
        lo, hi = a - self.train.length_m, max(b, a) + 1.0
        starts, grades = self._grade_lists
        n = len(grades)
        i0 = min(max(bisect_right(starts, lo) - 1, 0), n - 1)
        i1 = min(max(bisect_right(starts, hi) - 1, 0), n - 1)
        if math.isfinite(lo) and math.isfinite(hi) and i1 - i0 <= 1:
            # the 64 samples run from lo to hi exactly: the grades of their first and last
            # pieces are all they see (the same minimum, without the arrays)
            g = min(grades[i0], grades[i1])
        else:
            xs = np.linspace(lo, hi, 64)
            g = float(np.min(self.track.grade_at(xs)))
        return max(self.train.max_service_brake_mps2 + G_MPS2 * min(g, 0.0), 0.05)

    def speed_cap(self, s: dict[str, Any], x_at: Optional[float] = None,
                  authority: bool = True) -> float:
        """Ceiling on the desired speed from the ATP data and known TSRs [m/s].

        - the ATP's service-brake intervention speed, estimated from the supervision (EBI)
          speed of the state less the SBI offset, minus ``SPEED_MARGIN_MPS``;
        - end of movement authority: the speed whose SBI distance (:class:`AtpModel`) plus
          ``AUTHORITY_MARGIN_M`` fits in the authority left, and a braking curve at the
          planned deceleration to a stop ``AUTHORITY_MARGIN_M`` short of it;
        - every TSR known and not yet cleared by the rear: a braking curve at the planned
          deceleration reaching ``limit - margin`` ``lead`` metres before the zone, then
          the limit inside it.

        ``x_at``: evaluate at this chainage instead of the state's position [m] (the
        supervision speed of the state still applies); ``authority=False`` leaves the end of
        movement authority out.
        """
        return self._cap_at(self._cap_context(s), x_at, authority)

    def _cap_context(self, s: dict[str, Any]) -> tuple[Any, ...]:
        """What :meth:`speed_cap` takes from a state whatever the position.

        (x [m], v [m/s], supervision cap [m/s] (inf when unknown), end of authority [m],
        the TSRs known and not yet ended at the state's time with their target speeds,
        the ATP's worst-case response acceleration at v [m/s^2]).
        """
        x, v, t = float(s["x_m"]), float(s["v_mps"]), float(s["t_s"])
        cap = math.inf
        sup = float(s["supervision_speed_mps"])
        if math.isfinite(sup):
            cap = sup - self.atp.sbi_offset_mps - SPEED_MARGIN_MPS
        margin = self.core.limits.speed_margin_mps
        zones = tuple((z, max(z.limit_mps - margin, 0.5 * z.limit_mps)) for z in self.tsrs
                      if z.known_s <= t < z.to_s)
        # the ATP's worst-case response acceleration at the state's speed (AtpModel.sbi_speed)
        a_w = max_traction_accel_at(self.atp.train, v) + self.atp.g_down
        return x, v, cap, float(s["movement_authority_m"]), zones, a_w, \
            self.atp.sbi_terms(a_w)

    def _cap_at(self, ctx: tuple[Any, ...], x_at: Optional[float], authority: bool) -> float:
        """:meth:`speed_cap` from a :meth:`_cap_context`, its calls written out.

        The static SBI minimum (:meth:`AtpModel.static_sbi`), the planned deceleration
        (:meth:`_plan_decel`) and the authority's SBI speed (:meth:`AtpModel.sbi_speed`, its
        constants at the state's speed taken once per state in the context) are evaluated
        inline with the same operations in the same order; where a table is missing the
        methods themselves are called.  Proven equal to the per-call construction on
        generated states (``test/test_scalar_math.py``).
        """
        x, v, cap, ma, zones, a_w, terms = ctx
        if x_at is not None:
            x = float(x_at)
        atp = self.atp
        lst = atp._sbi_list
        if lst is not None:
            x0, dx, n = atp.grid_x0_m, atp.grid_dx_m, atp._sbi_n
            k0 = int((x - x0) / dx)
            k1 = int((x + v * CAP_LOOKAHEAD_S + 1.0 - x0) / dx) + 1
            k0 = 0 if k0 < 0 else (k0 if k0 < n else n - 1)
            k1 = k0 + 1 if k1 < k0 + 1 else (k1 if k1 < n else n)
            c = min(lst[k0:k1]) - atp.sbi_offset_mps - SPEED_MARGIN_MPS
        else:
            c = atp.static_sbi(x, x + v * CAP_LOOKAHEAD_S + 1.0) - SPEED_MARGIN_MPS
        if c < cap:
            cap = c
        run = self.core.run
        if run is not None and self._b_run is run:
            i = int((run.run_coordinate_at(x) + 50.0) / 10.0)
            tab = self._b_list
            n = self._b_n
            b = tab[0 if i < 0 else (i if i < n else n - 1)]
        else:
            b = self._plan_decel(x)
        if authority and math.isfinite(ma):
            d = ma - x - AUTHORITY_MARGIN_M
            c = braking_speed(d, b)
            if c < cap:
                cap = c
            # AtpModel.sbi_speed -> ebi_speed_at(d - t_sbi v, 0, a_w, t_r, b_g)
            c0, c2, two_b, t_sbi, off = terms
            c = ebi_speed_from(c0, two_b, c2, d - t_sbi * v) - off - SPEED_MARGIN_MPS
            if c < cap:
                cap = c
        if zones:
            lead = self.core.limits.restriction_lead_m
            rear = x - self.train.length_m
            for z, lim in zones:
                if rear >= z.end_m:
                    continue
                d = z.start_m - lead - x
                cap = min(cap, math.sqrt(lim * lim + 2.0 * b * max(d, 0.0)),
                          atp.sbi_speed_to(z.start_m - x - v * CAP_LOOKAHEAD_S, z.limit_mps)
                          - SPEED_MARGIN_MPS)
        return 0.0 if 0.0 > cap else cap

    def _plan_decel(self, x: float) -> float:
        """Planned braking deceleration at chainage x (the run's, else the capability)."""
        run = self.core.run
        if run is None:
            return 0.8 * self._brake_capability(x, x + 400.0)
        if self._b_run is not run:
            # lowest planned deceleration over [s - 50, s + 400] on a 10 m grid of the run
            ss = np.arange(-50.0, run.length_m + 410.0, 10.0)
            b = run.brake_decel(np.clip(ss, 0.0, run.length_m))
            k = 45
            pad = np.concatenate((b, np.full(k, b[-1])))
            self._b_tab = np.lib.stride_tricks.sliding_window_view(pad, k + 1).min(axis=1)
            self._b_list = self._b_tab.tolist()  # the same floats, read without numpy
            self._b_n = len(self._b_list)
            self._b_run = run
        i = int((run.run_coordinate_at(x) + 50.0) / 10.0)
        tab = self._b_list
        n = len(tab)
        return tab[0 if i < 0 else (i if i < n else n - 1)]

    def guard(self, s: dict[str, Any], ctx: Optional[tuple[Any, ...]] = None) -> float:
        """Upper bound on the effort from authority, TSRs, the stop and supervision.

        The caps of :meth:`speed_cap` are followed by the tracker; this hard bound only acts
        when the train is well above one (speed feedback on top of the curve's
        deceleration) and when it is above the curve that still stops at the platform.
        ``ctx``: the state's :meth:`_cap_context` when the caller has it.
        """
        bound = 1.0
        x, v = float(s["x_m"]), float(s["v_mps"])
        nxt = int(s["next_station"])
        st = self._stations_list
        x_stop = st[nxt] if 0 <= nxt < len(st) else math.inf
        bs = self.train.max_service_brake_mps2
        # the service brake's deceleration at the train's own position (its grade)
        b_ach = self._brake_capability(x, x)
        d = x_stop - x
        if 0.0 < d < 400.0 and v > 0.3:
            # stopping guard: above the curve that ends at the stop point (late, e.g. after
            # an authority restriction released near the platform) brake with the
            # deceleration that ends there, plus the grade's pull
            a_req = v * v / (2.0 * max(d - 0.15, 0.05))
            if a_req > STOP_GUARD * b_ach:
                bound = min(bound, -min(1.0, (a_req + bs - b_ach) / bs))
        cap = self._cap_at(ctx if ctx is not None else self._cap_context(s), None, True)
        over = v - cap - GUARD_SLACK_MPS
        if over > 0.0:
            bound = min(bound, -min(1.0, (bs - b_ach) / bs + GUARD_GAIN * over))
        return bound


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
    _sbi_list: Optional[list[float]] = dataclasses.field(default=None, init=False, repr=False,
                                                         compare=False)
    _sbi_n: int = dataclasses.field(default=0, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        """Keep the static SBI table as a list too (its minima without numpy; not with NaN)."""
        tab = self.sbi_static_mps
        lst = None
        if tab is not None and not bool(np.isnan(np.asarray(tab, dtype=float)).any()):
            lst = np.asarray(tab, dtype=float).tolist()
        object.__setattr__(self, "_sbi_list", lst)
        object.__setattr__(self, "_sbi_n", len(lst) if lst is not None else 0)

    def sbi_speed_to(self, dist_m: float, target_mps: float) -> float:
        """Static SBI speed [m/s] ``dist_m`` before a point where the limit is ``target``.

        The plant's static construction (:mod:`metro_atc.core.line.track`): braking
        envelope ``E^2 = (target + tol)^2 + 2 b_g D`` evaluated past the response and SBI
        look-ahead distances, ``v + a_w(v) t_r = E`` (one fixed-point step), less the SBI
        offset.
        """
        d = max(dist_m - self.resp_dist_m - self.sbi_dist_m, 0.0)
        e = math.sqrt((target_mps + self.tol_mps) ** 2 + 2.0 * self.b_g * d)
        v = e - (max_traction_accel_at(self.train, e) + self.g_down) * self.t_r
        v = e - (max_traction_accel_at(self.train, max(v, 0.0)) + self.g_down) * self.t_r
        return v - self.sbi_offset_mps

    def static_sbi(self, x_from_m: float, x_to_m: float) -> float:
        """Lowest static SBI speed [m/s] (limits, no TSR) with the front in [from, to] [m].

        The plant's static supervision (``AtpSupervisor.sbi_static`` less the SBI offset) on its
        grid; inf when the model has no table.
        """
        tab = self.sbi_static_mps
        if tab is None:
            return math.inf
        k0 = int((x_from_m - self.grid_x0_m) / self.grid_dx_m)
        k1 = int((x_to_m - self.grid_x0_m) / self.grid_dx_m) + 1
        lst = self._sbi_list
        if lst is not None:
            # the same minimum over the same floats without a numpy call, the index clamps
            # of the numpy path written out (integers)
            n = len(lst)
            k0 = 0 if k0 < 0 else (k0 if k0 < n else n - 1)
            k1 = k0 + 1 if k1 < k0 + 1 else (k1 if k1 < n else n)
            return min(lst[k0:k1]) - self.sbi_offset_mps
        k0 = min(max(k0, 0), tab.size - 1)
        k1 = min(max(k1, k0 + 1), tab.size)
        return float(tab[k0:k1].min()) - self.sbi_offset_mps

    def sbi_terms(self, a_w: float) -> tuple[float, float, float, float, float]:
        """The constants of :meth:`sbi_speed` at one ``a_w`` [m/s^2], as it computes them.

        (``c0``, ``c2``, ``2 b_g``, ``t_sbi``, SBI offset) of
        :func:`metro_atc.core.line.track.ebi_speed_at` with target 0: then
        ``sbi_speed(d, v, a_w) = (sqrt(max(c0 + 2 b_g (d - t_sbi v), 0)) - c2) - offset``.
        """
        c0, c1, c2 = ebi_coef(float(self.b_g), float(self.t_r), float(a_w))
        return float(c0), float(c2), float(c1), self.t_sbi, self.sbi_offset_mps

    def sbi_speed(self, dist_m: float, v_mps: float, a_w: Optional[float] = None) -> float:
        """ATP service-brake intervention speed [m/s] for a stop ``dist_m`` ahead at v.

        ``ebi_speed(dist - t_sbi v)`` with the worst-case response acceleration
        ``a_w = traction(v) + g_down`` (:func:`metro_atc.core.line.track.ebi_speed`;
        ``a_w`` [m/s^2]: that value when the caller has it for this v).
        """
        if a_w is None:
            a_w = max_traction_accel_at(self.train, v_mps) + self.g_down
        return ebi_speed_at(dist_m - self.t_sbi * v_mps, 0.0, a_w, self.t_r, self.b_g) \
            - self.sbi_offset_mps


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
