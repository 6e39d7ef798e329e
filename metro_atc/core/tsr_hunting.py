"""Speed minima of a train through a TSR approach, and which of them are hunting.

A train approaching a temporary speed restriction (TSR) brakes once to the restricted speed,
holds it through the zone and accelerates out of it: one speed minimum.  Hunting is the ATO
braking and releasing again and again on the approach (stop-start, "inside a
30 km/h TSR on a descent the speed hunts between 0 and 30 km/h about ten times").  Inside
the watched window other things legitimately make a speed minimum, and they are not hunting:

- a **lower permanent civil limit** the train rides (the minimum is within
  ``PERMANENT_BAND_MPS`` of the permanent limit over the whole train, ``LIMIT_REACH_M``
  either side): e.g. a 40 km/h curve limit before a 25 km/h TSR, 35 km/h there, then
  the TSR;
- a **station stop** (standstill within ``STATION_TOLERANCE_M`` of a stopping point);
- a **stop or hold forced by the incident**: the broken-down train itself, or a train whose
  end of movement authority (the train ahead) is close enough to constrain it (closer than
  the distance to stop at ``HOLD_DECEL_MPS2`` plus ``HOLD_MARGIN_M``).

:class:`SpeedMinima` reduces one train's speed samples through one approach to its turning
points with a hysteresis of ``HUNT_HYSTERESIS_MPS`` and counts the minima (``minima``) and
those not explained by any of the above (``hunting``: at most one per approach, the TSR's
own).  :func:`explain` is the per-sample explanation (SI units throughout).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

HUNT_HYSTERESIS_MPS = 0.5
"""A speed minimum counts when the speed rose by this much after it [m/s]."""
PERMANENT_BAND_MPS = 1.5
"""A minimum this close to (or above) the permanent civil limit over the train is the train
riding that limit [m/s] (the ATO tracks ``SPEED_MARGIN_MPS`` = 0.5 m/s below a limit and
undershoots it by up to ~0.6 m/s when the braking to it releases; gen_0006_inc: 36 km/h
under a 40 km/h limit)."""
LIMIT_REACH_M = 30.0
"""The permanent limit explaining a minimum is the lowest from this far ahead of the front to
this far behind the rear [m]: braking to a lower limit ends at (and may undershoot just
before) its start (gen_0006_inc: 35.4 km/h 12 m before a 40 km/h limit, then ~38 km/h in
it), and the ATO accelerates only once the rear has cleared it, the speed still falling
while the traction builds up (jerk-limited, ~1 s)."""
STANDSTILL_MPS = 0.3
"""Speed below which a train is at a standstill [m/s]."""
STATION_TOLERANCE_M = 2.0
"""A standstill this close to a stopping point is a station stop [m] (the plant takes any
standstill within +-1 m as the arrival)."""
HOLD_DECEL_MPS2 = 0.5
"""A train is held by its movement authority when it would have to brake at about this
deceleration (or harder) to stop ``HOLD_MARGIN_M`` short of its end [m/s^2]."""
HOLD_MARGIN_M = 50.0
"""Distance [m] added to the stopping distance for the authority to count as constraining
(the ATO aims 10 m short of it, its curve starts a few tens of metres earlier)."""

PERMANENT = "permanent_limit"
STATION = "station_stop"
FORCED = "forced_stop"


def explain(v_mps: float, permanent_limit_mps: float, station_dist_m: float,
            broken: bool, authority_dist_m: float) -> str:
    """Why a train at this sample may be at a speed minimum ('' when nothing explains it).

    Args:
        v_mps: speed [m/s].
        permanent_limit_mps: lowest permanent civil limit over the whole train and
            ``LIMIT_REACH_M`` beyond it on both sides [m/s] (without TSRs and without the
            ATP's overspeed margin).
        station_dist_m: distance from the front to the nearest stopping point [m].
        broken: the train is broken down (the incident).
        authority_dist_m: distance from the front to the end of its movement authority [m]
            (inf when nothing is ahead).
    """
    if broken:
        return FORCED
    if v_mps < STANDSTILL_MPS and abs(station_dist_m) <= STATION_TOLERANCE_M:
        return STATION
    if authority_dist_m < v_mps * v_mps / (2.0 * HOLD_DECEL_MPS2) + HOLD_MARGIN_M:
        return FORCED
    if v_mps >= permanent_limit_mps - PERMANENT_BAND_MPS:
        return PERMANENT
    return ""


@dataclass
class SpeedMinima:
    """Zig-zag of one train's speed through one TSR approach (module docstring).

    Feed every sample with :meth:`feed` (speed [m/s] and its :func:`explain`); read
    ``minima`` (all) and ``hunting`` (unexplained) after :meth:`close`.
    """

    direction: int = 0
    extreme: float = math.nan
    cause: str = ""
    minima: int = 0
    hunting: int = 0
    causes: dict[str, int] = field(default_factory=dict)

    def feed(self, v_mps: float, cause: str = "") -> None:
        """One speed sample [m/s] and its explanation ('' for none)."""
        v = float(v_mps)
        if math.isnan(self.extreme):
            self.extreme = v
            return
        if self.direction >= 0:
            if v > self.extreme:
                self.extreme = v
            elif v < self.extreme - HUNT_HYSTERESIS_MPS:
                self.direction, self.extreme, self.cause = -1, v, cause
        elif v < self.extreme:
            self.extreme, self.cause = v, cause
        elif v <= self.extreme + 1e-9:
            # a plateau at the minimum (a standstill): any explained sample explains it
            self.cause = self.cause or cause
        elif v > self.extreme + HUNT_HYSTERESIS_MPS:
            self._count()
            self.direction, self.extreme = 1, v

    def close(self) -> "SpeedMinima":
        """End of the approach: a minimum still being reached counts too; returns self."""
        if self.direction < 0:
            self._count()
            self.direction = 0
        return self

    def _count(self) -> None:
        self.minima += 1
        if self.cause:
            self.causes[self.cause] = self.causes.get(self.cause, 0) + 1
        else:
            self.hunting += 1
