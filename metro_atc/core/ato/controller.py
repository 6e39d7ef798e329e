"""Stateful ATO core for one train: plan an inter-station run; the compiled step's data.

The on-board ATO (:class:`metro_atc.core.ato.onboard.OnboardAto`, what the ROS node
``ato_controller`` and the ROS-free closed loop run per train) owns one :class:`AtoCore`.
On a departure it calls :meth:`AtoCore.plan` (x_start, x_stop, target running time); every
control step the compiled step (:mod:`metro_atc.core.ato.control_kernel_step`, the one
source of the control law) turns the state into a normalised effort u in [-1, 1] (u > 0:
fraction of the maximum tractive force, u < 0: fraction of the maximum service brake;
:func:`metro_atc.core.line.vehicle.effort_force`) from the tables and constants this core
hands over (:meth:`kernel_plan`, :meth:`kernel_constants`) and the per-train state it holds
(:attr:`AtoCore.state`).

Safety behaviour of the step: with no plan the train is held braked (the on-board ATO's
answer); past the stopping point, above the envelope or on a tracker input that is not a
number it brakes; at the platform a holding brake is applied.  The command rate is limited
by the jerk limit (Ke 2010: 1 m/s^3).
"""

from __future__ import annotations

import math
from typing import Any, Optional

import numpy as np

from metro_atc.core.ato.control_kernel import (CORE_STATE_FIELDS, STATE_FIELDS, STATE_INDEX,
                                               TRACKER_FUZZY, TRACKER_FUZZY_ABS, TRACKER_PI)
from metro_atc.core.ato.envelope import OperatingLimits, RunModel
from metro_atc.core.ato.fuzzy import FuzzyController
from metro_atc.core.ato.pi import PIController
from metro_atc.core.ato.planner import PLANNERS, Profile, plan_profile
from metro_atc.core.ato.registry import TRACKERS as TRACKER_REGISTRY
from metro_atc.core.ato.reference_curve import ProfileReference
from metro_atc.core.ato.tsr_plan import track_with_tsrs
from metro_atc.core.line.vehicle import Track, TrainParams

TRACKERS = TRACKER_REGISTRY.names
"""Tracker names accepted by :class:`AtoCore` (:data:`metro_atc.core.ato.registry.TRACKERS`)."""
MEMO_KEEP = 256
"""Newest entries kept per shared memo whose keys hold the train's mass or TSRs [-].

The run models, finished plans and per-mass / per-TSR pre-work tables of the trains of a
process (:class:`AtoCore`'s ``shared``) are keyed by the load-weigh mass at departure (and
the TSRs of the run): a new entry per departure with a new load, so over a service day they
would grow without bound (~900 MB by 11:00 for the Taipei fleet).  A memo: an entry dropped
(the oldest first) is computed again when asked for, the same value."""
APPROACH_JERK_SHARE = 0.8
"""Share of the jerk limit the approach bound counts on to take the surplus acceleration
off before the reference is reached (``control_kernel.approach_bound``) [-]."""


def memo_put(memo: dict[Any, Any], key: Any, value: Any, keep: int = MEMO_KEEP) -> None:
    """``memo[key] = value``, then drop the oldest entries beyond ``keep`` (:data:`MEMO_KEEP`)."""
    memo[key] = value
    while len(memo) > keep:
        del memo[next(iter(memo))]  # insertion order: the oldest first


def memo_slot(memo: dict[Any, Any], key: Any) -> dict[Any, Any]:
    """The sub-memo of ``key`` in ``memo`` (a new empty one put with :func:`memo_put`)."""
    got = memo.get(key)
    if got is None:
        got = {}
        memo_put(memo, key, got)
    return got


class AtoCore:
    """ATO of one train: planner (``PLANNERS``) + tracker (``TRACKERS``).

    Parameters: train, track; planner name; tracker name; control period [s]; limits:
    operating limits; planner_params: passed to :func:`metro_atc.core.ato.planner.plan_profile`
    (e.g. MMAS ``n_ants``, ``n_iterations``; FCTP ``coast_fraction``).
    """

    def __init__(self, train: TrainParams, track: Track, planner: str = "ectp",
                 tracker: str = "fuzzy", control_period_s: float = 0.1,
                 limits: Optional[OperatingLimits] = None,
                 shared: Optional[dict[str, Any]] = None, feedforward: bool = True,
                 **planner_params: Any) -> None:
        """Validate the names and build the tracker.

        ``shared``: a dict shared by the cores of one process (same train and track): the
        pre-work tables, run models and finished plans are then computed once per run and
        target instead of once per train (``shared["plan_store"]``, optional: a
        :class:`~metro_atc.core.ato.plan_store.PlanStore` shares the finished plans with the
        other processes of a run).  ``feedforward``: add the effort that holds the
        reference on the grade (Li n.d. Newton's law) to the tracker's output.
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
        self.feedforward = bool(feedforward)
        self.state = np.zeros(len(STATE_FIELDS))
        """The per-train state of the compiled step (``control_kernel.STATE_FIELDS``, flags
        0/1): this core's part (last time, effort, feedforward, arrival, standstill time, the
        tracker's error and integrated effort) and the on-board guards' (authority, speed
        peak, next stop, held speed).  Read and updated in place by every step."""
        self.last_reason = "no plan"
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
            else memo_slot(self._shared.setdefault("prework_mass", {}), self._mass_key)
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
            cache = memo_slot(self._shared.setdefault("prework_tsr", {}), key)
        run = self._runs.get(key)
        if run is None:
            track = track_with_tsrs(self.track, restrictions) if restrictions else self.track
            run = RunModel(self.train, track, x_start_m, x_stop_m, self.limits)
            memo_put(self._runs, key, run)
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
                memo_put(self._plans, memo, prof)
        if prof is None:
            prof = plan_profile(run, target_running_time_s, self.planner, cache, **params)
            memo_put(self._plans, memo, prof)
            if store is not None:
                store.put(memo, prof)
        self.run = run
        self.profile = prof
        b = float(run.brake_decel(run.length_m))  # at the platform (grade-aware option)
        self._ref = ProfileReference(prof.s_grid, prof.v_profile, run.length_m,
                                     tail_decel=b, creep_speed=0.5, tail_brake=0.5 * b)
        self._tail_brake = 0.5 * b
        ff = self.state[STATE_INDEX["ff"]]
        for f in CORE_STATE_FIELDS:  # a new run: no last step, zero effort, tracker at rest
            self.state[STATE_INDEX[f]] = 0.0
        self.state[STATE_INDEX["ff"]] = ff
        self.last_reason = "planned" if prof.feasible else prof.message
        return prof

    # ------------------------------------------------------------------ compiled step
    def kernel_constants(self) -> list[float]:
        """The controller constants of the compiled ATO step (``control_kernel_pack``).

        (period [s], swing [s], effort rate [1/s], brake share [-], approach jerk [m/s^3],
        feedforward 0/1, fuzzy e scale [m/s], d scale [m/s], gain [-], tracker, PI kp
        [1/(m/s)], ki [1/m], restriction lead [m], TSR speed margin [m/s], acceleration
        limit [m/s^2]); the tracker is ``control_kernel.TRACKER_*`` (its gains: e scale, d
        scale and gain of the fuzzy controller, kp and ki of the PI controller).
        """
        tr = self.tracker
        head = [self.period, self.swing_s, self._du_max_per_s, self._brake_share,
                self.approach_jerk, 1.0 if self.feedforward else 0.0]
        lim = self.limits
        tail = [lim.restriction_lead_m, lim.speed_margin_mps, lim.accel_max_mps2]
        if isinstance(tr, PIController):
            return head + [1.0, 1.0, 0.0, TRACKER_PI, tr.p.kp, tr.p.ki] + tail
        kind = TRACKER_FUZZY if tr.p.incremental else TRACKER_FUZZY_ABS
        return head + [tr.p.e_scale_mps, tr.p.d_scale_mps, tr.p.gain, kind, 0.0, 0.0] + tail

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

    @property
    def last_effort(self) -> float:
        """The last effort commanded (after rate limits and guards) [-1, 1]."""
        return float(self.state[STATE_INDEX["u"]])
