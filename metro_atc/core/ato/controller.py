"""Stateful ATO core for one train: plan an inter-station run, then command the effort.

The ROS node ``ato_controller`` owns one :class:`AtoCore` per train.  On a departure
command it calls :meth:`AtoCore.plan` (x_start, x_stop, target running time); every control
step it calls :meth:`AtoCore.command` with the train state and publishes the returned
normalised effort u in [-1, 1] (u > 0: fraction of the maximum tractive force, u < 0:
fraction of the maximum service brake; :func:`metro_atc.core.line.vehicle.effort_force`).

Safety behaviour of :meth:`AtoCore.command_ex`: non-finite input, a state older than
``stale_after_s`` (when the caller passes ``now_s``) or a time stamp going backwards give a
full service brake (u = -1) with the reason; with no plan the train is held braked; past the
stopping point or above the envelope it brakes.  At the platform a holding brake is applied.
The command rate is limited by the jerk limit (Ke 2010: 1 m/s^3).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Optional


from metro_atc.core.ato.control_kernel import STATE_INDEX
from metro_atc.core.ato.envelope import OperatingLimits, RunModel
from metro_atc.core.ato.fuzzy import FuzzyController
from metro_atc.core.ato.pi import PIController
from metro_atc.core.ato.planner import PLANNERS, Profile, plan_profile
from metro_atc.core.ato.registry import TRACKERS as TRACKER_REGISTRY
from metro_atc.core.ato.reference_curve import ProfileReference
from metro_atc.core.ato.tsr_plan import track_with_tsrs
from metro_atc.core.line.vehicle import (Track, TrainParams, max_traction_force_at,
                                         resistance_force_at)
from metro_atc.core.scalar_math import sqrt_or_nan

TRACKERS = TRACKER_REGISTRY.names
"""Tracker names accepted by :class:`AtoCore` (:data:`metro_atc.core.ato.registry.TRACKERS`)."""
HOLD_BRAKE = -0.5
"""Holding-brake command at the platform [-]."""
SAFE_BRAKE = -1.0
"""Command on bad input: full service brake [-]."""
JOIN_BAND_MPS = 0.3
"""Below the reference by more than this [m/s], the tracker aims at the reference where a
swing from full traction to the planned braking would end (no overshoot of a braking
curve joined from below)."""
BERTH_WINDOW_M = 0.3
"""A standstill this close to the stopping point is the arrival (+-0.30 m, the
platform-screen-door tolerance); stopped further short, the train creeps on [m]."""
STOP_FF_MPS = 0.5
"""Below this desired speed [m/s] the feedforward never commands traction."""
JOIN_MIN_SPEED_MPS = 3.0
"""The join rule applies above this speed only (in the final creep to the stopping point the
reference ahead is zero) [m/s]."""
PREVIEW_PERIODS = 1.0
"""The tracker follows the reference this many control periods ahead of the train (the
effort is held over the next period and the plant limits its rate) [-]."""
APPROACH_JERK_SHARE = 0.8
"""Share of the jerk limit the approach bound counts on to take the surplus acceleration
off before the reference is reached (:meth:`AtoCore.approach_bound`) [-]."""
APPROACH_MIN_SPEED_MPS = 1.0
"""The approach bound applies above this speed (not in the creep to the stop point) [m/s]."""
RESTART_MAX_SPEED_MPS = 3.0
"""Below this speed the stop bound (:meth:`AtoCore.stop_bound`) limits the traction [m/s]."""


@dataclass(frozen=True)
class Command:
    """One command: effort u [-1, 1], ok flag, reason, desired speed r [m/s]."""

    u: float
    ok: bool
    reason: str
    r_mps: float


class AtoCore:
    """ATO of one train: planner (``PLANNERS``) + tracker (``TRACKERS``).

    Parameters: train, track; planner name; tracker name; control period [s];
    stale_after_s: maximum age of a state when ``now_s`` is given [s]; limits: operating
    limits; planner_params: passed to :func:`metro_atc.core.ato.planner.plan_profile`
    (e.g. MMAS ``n_ants``, ``n_iterations``; FCTP ``coast_fraction``).
    """

    def __init__(self, train: TrainParams, track: Track, planner: str = "ectp",
                 tracker: str = "fuzzy", control_period_s: float = 0.1,
                 stale_after_s: float = 1.0, limits: Optional[OperatingLimits] = None,
                 shared: Optional[dict[str, Any]] = None, feedforward: bool = True,
                 **planner_params: Any) -> None:
        """Validate the names and build the tracker.

        ``shared``: a dict shared by the cores of one process (same train and track): the
        pre-work tables, run models and finished plans are then computed once per run and
        target instead of once per train (``shared["plan_store"]``, optional: a
        :class:`~metro_atc.core.ato.plan_store.PlanStore` shares the finished plans with the
        other processes of a run).  ``feedforward``: add the effort that holds the
        reference on the grade (:meth:`_feedforward`) to the tracker's output.
        """
        if planner.lower().replace("-", "_") not in PLANNERS:
            raise ValueError(f"unknown planner {planner!r}; expected one of {PLANNERS}")
        if tracker not in TRACKERS:
            raise ValueError(f"unknown tracker {tracker!r}; expected one of {TRACKERS}")
        if not (math.isfinite(control_period_s) and control_period_s > 0.0):
            raise ValueError("control_period_s must be a positive number")
        self.train = train
        self.track = track
        self.planner = planner
        self.tracker_name = tracker
        self.period = float(control_period_s)
        self.stale_after_s = float(stale_after_s)
        self.limits = limits if limits is not None else OperatingLimits()
        self.planner_params = dict(planner_params)
        self.tracker: FuzzyController | PIController = \
            TRACKER_REGISTRY[tracker].load()()  # default gains
        self._shared: dict[str, Any] = shared if shared is not None else {}
        self._cache: dict[Any, Any] = self._shared.setdefault("prework", {})
        self._runs: dict[tuple[Any, ...], RunModel] = self._shared.setdefault("runs", {})
        self._plans: dict[Any, Profile] = self._shared.setdefault("plans", {})
        self.profile: Optional[Profile] = None
        self.run: Optional[RunModel] = None
        self._ref: Optional[ProfileReference] = None
        self._tail_brake = 0.4
        self._last_t: Optional[float] = None
        self._last_u = 0.0
        self._last_ff = 0.0
        self.feedforward = bool(feedforward)
        self._arrived = False
        self._still_s = 0.0
        self.last_reason = "no plan"
        self._fg_run: Optional[RunModel] = None
        self._fg_s = math.nan
        self._fg_v = 0.0
        self._ce_run: Optional[RunModel] = None
        self._ce_s = math.nan
        self._ce_v = 0.0
        self._kplan: Optional[tuple[Any, Any, tuple[Any, ...]]] = None
        self._train0 = train
        self._mass_key: tuple[Any, ...] = ()
        self._derive()

    def _derive(self) -> None:
        """The rates derived from the train and the limits (at build and :meth:`set_train`)."""
        train = self.train
        a_ref = max(train.a1_mps2, train.max_service_brake_mps2)
        self._du_max_per_s = self.limits.jerk_max_mps3 / max(a_ref, 1e-6)
        # jerk [m/s^3] at which the surplus traction can be taken off: the ATO's rate limit
        # in traction units and the plant's jerk limit, whichever is slower
        self.approach_jerk = APPROACH_JERK_SHARE * min(
            self._du_max_per_s * train.a1_mps2, train.max_jerk_mps3)
        self.swing_s = (self.limits.accel_max_mps2 + self.limits.brake_decel_mps2) \
            / max(self.limits.jerk_max_mps3, 1e-6)
        """Time of a jerk-limited swing from full traction to the planned braking [s]."""
        self._brake_share = self.limits.brake_decel_mps2 / max(train.max_service_brake_mps2,
                                                               1e-6)
        """The planned braking deceleration as an effort (a share of the service brake) [-]."""

    def set_train(self, train: TrainParams, limits: OperatingLimits) -> None:
        """Plan and track from now on with the rolling stock ``train`` at its load.

        ``train``: the reference stock's :meth:`~TrainParams.at_mass` (the load-weigh mass
        at departure), ``limits`` the planning limits at that mass.  Runs, pre-work and
        plans of a mass other than the first train's are kept apart (keyed by the mass) in
        the shared caches.  Takes effect at the next :meth:`plan`.
        """
        if train is self.train and limits is self.limits:
            return
        self.train = train
        self.limits = limits
        self._mass_key = () if train is self._train0 \
            else (("mass_kg", float(train.mass_kg)),)
        self._cache = self._shared.setdefault("prework", {}) if not self._mass_key \
            else self._shared.setdefault("prework_mass", {}).setdefault(self._mass_key, {})
        self._derive()

    # ------------------------------------------------------------------ planning
    def plan(self, x_start_m: float, x_stop_m: float, target_running_time_s: float,
             restrictions: tuple[tuple[float, float, float], ...] = ()) -> Profile:
        """Plan a run; returns the profile (a flat-out fallback with ``feasible=False``).

        ``restrictions``: temporary speed limits the run respects as civil limits, (start
        [m], end [m], limit [m/s]) (:func:`metro_atc.core.ato.tsr_plan.tsrs_for_run`).
        """
        key: tuple[Any, ...] = (float(x_start_m), float(x_stop_m)) + self._mass_key
        cache = self._cache
        if restrictions:
            # a run of its own (envelope, pre-work tables and plans keyed by the TSRs too)
            key = key + (tuple(restrictions),)
            cache = self._shared.setdefault("prework_tsr", {}).setdefault(key, {})
        run = self._runs.get(key)
        if run is None:
            track = track_with_tsrs(self.track, restrictions) if restrictions else self.track
            run = RunModel(self.train, track, x_start_m, x_stop_m, self.limits)
            self._runs[key] = run
        params = dict(self.planner_params)
        # the profile integration grid grows with the run (cost ~ 1/h^2): 2 m on metro runs,
        # ~10 m on a 7 km and ~130 m on a 94 km high-speed run
        params.setdefault("h_m", max(2.0, run.length_m / 700.0))
        memo = (self.planner, key, round(float(target_running_time_s), 2)
                if math.isfinite(float(target_running_time_s)) else None,
                tuple(sorted((k, repr(v)) for k, v in params.items())))
        prof = self._plans.get(memo) if memo[2] is not None else None
        store = self._shared.get("plan_store") if memo[2] is not None else None
        if prof is None and store is not None:
            prof = store.get(memo)  # planned by another process of the run (same result)
            if prof is not None:
                self._plans[memo] = prof
        if prof is None:
            prof = plan_profile(run, target_running_time_s, self.planner, cache, **params)
            self._plans[memo] = prof
            if store is not None:
                store.put(memo, prof)
        self.run = run
        self.profile = prof
        b = float(run.brake_decel(run.length_m))  # at the platform (grade-aware option)
        self._ref = ProfileReference(prof.s_grid, prof.v_profile, run.length_m,
                                     tail_decel=b, creep_speed=0.5, tail_brake=0.5 * b)
        self._tail_brake = 0.5 * b
        self.tracker.reset(0.0)
        self._last_t = None
        self._last_u = 0.0
        self._arrived = False
        self._still_s = 0.0
        self.last_reason = "planned" if prof.feasible else prof.message
        return prof

    # ------------------------------------------------------------------ control
    def command(self, t_s: float, x_m: float, v_mps: float,
                now_s: Optional[float] = None, r_cap_mps: float = math.inf,
                cap_accel_mps2: float = 0.0) -> float:
        """Normalised effort u in [-1, 1]; see :meth:`command_ex` (reason in last_reason)."""
        return self.command_ex(t_s, x_m, v_mps, now_s, r_cap_mps, cap_accel_mps2).u

    def _feedforward(self, s: float, v: float, r: float, a_cap: Optional[float]) -> float:
        """Effort [-1, 1] that holds the reference on the grade (Li n.d. Newton's law).

        ``F = M_eff a_ref + F_r(v) + F_g`` with the grade force averaged over the train
        length behind the front at s and ``a_ref = d(r^2/2)/ds`` of the planned reference
        (``a_cap``, the cap's slope, when an outer cap sets r); normalised by the maximum
        tractive force (F > 0) or the service brake ``M_eff b_s`` (F < 0), as the plant
        applies the effort.
        """
        run = self.run
        assert run is not None and self._ref is not None
        tr = self.train
        a_ref = float(a_cap) if a_cap is not None and math.isfinite(a_cap) else 0.0
        if a_cap is None and r > 0.0:
            h = max(v * self.period, 0.5)
            r1 = self._ref.speed_at(s + h)
            a_ref = (r1 * r1 - r * r) / (2.0 * h)
        f_g = self._grade_force(run, s)
        f = tr.effective_mass_kg * a_ref + resistance_force_at(tr, v) + f_g
        if r < STOP_FF_MPS:
            # final stop: no traction feedforward (the resistance at standstill is static
            # friction, and a creeping train would never come to rest at the platform)
            f = min(f, 0.0)
        if f >= 0.0:
            return min(f / max(max_traction_force_at(tr, v), 1.0), 1.0)
        return max(f / (tr.effective_mass_kg * tr.max_service_brake_mps2), -1.0)

    def _braking_needed(self, s: float, v: float, r: float, r_a: float, ds: float) -> bool:
        """Whether following the reference from r to r_a over ds [m] needs the brake.

        True when the deceleration of the reference ``(r^2 - r_a^2) / (2 ds)`` exceeds what
        the train loses coasting (resistance and grade at s, Li n.d. Newton's law): a
        braking curve, not a coasting phase of the plan.
        """
        run = self.run
        assert run is not None
        tr = self.train
        if ds <= 0.0:
            return False
        a_ref = (r * r - r_a * r_a) / (2.0 * ds)
        a_coast = (resistance_force_at(tr, v) + self._grade_force(run, s)) / tr.effective_mass_kg
        return a_ref > a_coast

    def brake_onset_bound(self, s: float, s_p: float, v: float, r: float, dt: float) -> float:
        """Highest effort [-1, 1] that still joins the plan's braking curve ahead on time.

        The brake builds up at the ATO's effort rate rho (the jerk limit): from the last
        effort u0 to the curve's effort u_c (:meth:`_feedforward` with the curve's
        deceleration) a linear ramp of tau = (u0 - u_c) / rho, which loses the speed of
        braking at the curve's deceleration for tau / 2 only.  Started when the train
        reaches the curve's speed v tau / 2 ahead of the preview point ``s_p`` [m run
        coordinate], the ramp ends on the curve; started at the curve (a step demand),
        it ends behind it, and the tracker and the stopping guard catch up with a full
        service brake (``gen_0009_inc``: a brake false alarm).  Once the onset
        is reached the bound keeps ramping, ``rho dt`` per step, down to u_c; 1 (no bound)
        before it, when the curve ahead is not a braking curve (no steeper than
        coasting) or when the effort is already at the curve's.
        """
        assert self._ref is not None
        rho, u0 = self._du_max_per_s, self._last_u
        h = max(v * self.period, 0.5)
        tau = (self._brake_share + u0) / rho
        u_c = u0
        r_a = r
        for _ in range(2):
            s_a = s_p + 0.5 * v * tau
            r_a = self._ref.speed_at(s_a)
            r_h = self._ref.speed_at(s_a + h)
            if not self._braking_needed(s, v, r_a, r_h, h):
                return 1.0
            u_c = self._feedforward(s, v, r_a, (r_h * r_h - r_a * r_a) / (2.0 * h))
            tau = max(u0 - u_c, 0.0) / rho
            if tau <= 0.0:
                return 1.0
        if v < r_a:
            return 1.0  # the onset is still ahead
        return max(u_c, u0 - rho * dt)

    def approach_bound(self, s: float, v: float, r_end: float) -> float:
        """Highest effort [-1, 1] that still reaches ``r_end`` [m/s] from below without overshoot.

        Accelerating toward a speed the train must then hold (a cap or a cruise level), the
        surplus acceleration ``a`` over the holding effort (resistance and grade at s, seed
        004 Newton's law) can only be taken off at the jerk ``J`` (:attr:`approach_jerk`),
        one control period ``T`` after the decision; the speed still gained is
        ``a T + a^2 / (2 J)``.  It must fit in the gap ``r_end - v``:
        ``a = J (-T + sqrt(T^2 + 2 gap / J))``.  The bound is the force
        ``F_hold + M_eff a`` as an effort (traction or service brake scale).
        """
        run = self.run
        assert run is not None
        tr = self.train
        j, t = self.approach_jerk, self.period
        gap = max(r_end - v, 0.0)
        a_ex = j * (-t + math.sqrt(t * t + 2.0 * gap / j))
        f = resistance_force_at(tr, v) + self._grade_force(run, s) \
            + tr.effective_mass_kg * a_ex
        if f >= 0.0:
            return min(f / max(max_traction_force_at(tr, v), 1.0), 1.0)
        return max(f / (tr.effective_mass_kg * tr.max_service_brake_mps2), -1.0)

    def stop_distance(self, v: float, a: float) -> float:
        """Distance [m] to rest from speed v [m/s] with the surplus acceleration a [m/s^2].

        The effort is held one control period ``T``, then taken off at the jerk ``J``
        (:attr:`approach_jerk`) down to the gentlest braking of the stop tail ``b``, which
        then holds to rest: ``v T + a T^2/2`` + the jerk-limited ramp + ``v_1^2 / (2 b)``.
        """
        j, t, b = self.approach_jerk, self.period, max(self._tail_brake, 0.05)
        v0 = v + a * t
        x0 = v * t + 0.5 * a * t * t
        tau = (a + b) / j
        v1 = v0 + a * tau - 0.5 * j * tau * tau
        if v1 <= 0.0:  # at rest inside the ramp: v0 + a t - J t^2 / 2 = 0
            ts = (a + math.sqrt(a * a + 2.0 * j * v0)) / j
            return x0 + v0 * ts + 0.5 * a * ts * ts - j * ts ** 3 / 6.0
        return x0 + v0 * tau + 0.5 * a * tau * tau - j * tau ** 3 / 6.0 + v1 * v1 / (2.0 * b)

    def stop_bound(self, s: float, v: float) -> float:
        """Highest effort [-1, 1] from which the train can still stop at the stopping point.

        Restarting close to the platform (after a breakdown or a hold short of it) the
        tracker sees the stop tail ahead as a speed to reach; full traction there overruns
        the stop (a train held 1.65 m short for 60 s ran 1.06 m past it).  The bound is the
        largest surplus acceleration whose :meth:`stop_distance` fits in the distance left
        (bisection), as an effort; 0 (no traction) when even coasting does not fit.  The
        surplus of the last command counts as well (the plant takes it off at the jerk
        limit whatever is commanded now).
        """
        run = self.run
        assert run is not None
        tr = self.train
        d = run.length_m - s
        f_hold = resistance_force_at(tr, v) + self._grade_force(run, s)
        f_max = max(max_traction_force_at(tr, v), 1.0)
        a_hi = max((f_max - f_hold) / tr.effective_mass_kg, 0.0)
        a_last = max((self._last_u * f_max - f_hold) / tr.effective_mass_kg, 0.0) \
            if self._last_u > 0.0 else 0.0
        if self.stop_distance(v, a_last) >= d:
            return 0.0
        if self.stop_distance(v, a_hi) <= d:
            return 1.0
        lo, hi = 0.0, a_hi
        for _ in range(30):
            mid = 0.5 * (lo + hi)
            if self.stop_distance(v, max(mid, a_last)) <= d:
                lo = mid
            else:
                hi = mid
        return min(max((f_hold + tr.effective_mass_kg * lo) / f_max, 0.0), 1.0)

    def _grade_force(self, run: RunModel, s: float) -> float:
        """Mean grade force [N] over the train with its front at run coordinate s [m].

        ``run.mean_grade_force_at(s - length, s)``, kept for the last (run, s): the
        feedforward and the bounds of one control step ask for it at the same s several
        times (the same float, computed once).
        """
        if s == self._fg_s and run is self._fg_run:
            return self._fg_v
        f = run.mean_grade_force_at(s - self.train.length_m, s)
        self._fg_run, self._fg_s, self._fg_v = run, s, f
        return f

    def ceiling_e_at(self, run: RunModel, s: float) -> float:
        """The run's ceiling energy at run coordinate s [m^2/s^2], kept for the last (run, s).

        The on-board speed-dip check and :meth:`command_ex` ask for it at the same s in one
        control step (the same float, computed once).
        """
        if s == self._ce_s and run is self._ce_run:
            return self._ce_v
        e = run.ceiling_e_at(s)
        self._ce_run, self._ce_s, self._ce_v = run, s, e
        return e

    def reference_speed(self, x_m: float) -> float:
        """The planned reference r [m/s] at chainage x [m] (0 with no plan)."""
        if self.run is None or self._ref is None:
            return 0.0
        return self._ref.speed_at(self.run.run_coordinate_at(float(x_m)))

    def net_accel(self, x_m: float, v_mps: float) -> float:
        """Net acceleration [m/s^2] of full traction at chainage x [m] and speed v [m/s].

        Traction less resistance and the grade over the train (Li n.d. Newton's law),
        at most the planning limit ``accel_max_mps2``; 0 with no plan.
        """
        run = self.run
        if run is None:
            return 0.0
        tr = self.train
        s = run.run_coordinate_at(float(x_m))
        f = max_traction_force_at(tr, v_mps) - resistance_force_at(tr, v_mps) \
            - self._grade_force(run, s)
        return min(max(f / tr.effective_mass_kg, 0.0), self.limits.accel_max_mps2)

    # ------------------------------------------------------------------ compiled step
    def kernel_constants(self) -> Optional[list[float]]:
        """The controller constants of the compiled ATO step (``control_kernel_pack``).

        (period [s], swing [s], effort rate [1/s], brake share [-], approach jerk [m/s^3],
        feedforward 0/1, fuzzy e scale [m/s], d scale [m/s], gain [-], PI 0/1, PI kp
        [1/(m/s)], ki [1/m], restriction lead [m], TSR speed margin [m/s], acceleration
        limit [m/s^2]); None when the tracker is the fuzzy controller's absolute form (the
        kernel does not cover it).
        """
        tr = self.tracker
        head = [self.period, self.swing_s, self._du_max_per_s, self._brake_share,
                self.approach_jerk, 1.0 if self.feedforward else 0.0]
        lim = self.limits
        tail = [lim.restriction_lead_m, lim.speed_margin_mps, lim.accel_max_mps2]
        if isinstance(tr, PIController):
            return head + [1.0, 1.0, 0.0, 1.0, tr.p.kp, tr.p.ki] + tail
        if not isinstance(tr, FuzzyController) or not tr.p.incremental:
            return None
        return head + [tr.p.e_scale_mps, tr.p.d_scale_mps, tr.p.gain, 0.0, 0.0, 0.0] + tail

    def kernel_plan(self) -> Optional[tuple[Any, ...]]:
        """The plan's tables for the compiled step, the same object while the plan holds.

        (head: x_start [m], direction, run length [m], PSS start [m], tail brake [m/s^2],
        then :meth:`ProfileReference.kernel_tables`' head; ref s, ref v^2, grade
        breakpoints, grade-force integral, envelope s, ceiling energy); None with no plan.
        """
        run, ref = self.run, self._ref
        if run is None or ref is None:
            return None
        kp = self._kplan
        if kp is not None and kp[0] is run and kp[1] is ref:
            return kp[2]
        rh, rs, re = ref.kernel_tables()
        bp, _, cum, s_env, e_ceil = run.point_tables()
        head = [run.x_start_m, run.direction, run.length_m, run.pss_start_s,
                self._tail_brake] + rh
        out = (head, rs, re, bp, cum, s_env, e_ceil)
        self._kplan = (run, ref, out)
        return out

    def kernel_state(self) -> Optional[list[float]]:
        """The per-train state the compiled step reads: ``control_kernel.CORE_STATE_FIELDS``.

        Their values in that order; None when the tracker's state is not a plain one-train
        state.
        """
        ts = self.tracker.scalar_state()
        if ts is None:
            return None
        lt = self._last_t
        return [0.0 if lt is None else 1.0, 0.0 if lt is None else lt, self._last_u,
                self._last_ff, 1.0 if self._arrived else 0.0, self._still_s,
                1.0 if ts[0] else 0.0, ts[1], ts[2]]

    def set_kernel_state(self, st: list[float], reason: str) -> None:
        """Take the state back from the compiled step (``control_kernel.STATE_FIELDS``' values)."""
        i = STATE_INDEX
        self._last_t = st[i["t"]] if st[i["has_t"]] != 0.0 else None
        self._last_u = st[i["u"]]
        self._last_ff = st[i["ff"]]
        self._arrived = st[i["arrived"]] != 0.0
        self._still_s = st[i["still"]]
        self.tracker.set_scalar_state(st[i["has_e"]] != 0.0, st[i["e"]], st[i["tu"]])
        self.last_reason = reason

    @property
    def last_effort(self) -> float:
        """The last effort commanded (after rate limits and guards) [-1, 1]."""
        return self._last_u

    def applied(self, u: float) -> None:
        """Align the tracker and the jerk limiter with the effort actually applied.

        Called when an outer guard lowered the command: the tracker's state then follows
        the applied effort (no wind-up against the guard) and the next command is rate
        limited from it.
        """
        if math.isfinite(u) and u != self._last_u:
            self._last_u = float(u)
            self.tracker.set_output(float(u), self._last_ff)

    def _fail(self, reason: str) -> Command:
        self.last_reason = reason
        self._last_u = SAFE_BRAKE
        return Command(SAFE_BRAKE, False, reason, 0.0)

    def command_ex(self, t_s: float, x_m: float, v_mps: float,
                   now_s: Optional[float] = None, r_cap_mps: float = math.inf,
                   cap_accel_mps2: float = 0.0) -> Command:
        """Tracking command for the state (time [s], chainage [m], speed [m/s]).

        ``r_cap_mps``: a ceiling on the desired speed from outside the plan (the on-board
        guards: ATP supervision, authority and TSR braking curves), taken at the preview
        position [m/s]; the tracker follows min(plan, cap), so a restriction is approached
        smoothly, jerk limited; ``cap_accel_mps2``: the cap's slope d(cap^2/2)/ds there
        (the feedforward acceleration while the cap sets the reference) [m/s^2].
        """
        isfinite = math.isfinite
        try:
            if not (isfinite(float(t_s)) and isfinite(float(x_m)) and isfinite(float(v_mps))
                    and (now_s is None or isfinite(float(now_s)))):
                return self._fail("non-finite state input")
        except (TypeError, ValueError):
            return self._fail("non-numeric state input")
        t, x, v = float(t_s), float(x_m), max(float(v_mps), 0.0)
        if now_s is not None and float(now_s) - t > self.stale_after_s:
            return self._fail(f"stale state ({float(now_s) - t:.2f} s old)")
        if self._last_t is not None and t < self._last_t - 1e-9:
            return self._fail("state time went backwards")
        if self.run is None or self._ref is None:
            self.last_reason = "no plan: holding brake"
            return Command(SAFE_BRAKE if v > 0.0 else HOLD_BRAKE, False, self.last_reason, 0.0)
        dt = self.period if self._last_t is None else t - self._last_t
        if dt <= 0.0:  # duplicate sample: repeat the last command
            return Command(self._last_u, True, "duplicate state", 0.0)
        dt = min(dt, 5.0 * self.period)
        self._last_t = t
        run = self.run
        s = run.run_coordinate_at(x)
        if self._arrived:
            self.last_reason = "stopped at platform"
            self._last_u = HOLD_BRAKE
            return Command(HOLD_BRAKE, True, self.last_reason, 0.0)
        if s > run.length_m + 2.0:
            return self._fail(f"overshot the stopping point by {s - run.length_m:.2f} m")
        # preview: the command acts over the coming control period, so track the reference
        # where the train will be (PREVIEW_PERIODS control periods ahead at its speed)
        s_p = s + PREVIEW_PERIODS * v * self.period
        r = self._ref.speed_at(s_p)
        r_swing = math.nan  # the reference where a swing to braking would end (once a step)
        if r - v > JOIN_BAND_MPS and v > JOIN_MIN_SPEED_MPS and self._last_u > 0.0:
            # below the reference while in traction: when accelerating toward a braking
            # curve, aim at the curve where the jerk-limited swing to braking would end
            r_swing = self._ref.speed_at(s_p + v * self.swing_s)
            r = min(r, r_swing)
        r_plan = r
        capped = r_cap_mps < r
        if capped:
            r = max(float(r_cap_mps), 0.0)
        u_ff = self._feedforward(s, v, r, cap_accel_mps2 if capped else None) \
            if self.feedforward else 0.0
        self._last_ff = u_ff
        u = self.tracker.step_float(r, v, dt, u_ff)
        bounded = False
        if u > 0.0 and v > APPROACH_MIN_SPEED_MPS:
            # approaching the reference from below: take the traction off in time (the
            # reference where a swing would end when the plan still rises)
            if not capped and r_swing != r_swing:
                r_swing = self._ref.speed_at(s_p + v * self.swing_s)
            r_end = r if capped else min(max(r, r_swing), r_cap_mps)
            u_b = self.approach_bound(s, v, r_end)
            if u_b < u:
                u, bounded = u_b, True
        if not capped and v > JOIN_MIN_SPEED_MPS and self._last_u > -self._brake_share:
            # coasting toward a braking curve of the plan: ramp the brake on in time
            u_b = self.brake_onset_bound(s, s_p, v, r, dt)
            if u_b < u:
                u, bounded = u_b, True
        if u > 0.0 and v < RESTART_MAX_SPEED_MPS and s > 0.5 * run.length_m:
            # (re)starting near the platform: only the traction the stop still absorbs
            u_b = self.stop_bound(s, v)
            if u_b < u:
                u, bounded = u_b, True
        if r_plan <= 0.0 and s >= run.length_m - BERTH_WINDOW_M:
            u = min(u, HOLD_BRAKE)  # at the stopping point: brake to rest, never creep
        ceiling = sqrt_or_nan(2.0 * self.ceiling_e_at(run, min(max(s, 0.0), run.length_m)))
        reason = "tracking"
        if s >= run.pss_start_s:
            reason = "programmed station stopping"  # Ke 2010: PSS from 350 m
        if v > ceiling + 1.0 and s < run.length_m:
            u = SAFE_BRAKE
            reason = "above the speed envelope"
        du = self._du_max_per_s * dt
        u_lim = min(max(u, self._last_u - du), self._last_u + du)
        if (u_lim != u or bounded) and reason != "above the speed envelope":
            self.tracker.set_output(u_lim, u_ff)
        u = u_lim
        if v <= 1e-6 and s > run.length_m - BERTH_WINDOW_M:
            self._still_s += dt
            if self._still_s >= 1.0:
                self._arrived = True
                u = HOLD_BRAKE
                reason = "stopped at platform"
        else:
            self._still_s = 0.0
        self._last_u = u
        self.last_reason = reason
        return Command(u, True, reason, r)
