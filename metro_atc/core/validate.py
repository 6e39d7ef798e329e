"""Plausibility rules for every message a node receives (ROS-free).

The conversion layer (:mod:`metro_atc.nodes.conversions`) turns a message into plain
values and calls these rules; a violation raises :class:`Rejected`, whose ``kind`` names
the rule (``step``, ``stamp``, ``position`` ...).  Nodes count rejections per kind in a
:class:`Rejections` and log them rate-limited.  The rules are:

- **type**: finite numbers where a number is meant (NaN only where the message defines it);
- **range**: each quantity within what the line can produce (:class:`Bounds`, from the
  scenario: chainage within the gridded line, speed below 150 m/s, times within the run
  horizon, station indices on the line, mode codes defined);
- **lockstep**: a command is applied only for the current step ``k`` (``k - 1`` is a stale
  duplicate, anything else is rejected); a state is taken only for the step after the last
  one (or the same step again: a re-send); :class:`StepWindow` re-synchronises after a
  consistent run of states (a restarted simulator);
- **stamp**: every message of the graph carries its simulation time twice (a state's
  ``header.stamp`` is ``step x control period``, a command's is its state's stamp, a
  departure command's is its departure time, an event's is its actual time); a message
  whose two copies disagree did not come from the graph.

These are plausibility checks, not authentication: a message forged with consistent values
is indistinguishable from a real one without DDS Security (see the README).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Optional

__all__ = ["Rejected", "Rejections", "Bounds", "bounds_for", "StepWindow", "check_finite",
           "check_range", "check_time", "check_stamp", "STAMP_TOL_S"]

STAMP_TOL_S = 1e-6
"""Largest disagreement of a message's two copies of its simulation time [s] (rounding of
``builtin_interfaces/Time`` to the nanosecond and of the accumulated clock)."""


class Rejected(ValueError):
    """A value failed a rule; ``kind`` names the rule, the text names the field (one line)."""

    def __init__(self, kind: str, text: str) -> None:
        """Remember the kind."""
        super().__init__(text)
        self.kind = kind


class Rejections:
    """Counters of rejected messages per kind (public: published by the nodes).

    :meth:`add` also rate-limits the log per kind: the first rejection of a kind is always
    logged, then at most one per ``log_period_s`` of that kind (a flood of one kind cannot
    hide another; rclpy's ``throttle_duration_sec`` throttles per call site, not per kind).
    """

    def __init__(self, log_period_s: float = 1.0) -> None:
        """No rejection yet."""
        self.counts: dict[str, int] = {}
        self.log_period_s = float(log_period_s)
        self._logged: dict[str, float] = {}

    def add(self, kind: str, now_s: float = math.inf) -> bool:
        """Count one rejection of ``kind``; True if it should be logged (per-kind limit).

        ``now_s``: a monotonic time [s]; the default logs only the first of each kind.
        """
        self.counts[kind] = self.counts.get(kind, 0) + 1
        last = self._logged.get(kind)
        if last is None or now_s - last >= self.log_period_s:
            self._logged[kind] = now_s
            return True
        return False

    def note(self, what: str, exc: Rejected, now_s: float) -> str | None:
        """Count ``exc`` (its kind); the one-line log text, or None inside the rate limit.

        ``what``: the input rejected (e.g. ``state``); ``now_s``: a monotonic time [s].
        """
        if not self.add(exc.kind, now_s):
            return None
        return f"rejected {what} ({exc.kind}): {exc} [rejected so far: {self.summary()}]"

    @property
    def total(self) -> int:
        """All rejections."""
        return sum(self.counts.values())

    def as_dict(self) -> dict[str, int]:
        """A copy of the counters (sorted by kind)."""
        return dict(sorted(self.counts.items()))

    def summary(self) -> str:
        """``kind n, kind n`` (every kind seen so far)."""
        return ", ".join(f"{k} {v}" for k, v in sorted(self.counts.items())) or "none"


@dataclasses.dataclass(frozen=True)
class Bounds:
    """What the line of a scenario can produce (plausibility ranges of message fields)."""

    n_stations: int
    """Stations on the line."""
    x_min_m: float
    """Smallest chainage a train front can have (the plant grid starts later) [m]."""
    x_max_m: float
    """Largest chainage (tail track, parking; the grid ends earlier) [m]."""
    horizon_s: float
    """Latest simulation time of the run, with margin [s]."""
    control_period_s: float
    """Lockstep control period [s]."""
    t_first_s: float = 0.0
    """First timetable departure: no departure is commanded before it [s]."""
    v_max_mps: float = 150.0
    """Largest plausible speed (above every rolling stock of the schema) [m/s]."""
    a_max_mps2: float = 20.0
    """Largest plausible |acceleration| [m/s^2]."""
    n_modes: int = 7
    """TrainState.MODE_* codes 0..n_modes-1."""


def bounds_for(scn: Any) -> Bounds:
    """Bounds of a loaded :class:`~metro_atc.core.line.scenario.Scenario`.

    Chainage: the plant grids from the first stop minus a train length (<= 600 m) and
    500 m to the tail track plus 200 m; 1 km of margin on both sides.  Times: the
    scenario's hard stop plus an hour (a regulator may hold trains beyond the timetable);
    departures not before the timetable's first one.
    """
    st = scn.line.stations
    return Bounds(n_stations=len(st),
                  x_min_m=float(st[0].position_m) - 2100.0,
                  x_max_m=float(st[-1].position_m) + float(scn.line.tail_track_m) + 1300.0,
                  horizon_s=float(scn.sim.duration_s) + 3600.0,
                  control_period_s=float(scn.sim.control_period_s),
                  t_first_s=float(scn.timetable.first_departure_s))


def check_finite(name: str, value: float) -> float:
    """``value`` as float, or :class:`Rejected` (kind ``nan``) if not finite."""
    v = float(value)
    if not math.isfinite(v):
        raise Rejected("nan", f"{name} is not finite ({value})")
    return v


def check_range(name: str, value: float, lo: float, hi: float, kind: str = "range",
                nan_ok: bool = False) -> float:
    """``value`` in [lo, hi] (NaN allowed only with ``nan_ok``), else :class:`Rejected`."""
    v = float(value)
    if math.isnan(v):
        if nan_ok:
            return v
        raise Rejected("nan", f"{name} is not finite (nan)")
    if not lo <= v <= hi:
        raise Rejected(kind, f"{name}={v:.6g} outside [{lo:.6g}, {hi:.6g}]")
    return v


def check_time(name: str, value: float, b: Bounds, nan_ok: bool = False) -> float:
    """A simulation time in [0, horizon] (kind ``time``)."""
    return check_range(name, value, 0.0, b.horizon_s, "time", nan_ok)


def check_index(name: str, value: int, lo: int, hi: int, kind: str = "index") -> int:
    """An integer index in [lo, hi] (kind ``index`` unless given)."""
    v = int(value)
    if not lo <= v <= hi:
        raise Rejected(kind, f"{name}={v} outside [{lo}, {hi}]")
    return v


def check_stamp(name: str, stamp_s: float, expected_s: float) -> None:
    """The header stamp agrees with the message's own time (kind ``stamp``)."""
    if not abs(stamp_s - expected_s) <= STAMP_TOL_S * max(1.0, abs(expected_s)):
        raise Rejected("stamp", f"{name}: header stamp {stamp_s:.9g} s disagrees with "
                       f"{expected_s:.9g} s")


class StepWindow:
    """Lockstep step indices a receiver of states accepts (ROS-free).

    :meth:`accept` returns ``"next"`` for the step after the last accepted one (or the
    first ever), ``"again"`` for the last accepted step (a re-send), and raises
    :class:`Rejected` (kind ``step``) otherwise.  A sender that really jumped (a restarted
    simulator, possibly behind) is followed after ``resync`` consecutive consistent states
    outside the window (each the same step again or the next one: a lockstep simulator
    re-sends the step it waits on); a random step never builds such a run.
    """

    def __init__(self, resync: int = 4) -> None:
        """Nothing accepted yet."""
        self.last: Optional[int] = None
        self.resync = int(resync)
        self._cand: Optional[int] = None
        self._cand_n = 0

    def accept(self, step: int, name: str = "step") -> str:
        """Classify ``step`` (see class docstring); update the window."""
        s = int(step)
        if self.last is None or s == self.last + 1:
            self.last = s
            self._cand, self._cand_n = None, 0
            return "next"
        if s == self.last:
            return "again"
        if self._cand is not None and s in (self._cand, self._cand + 1):
            self._cand_n += 1  # the next step, or the same one re-sent (a waiting lockstep)
        else:
            self._cand_n = 1
        self._cand = s
        if self._cand_n >= self.resync:
            self.last = s
            self._cand, self._cand_n = None, 0
            return "next"
        raise Rejected("step", f"{name}={s} is not the lockstep step {self.last} or "
                       f"{self.last + 1}")
