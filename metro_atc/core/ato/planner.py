"""One planning interface over every planner: MMAS, DP, FOTP, FCTP, ECTP, ACTP-TC, ACTP-C.

:func:`plan_profile` returns a :class:`Profile`: section boundaries (chainage [m]), per-section
operation mode (MODE_* ints: accelerate / cruise / coast / brake) and speed code [m/s], the
first coasting point, predicted running time [s] and traction energy [J], the planned speed
profile, a ``feasible`` flag and a message.  The planner meets the running-time target or --
when the target is below the physical minimum (or not a finite positive number) -- returns
the fastest feasible (flat-out) profile with ``feasible=False`` and says why.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any, Optional

import numpy as np
from numpy.typing import NDArray

from metro_atc.core.ato import coasting
from metro_atc.core.ato.dp import build_dp_tables, solve_dp
from metro_atc.core.ato.envelope import (MODE_ACCEL, MODE_BRAKE, MODE_COAST, MODE_CRUISE,
                                         RunModel, profile_energy_time)
from metro_atc.core.ato.mmas import MmasParams, solve_mmas
from metro_atc.core.ato.registry import PLANNERS as PLANNER_REGISTRY
from metro_atc.core.ato.sections import build_section_tables
from metro_atc.core.laws import G_MPS2

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

PLANNERS = PLANNER_REGISTRY.names
"""Planner names accepted by :func:`plan_profile` (:mod:`metro_atc.core.ato.registry`)."""


@dataclass
class Profile:
    """A planned inter-station profile (SI; positions are chainage [m]).

    section_bounds_m (n+1,), modes (n,), codes_mps (n,): the speed-code profile;
    coast_point_m: first coasting position (nan if none); running_time_s / energy_j:
    prediction; feasible / message: target met or the reason for the fallback;
    s_grid / v_profile: planned speed [m/s] over the run coordinate [m] (0 = departure);
    compute_s: planning wall time [s].
    """

    planner: str
    x_start_m: float
    x_stop_m: float
    target_running_time_s: float
    section_bounds_m: FloatArray
    modes: IntArray
    codes_mps: FloatArray
    coast_point_m: float
    running_time_s: float
    energy_j: float
    feasible: bool
    message: str
    s_grid: FloatArray = field(default_factory=lambda: np.zeros(0))
    v_profile: FloatArray = field(default_factory=lambda: np.zeros(0))
    compute_s: float = 0.0

    def speed_at(self, x_m: float) -> float:
        """Planned speed [m/s] at chainage x_m."""
        d = 1.0 if self.x_stop_m >= self.x_start_m else -1.0
        return float(np.interp(d * (x_m - self.x_start_m), self.s_grid, self.v_profile))


def derive_sections(run: RunModel, s: FloatArray, v: FloatArray
                    ) -> tuple[FloatArray, IntArray, FloatArray, float]:
    """Sections of constant mode from a speed profile: (bounds s, modes, codes, coast s).

    Mode per interval from the effort (profile_energy_time): traction with rising speed ->
    accelerate, traction at ~constant speed -> cruise, |effort| < 0.5 % of the weight ->
    coast, negative effort -> brake.  Codes are the highest speed in each section.
    """
    _, _, force = profile_energy_time(run, s, v)
    dv = np.diff(v)
    tol = 0.005 * run.train.mass_kg * G_MPS2
    mode = np.where(np.abs(force) < tol, MODE_COAST,
                    np.where(force < 0.0, MODE_BRAKE,
                             np.where(dv > 1e-3, MODE_ACCEL, MODE_CRUISE)))
    change = np.nonzero(np.diff(mode) != 0)[0] + 1
    starts = np.concatenate(([0], change))
    ends = np.concatenate((change, [mode.size]))
    bounds = np.concatenate((s[starts], [s[-1]]))
    codes = np.array([np.max(v[a:b + 1]) for a, b in zip(starts, ends)])
    coast = np.nonzero(mode == MODE_COAST)[0]
    return bounds, mode[starts].astype(np.int64), codes, (float(s[coast[0]]) if coast.size
                                                          else math.nan)


def _profile(run: RunModel, planner: str, target: float, s: FloatArray, v: FloatArray,
             time_s: float, energy_j: float, feasible: bool, message: str, t0: float,
             sections: Optional[tuple[FloatArray, IntArray, FloatArray, float]] = None
             ) -> Profile:
    b, m, c, yc = sections if sections is not None else derive_sections(run, s, v)
    return Profile(planner=planner, x_start_m=run.x_start_m, x_stop_m=run.x_stop_m,
                   target_running_time_s=target, section_bounds_m=run.chainage(b),
                   modes=m, codes_mps=c,
                   coast_point_m=float(run.chainage(yc)) if np.isfinite(yc) else math.nan,
                   running_time_s=float(time_s), energy_j=float(energy_j),
                   feasible=bool(feasible), message=message, s_grid=np.asarray(s, dtype=float),
                   v_profile=np.asarray(v, dtype=float),
                   compute_s=time.perf_counter() - t0)


def plan_profile(run: RunModel, target_running_time_s: float, planner: str = "ectp",
                 cache: Optional[dict[Any, Any]] = None, **params: Any) -> Profile:
    """Plan the run for the target running time [s] with the named planner.

    ``cache`` (a dict kept by the caller) stores pre-work tables (MMAS sections, DP grid)
    per run so that re-planning the same run for a new target is fast.  ``params``:
    MMAS: ``n_sections``, ``codes_kmh``, and any :class:`MmasParams` field;
    DP: ``ds_m``, ``de_m2s2``; FCTP: ``coast_fraction``; FCTP/ECTP: ``delta``;
    ACTP: ``iterations``, ``seed``.
    """
    t0 = time.perf_counter()
    name = planner.lower().replace("-", "_")
    if name not in PLANNERS:
        raise ValueError(f"unknown planner {planner!r}; expected one of {PLANNERS}")
    h = float(params.get("h_m", 2.0))
    fk = ("fotp", run.x_start_m, run.x_stop_m, h)
    fast = cache.get(fk) if cache is not None else None
    if fast is None:
        fast = coasting.fotp(run, math.inf, h)
        if cache is not None:
            cache[fk] = fast
    target = float(target_running_time_s) if target_running_time_s is not None else math.nan
    if not (math.isfinite(target) and target > 0.0):
        return _profile(run, name, target, fast.s_grid, fast.v_profile, fast.time_s,
                        fast.energy_j, False,
                        f"invalid running-time target {target_running_time_s!r}: "
                        "flat-out (fastest) profile", t0)
    if target < fast.time_s - 1e-6:
        return _profile(run, name, target, fast.s_grid, fast.v_profile, fast.time_s,
                        fast.energy_j, False,
                        f"target {target:.1f} s below the minimum running time "
                        f"{fast.time_s:.1f} s: flat-out (fastest) profile", t0)
    plan = PLANNER_REGISTRY[name].load()
    prof: Profile = plan(run, name, target, fast, cache, params, t0)
    return prof


# Planner functions of :data:`metro_atc.core.ato.registry.PLANNERS`: ``run``, the planner
# ``name``, a finite positive ``target`` [s] not below the flat-out time, the flat-out
# profile ``fast``, the caller's ``cache``, the planner ``params`` of :func:`plan_profile`
# and its start time ``t0`` (perf_counter) -> the Profile.

def plan_fotp(run: RunModel, name: str, target: float, fast: Any,
              cache: Optional[dict[Any, Any]], params: dict[str, Any], t0: float) -> Profile:
    """FOTP: the flat-out profile (it does not aim at the target)."""
    return _profile(run, name, target, fast.s_grid, fast.v_profile, fast.time_s,
                    fast.energy_j, True, "", t0)


def plan_coasting(run: RunModel, name: str, target: float, fast: Any,
                  cache: Optional[dict[Any, Any]], params: dict[str, Any], t0: float
                  ) -> Profile:
    """FCTP, ECTP, ACTP-TC, ACTP-C: the coasting control systems of :mod:`coasting`."""
    h = float(params.get("h_m", 2.0))
    if name == "fctp":
        res = coasting.fctp(run, target, float(params.get("coast_fraction", 0.5)),
                            float(params.get("delta", coasting.LEVEL_II)), h)
    elif name == "ectp":
        res = coasting.ectp(run, target, float(params.get("delta", coasting.LEVEL_II)), h)
    elif name in ("actp_tc", "actp_c"):
        ap = coasting.ActpParams(iterations=int(params.get("iterations", 400)),
                                 seed=int(params.get("seed", 1)))
        res = coasting.actp(run, target, name == "actp_tc", ap, h)
    else:
        raise ValueError(f"{name!r} is not a coasting control system")
    return _profile(run, name, target, res.s_grid, res.v_profile, res.time_s,
                    res.energy_j, res.feasible, res.message, t0)


def plan_dp(run: RunModel, name: str, target: float, fast: Any,
            cache: Optional[dict[Any, Any]], params: dict[str, Any], t0: float) -> Profile:
    """DP: the minimum-energy reference (tables cached per run and grid)."""
    key = (run.x_start_m, run.x_stop_m)
    ds = float(params.get("ds_m", 10.0))
    de = float(params.get("de_m2s2", 1.0))
    dk = ("dp", key, ds, de)
    tab = cache.get(dk) if cache is not None else None
    if tab is None:
        tab = build_dp_tables(run, ds, de)
        if cache is not None:
            cache[dk] = tab
    r = solve_dp(run, target, tables=tab)
    msg = "" if r.feasible else f"DP time {r.time_s:.2f} s exceeds target"
    return _profile(run, name, target, r.s_grid, r.v_profile, r.time_s, r.energy_j,
                    r.feasible, msg, t0)


def plan_mmas(run: RunModel, name: str, target: float, fast: Any,
              cache: Optional[dict[Any, Any]], params: dict[str, Any], t0: float) -> Profile:
    """MMAS over section modes and speed codes (section tables cached per run)."""
    key = (run.x_start_m, run.x_stop_m)
    n_sec = int(params.get("n_sections", 50))
    codes_kmh = tuple(params.get("codes_kmh", range(40, 85, 5)))
    mk = ("mmas", key, n_sec, codes_kmh)
    tables = cache.get(mk) if cache is not None else None
    if tables is None:
        tables = build_section_tables(run, n_sec, np.asarray(codes_kmh, dtype=float) / 3.6)
        if cache is not None:
            cache[mk] = tables
    fields = MmasParams.__dataclass_fields__
    mp = MmasParams(**{k: v for k, v in params.items() if k in fields})
    mres = solve_mmas(tables, target, mp)
    if not mres.feasible:
        return _profile(run, name, target, fast.s_grid, fast.v_profile, fast.time_s,
                        fast.energy_j, False,
                        f"MMAS found no profile within {target:.1f} s: flat-out profile", t0)
    coast_idx = np.nonzero(mres.modes == MODE_COAST)[0]
    yc = float(mres.section_bounds_m[coast_idx[0]]) if coast_idx.size else math.nan
    sections = (mres.section_bounds_m, mres.modes, mres.code_speeds_mps, yc)
    return _profile(run, name, target, mres.s_grid, mres.v_profile, mres.time_s,
                    mres.energy_j, True, "", t0, sections)
