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

import math
from dataclasses import dataclass
from typing import Any, Optional, Sequence

import numpy as np

from metro_atc.core.ato.controller import AtoCore
from metro_atc.core.ato.envelope import OperatingLimits
from metro_atc.core.ato.planner import Profile
from metro_atc.core.plant.vehicle import G_MPS2, Track, TrainParams

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
LEGACY = False
"""Effort per m/s of speed above a guard curve [1/(m/s)]."""


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


class OnboardAto:
    """Per-train ATO decision logic (module docstring).

    Parameters: train, track; ``stations_m`` stop-point chainages [m]; planner / tracker
    names and extra planner parameters (:class:`AtoCore`); ``control_period_s`` [s];
    ``limits`` planning limits; ``shared`` cache shared by the trains of a process;
    ``tsrs`` the temporary speed restrictions of the scenario.
    """

    def __init__(self, train: TrainParams, track: Track, stations_m: Sequence[float],
                 planner: str = "ectp", tracker: str = "fuzzy", control_period_s: float = 0.25,
                 limits: Optional[OperatingLimits] = None,
                 shared: Optional[dict[str, Any]] = None,
                 tsrs: Sequence[TsrZone] = (), **planner_params: Any) -> None:
        """Build the :class:`AtoCore` and the guard state."""
        self.core = AtoCore(train, track, planner=planner, tracker=tracker,
                            control_period_s=control_period_s, limits=limits, shared=shared,
                            **planner_params)
        self.train = train
        self.track = track
        self.stations = np.asarray(stations_m, dtype=float)
        self.tsrs = tuple(tsrs)
        self.commands: dict[int, tuple[float, float]] = {}
        self.planned_from = -1
        self.cur_station = -1
        self.last_mode = -1

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

    def plan(self, st: int, target_s: float, stamp_s: float, late: bool = False) -> PlanEvent:
        """Plan the run from station ``st`` to ``st + 1``."""
        x0, x1 = float(self.stations[st]), float(self.stations[st + 1])
        prof = self.core.plan(x0, x1, target_s)
        self.planned_from = st
        return PlanEvent(st, float(target_s), prof, float(stamp_s), late)

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
        if departing and 0 <= cur == nxt - 1:
            # plan the run definitively at departure from the state (deterministic in the
            # lockstep): the ATS target fixes the arrival (departure + running time), so a
            # late departure shortens the target (down to flat-out); rounded to 1 s when
            # late so the trains of a process share plans
            target = float(s["target_running_time_s"])
            late = float(s["t_s"]) - float(s["departure_time_s"])
            if math.isfinite(late) and late > 1.0:
                target = float(max(round(target - late), 1.0))
            planned = self.plan(cur, target, float(s["t_s"]), late=late > 1.0)
        elif self.planned_from != cur and 0 <= cur == nxt - 1:
            # started mid-run (e.g. the node was restarted): plan from here
            planned = self.plan(cur, float(s["target_running_time_s"]), float(s["t_s"]))
        u = float(self.core.command(s["t_s"], s["x_m"], s["v_mps"]))
        u = min(u, self.guard(s))
        mode = MODE_ACCELERATE if u > 0.05 else (MODE_BRAKE if u < -0.05 else MODE_COAST)
        return u, mode, planned

    def _brake_capability(self, x_from: float, x_to: float) -> float:
        """Service deceleration [m/s^2] achievable on the steepest downhill of [x_from, x_to].

        Full service brake minus the grade's pull (resistance neglected: conservative).
        """
        a, b = (x_from, x_to) if x_from <= x_to else (x_to, x_from)
        xs = np.linspace(a - self.train.length_m, max(b, a) + 1.0, 64)
        g = float(np.min(self.track.grade_at(xs)))
        return max(self.train.max_service_brake_mps2 + G_MPS2 * min(g, 0.0), 0.05)

    def legacy_guard(self, s: dict[str, Any]) -> float:
        """TEMPORARY: the node's guard before this branch (baseline measurement)."""
        from metro_atc.core.simple_ato import FlatOutTracker
        g = FlatOutTracker()
        bound = 1.0
        ma = s["movement_authority_m"]
        nxt = s["next_station"]
        x_stop = float(self.stations[nxt]) if 0 <= nxt < len(self.stations) else math.inf
        if math.isfinite(ma) and ma - g.authority_margin_m < x_stop:
            limit = float(self.track.limit_at(s["x_m"]))
            bound = min(bound, g.command(s["x_m"], s["v_mps"], ma, limit, ma))
        d = x_stop - s["x_m"]
        if 0.0 < d < 400.0 and s["v_mps"] > 0.3:
            a_req = s["v_mps"] ** 2 / (2.0 * max(d - 0.15, 0.05))
            if a_req > 0.85 * self.core.train.max_service_brake_mps2:
                bound = min(bound, -min(1.0, a_req / self.core.train.max_service_brake_mps2))
        sup = s["supervision_speed_mps"]
        if math.isfinite(sup):
            over = s["v_mps"] - (sup - 0.5)
            if over > 0.0:
                bound = min(bound, -min(1.0, g.gain * over))
        return bound

    def guard(self, s: dict[str, Any]) -> float:
        """Upper bound on the effort from authority, TSRs, the stop and supervision."""
        if LEGACY:
            return self.legacy_guard(s)
        bound = 1.0
        x, v = float(s["x_m"]), float(s["v_mps"])
        nxt = int(s["next_station"])
        x_stop = float(self.stations[nxt]) if 0 <= nxt < len(self.stations) else math.inf
        b_ach = self._brake_capability(x, x_stop if math.isfinite(x_stop) else x + 500.0)
        ma = float(s["movement_authority_m"])
        if math.isfinite(ma) and ma - AUTHORITY_MARGIN_M < x_stop:
            bound = min(bound, self._curve_bound(v, ma - AUTHORITY_MARGIN_M - x, 0.0,
                                                 0.7 * b_ach))
        for z in self.tsrs:
            if not (z.known_s <= s["t_s"] < z.to_s) or x - self.train.length_m >= z.end_m:
                continue
            d = z.start_m - x
            bound = min(bound, self._curve_bound(v, d, z.limit_mps, 0.7 * b_ach))
        d = x_stop - x
        if 0.0 < d < 400.0 and v > 0.3:
            # stopping guard: above the curve that ends at the stop point (late, e.g. after
            # an authority restriction released near the platform) brake with the
            # deceleration that ends there
            a_req = v * v / (2.0 * max(d - 0.15, 0.05))
            if a_req > STOP_GUARD * b_ach:
                bound = min(bound, -min(1.0, a_req / self.train.max_service_brake_mps2
                                        + (self.train.max_service_brake_mps2 - b_ach)
                                        / self.train.max_service_brake_mps2))
        sup = float(s["supervision_speed_mps"])
        if math.isfinite(sup):
            over = v - (sup - SPEED_MARGIN_MPS)
            if over > 0.0:
                bound = min(bound, -min(1.0, GUARD_GAIN * over))
        return bound

    def _curve_bound(self, v: float, dist_m: float, target_mps: float, b: float) -> float:
        """Effort bound to stay under ``v^2 = target^2 + 2 b d`` (speed-error feedback)."""
        r = math.sqrt(max(target_mps * target_mps + 2.0 * b * max(dist_m, 0.0), 0.0))
        if dist_m <= 0.0:
            r = target_mps
        if v <= r:
            return 1.0 if r - v > 0.5 else GUARD_GAIN * (r - v)
        return -min(1.0, b / self.train.max_service_brake_mps2 + GUARD_GAIN * (v - r))


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
