"""Run geometry and the operating speed envelope of one inter-station run (Ke 2010, Sec. 4-5).

A *run* goes from a departure point ``x_start`` to a stopping point ``x_stop`` (chainage [m]
on a :class:`~metro_atc.core.line.vehicle.Track`) in either direction.  Internally every ATO
algorithm works in the run coordinate ``s = |x - x_start|`` in [0, L] with the grade signed
in the direction of travel (positive = uphill for this train).

The envelope (Ke 2010, Sec. 4.1: "the track speed limits are modified in order to match the
requirement of different operation modes") is the highest speed a planner may command at
``s``:

- the permanent limit must hold for the whole train: for the front at ``s`` the limit is the
  minimum over ``[s - train length, s]`` (a restriction ends only when the rear clears it);
- constant-deceleration braking curves ``v^2 = v_t^2 + 2 b d`` to every lower limit ahead and
  to standstill at the stopping point (programmed station stopping, PSS: the speed command
  is calculated backwards from the dwell position; Ke 2010, Sec. 5 starts PSS 350 m before
  the stop, see :attr:`OperatingLimits.pss_distance_m`).

The jerk limit (Ke 2010: +-1.0 m/s^3) is not part of the envelope: with a_max = 1 m/s^2 a
full jerk-limited transition takes 1 s; it is enforced as a command-rate limit by the tracker
(:mod:`metro_atc.core.ato.controller`).  All quantities SI.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np
from numpy.typing import ArrayLike, NDArray

from metro_atc.core.line.vehicle import G_MPS2, Track, TrainParams, grade_force

FloatArray = NDArray[np.float64]

MODE_ACCEL = 0
"""Operation mode: accelerate (full traction at the traction level up to the speed code)."""
MODE_CRUISE = 1
"""Operation mode: cruise (hold the entry speed, capped at the speed code)."""
MODE_COAST = 2
"""Operation mode: coast (no effort; brakes only to respect the code / envelope)."""
MODE_BRAKE = 3
"""Operation mode: brake (following the envelope braking curve, used in profiles only)."""
MODE_NAMES = ("accelerate", "cruise", "coast", "brake")
"""Human-readable names of the mode integers."""


@dataclass(frozen=True)
class OperatingLimits:
    """Operating limits used by the planners (Ke 2010, Sec. 5).

    accel_max_mps2: net acceleration limit [m/s^2] (Ke 2010: 1.0).
    brake_decel_mps2: planning service deceleration of braking curves [m/s^2]; below the
    Ke 2010 limit of 1.0 so that the tracker keeps a braking margin (the Taipei preset can
    produce about 0.93 m/s^2 with its rotating-mass allowance).
    jerk_max_mps3: jerk limit [m/s^3] (Ke 2010: 1.0; enforced by the tracker).
    pss_distance_m: programmed station stopping starts this far before the stop [m]
    (Ke 2010, Sec. 5: 350 m, Taipei MRT practice).
    envelope_step_m: grid step of the tabulated envelope [m].
    grade_aware_braking: plan braking curves at the deceleration the service brake achieves
    on the grade: ``brake_decel_mps2`` less the downhill pull ``g |grade|`` of the
    steepest grade under the train, so the reserve of the service brake over the plan is the
    same on every grade (False: ``brake_decel_mps2`` everywhere, the Ke 2010 constant).
    speed_margin_mps: the profile stays this far below the civil limit (tracking margin,
    so the tracked speed never exceeds the limit) [m/s].
    restriction_lead_m: braking curves to a lower limit reach it this far before the
    restriction starts (the ATP's service-brake intervention looks ahead by its lead time
    and response distance) [m]; the stopping point has no lead.
    """

    accel_max_mps2: float = 1.0
    brake_decel_mps2: float = 0.8
    jerk_max_mps3: float = 1.0
    pss_distance_m: float = 350.0
    envelope_step_m: float = 1.0
    grade_aware_braking: bool = False
    speed_margin_mps: float = 0.0
    restriction_lead_m: float = 0.0


MIN_BRAKE_DECEL_MPS2 = 0.05
"""Floor of the planned braking deceleration on a steep descent [m/s^2]."""


class RunModel:
    """Geometry, grades, limits and the speed envelope of one run (run coordinate s [m]).

    Parameters
    ----------
    train: train parameters (mass [kg], Davis terms, traction curve).
    track: chainage-indexed grades and permanent speed limits.
    x_start_m, x_stop_m: departure and stopping chainage [m] (either direction, distinct).
    limits: operating limits (defaults: Ke 2010).
    """

    def __init__(self, train: TrainParams, track: Track, x_start_m: float, x_stop_m: float,
                 limits: Optional[OperatingLimits] = None) -> None:
        """Build the run; raises ValueError on a zero-length or non-finite run."""
        if not (np.isfinite(x_start_m) and np.isfinite(x_stop_m)) or x_stop_m == x_start_m:
            raise ValueError(f"invalid run {x_start_m!r} -> {x_stop_m!r}")
        self.train = train
        self.track = track
        self.limits = limits if limits is not None else OperatingLimits()
        self.x_start_m = float(x_start_m)
        self.x_stop_m = float(x_stop_m)
        self.direction = 1.0 if x_stop_m > x_start_m else -1.0
        self.length_m = abs(self.x_stop_m - self.x_start_m)
        self._build_grades()
        self._build_envelope()

    # ----------------------------------------------------------------- coordinates
    def chainage(self, s: ArrayLike) -> FloatArray:
        """Chainage x [m] of run coordinate s [m]."""
        return self.x_start_m + self.direction * np.asarray(s, dtype=float)

    def run_coordinate(self, x: ArrayLike) -> FloatArray:
        """Run coordinate s [m] of chainage x [m] (not clipped)."""
        return self.direction * (np.asarray(x, dtype=float) - self.x_start_m)

    # ----------------------------------------------------------------- grades
    def _pieces(self, starts: FloatArray, pad_m: float) -> FloatArray:
        """Breakpoints in run coordinates covering [-pad, L] for chainage segment starts."""
        s = self.direction * (np.asarray(starts, dtype=float) - self.x_start_m)
        s = s[(s > -pad_m) & (s < self.length_m)]
        return np.unique(np.concatenate(([-pad_m], s, [self.length_m])))

    def _build_grades(self) -> None:
        bp = self._pieces(self.track.grade_starts_m, 0.0)
        mid = 0.5 * (bp[:-1] + bp[1:])
        g = self.direction * self.track.grade_at(self.chainage(mid))
        self._grade_bp = bp
        self._grade_val = g.astype(float)
        fg = grade_force(self.train, g)
        self._fg_cum = np.concatenate(([0.0], np.cumsum(fg * np.diff(bp))))

    def grade(self, s: ArrayLike) -> FloatArray:
        """Grade in the direction of travel [-] (rise/run, + uphill) at s [m]."""
        i = np.searchsorted(self._grade_bp, np.asarray(s, dtype=float), side="right") - 1
        return self._grade_val[np.clip(i, 0, len(self._grade_val) - 1)]

    def grade_force_integral(self, s: ArrayLike) -> FloatArray:
        """Integral of the grade force from 0 to s [N m] (exact for piecewise grades)."""
        sa = np.clip(np.asarray(s, dtype=float), 0.0, self.length_m)
        return np.asarray(np.interp(sa, self._grade_bp, self._fg_cum), dtype=float)

    def mean_grade_force(self, s0: ArrayLike, s1: ArrayLike) -> FloatArray:
        """Mean grade force [N] over [s0, s1] (exact average of the piecewise grade)."""
        a = np.asarray(s0, dtype=float)
        b = np.asarray(s1, dtype=float)
        width = np.where(np.abs(b - a) > 1e-12, b - a, 1.0)
        mean = (self.grade_force_integral(b) - self.grade_force_integral(a)) / width
        return np.where(np.abs(b - a) > 1e-12, mean,
                        grade_force(self.train, self.grade(a)))

    def _tables(self) -> tuple[list[float], list[float], list[float], list[float], list[float]]:
        tab = self.__dict__.get("_scalar_tables")
        if tab is None:
            tab = (self._grade_bp.tolist(), self._grade_val.tolist(), self._fg_cum.tolist(),
                   self.s_env.tolist(), self.e_ceiling.tolist())
            self._scalar_tables = tab
        return tab

    def point_tables(self) -> tuple[list[float], ...]:
        """The tables of the one-point methods (for the compiled ATO step).

        (grade breakpoints [m], grades [-], grade-force integral [N m], envelope s [m],
        ceiling energy [m^2/s^2]).
        """
        return self._tables()

    # ----------------------------------------------------------------- limits
    def track_limit(self, s: ArrayLike) -> FloatArray:
        """Permanent track speed limit [m/s] at run coordinate s, capped by the train."""
        lim = self.track.limit_at(self.chainage(s))
        return np.minimum(lim, self.train.max_speed_mps)

    def static_limit(self, s: ArrayLike) -> FloatArray:
        """Limit [m/s] for the whole train with its front at s (min over [s - length, s])."""
        sa = np.asarray(s, dtype=float)
        pad = self.train.length_m
        bp = self._pieces(self.track.limit_starts_m, pad)
        mid = 0.5 * (bp[:-1] + bp[1:])
        lim = self.track_limit(mid)
        out = np.full(sa.shape, np.inf)
        for a, b, v in zip(bp[:-1], bp[1:], lim):
            inside = (sa >= a) & (sa < b + pad)
            out = np.where(inside, np.minimum(out, v), out)
        return np.where(np.isfinite(out), out, self.train.max_speed_mps)

    def brake_decel(self, s: ArrayLike) -> FloatArray:
        """Planned braking deceleration [m/s^2] with the front at s [m] (grade-aware option).

        ``brake_decel_mps2 + g min(grade, 0)`` with the steepest grade under the train
        (front at s, rear at s - length), floored at ``MIN_BRAKE_DECEL_MPS2``.
        """
        sa = np.asarray(s, dtype=float)
        b = self.limits.brake_decel_mps2
        if not self.limits.grade_aware_braking:
            return np.full(sa.shape, b)
        g_min = np.minimum(self.grade(sa), self.grade(sa - self.train.length_m))
        mid = self.grade(sa - 0.5 * self.train.length_m)
        g_min = np.minimum(g_min, mid)
        return np.asarray(np.maximum(b + G_MPS2 * np.minimum(g_min, 0.0),
                                     MIN_BRAKE_DECEL_MPS2), dtype=float)

    def _build_envelope(self) -> None:
        lim = self.limits
        n = max(2, int(np.ceil(self.length_m / lim.envelope_step_m)))
        s = np.linspace(0.0, self.length_m, n + 1)
        v_lim = self.static_limit(s)
        v_lim = np.maximum(v_lim - lim.speed_margin_mps, 0.5 * v_lim)
        e_static = 0.5 * v_lim ** 2
        if lim.restriction_lead_m > 0.0:
            # a lower limit applies restriction_lead_m before it starts (window min ahead)
            k = int(np.ceil(lim.restriction_lead_m / (s[1] - s[0])))
            pad = np.concatenate((e_static, np.full(k, e_static[-1])))
            win = np.lib.stride_tricks.sliding_window_view(pad, k + 1)
            e_static = win.min(axis=1)
        e_static[-1] = 0.0
        if not lim.grade_aware_braking:
            b = lim.brake_decel_mps2
            # e_c(s_k) = min_{j>=k} (e_s(s_j) + b (s_j - s_k)): reverse cumulative minimum
            key = e_static + b * s
            e_c = np.minimum.accumulate(key[::-1])[::-1] - b * s
        else:
            # e_c(s_k) = min(e_s(s_k), e_c(s_{k+1}) + b(s_k) ds): braking at the achievable
            # deceleration of each grid cell (exact for the piecewise-constant b)
            bb = (self.brake_decel(0.5 * (s[:-1] + s[1:])) * np.diff(s)).tolist()
            ec = e_static.tolist()
            for k in range(n - 1, -1, -1):
                nxt = ec[k + 1] + bb[k]
                if nxt < ec[k]:
                    ec[k] = nxt
            e_c = np.asarray(ec, dtype=float)
        self.s_env = s
        self.e_static = e_static
        self.e_ceiling = np.maximum(e_c, 0.0)

    def ceiling_e(self, s: ArrayLike) -> FloatArray:
        """Envelope as kinetic energy per unit mass e = v^2/2 [m^2/s^2] at s [m]."""
        return np.asarray(np.interp(np.asarray(s, dtype=float), self.s_env, self.e_ceiling),
                          dtype=float)

    def ceiling(self, s: ArrayLike) -> FloatArray:
        """Envelope speed [m/s] at s [m] (limits, braking curves, PSS stopping curve)."""
        return np.sqrt(2.0 * self.ceiling_e(s))

    @property
    def pss_start_s(self) -> float:
        """Run coordinate [m] where programmed station stopping starts (Ke 2010: 350 m)."""
        return max(0.0, self.length_m - self.limits.pss_distance_m)


def profile_energy_time(run: RunModel, s: ArrayLike, v: ArrayLike,
                        coast_mask: Optional[ArrayLike] = None
                        ) -> tuple[float, float, FloatArray]:
    """Traction energy [J], running time [s] and effort [N] of a speed-vs-distance profile.

    The profile is piecewise constant-acceleration between samples (s_k [m], v_k [m/s]): the
    effort on interval k is ``F = M_eff (v_{k+1}^2 - v_k^2) / (2 ds) + F_r(v_mean) + F_g``
    (Newton's law, Li n.d.), the time ``2 ds / (v_k + v_{k+1})`` and the traction energy
    ``max(F, 0) ds`` (mechanical energy at the wheel; braking is not credited).  Intervals
    flagged in ``coast_mask`` count zero energy (no effort is applied there).
    """
    from metro_atc.core.line.vehicle import resistance_force

    sa = np.asarray(s, dtype=float)
    va = np.maximum(np.asarray(v, dtype=float), 0.0)
    ds = np.diff(sa)
    fg = run.mean_grade_force(sa[:-1], sa[1:])
    vm = 0.5 * (va[:-1] + va[1:])
    force = run.train.effective_mass_kg * (va[1:] ** 2 - va[:-1] ** 2) / (2.0 * ds) \
        + resistance_force(run.train, vm) + fg
    work = np.maximum(force, 0.0) * ds
    if coast_mask is not None:
        work = np.where(np.asarray(coast_mask, dtype=bool), 0.0, work)
    with np.errstate(divide="ignore"):
        dt = np.where(va[:-1] + va[1:] > 0.0, 2.0 * ds / (va[:-1] + va[1:] + 1e-300), np.inf)
    return float(np.sum(work)), float(np.sum(dt)), force
