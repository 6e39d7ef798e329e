"""Temporary speed restrictions as speed limits of a planned run (ROS-free).

A TSR known when a run is planned is a speed limit of that run like any civil limit: the
energy-optimal profile then coasts (or brakes) into the TSR's braking curve instead of
motoring up to the permanent limit just before it and braking the gain away (a second speed
minimum on the approach: hunting).  :func:`tsrs_for_run` picks the TSRs a run must respect
and :func:`track_with_tsrs` merges them into the track's piecewise-constant limits, which
:class:`metro_atc.core.ato.envelope.RunModel` turns into its envelope (the limit over the
whole train length, ``restriction_lead_m`` and the braking curves included).

Positions are chainages [m], speeds [m/s], times [s].
"""

from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np

from metro_atc.core.line.vehicle import Track


def tsrs_for_run(tsrs: Sequence[Any], x_start_m: float, x_stop_m: float, length_m: float,
                 t_s: float) -> tuple[tuple[float, float, float], ...]:
    """The TSRs a run planned at ``t_s`` respects: (start [m], end [m], limit [m/s]) sorted.

    A TSR counts when it is known (``known_s <= t_s``), not over (``t_s < to_s``) and
    overlaps the run's span widened by the train length ``length_m`` (the rear at the
    departure, the front beyond the stopping point).  Zones with non-finite or
    non-positive limits, or an empty extent, are ignored (hostile input).
    """
    lo = min(x_start_m, x_stop_m) - length_m
    hi = max(x_start_m, x_stop_m) + length_m
    out = set()
    for z in tsrs:
        a, b, v = float(z.start_m), float(z.end_m), float(z.limit_mps)
        if not (math.isfinite(a) and math.isfinite(b) and math.isfinite(v)) or b <= a \
                or v <= 0.0:
            continue
        if float(z.known_s) <= t_s < float(z.to_s) and a < hi and b > lo:
            out.add((a, b, v))
    return tuple(sorted(out))


def track_with_tsrs(track: Track, zones: Sequence[tuple[float, float, float]]) -> Track:
    """``track`` with each zone's limit applied over [start, end) (the lower limit wins).

    ``zones``: (start [m], end [m], limit [m/s]) as :func:`tsrs_for_run` returns them.  The
    grades are shared; the limit breakpoints are the track's and the zones' ends.
    """
    if not zones:
        return track
    starts = np.asarray(track.limit_starts_m, dtype=float)
    edges = [a for a, _, _ in zones] + [b for _, b, _ in zones]
    bp = np.unique(np.concatenate((starts, np.asarray(edges, dtype=float))))
    lim = np.asarray(track.limit_at(bp), dtype=float).copy()
    for a, b, v in zones:
        inside = (bp >= a) & (bp < b)
        lim[inside] = np.minimum(lim[inside], v)
    return Track(np.asarray(track.grade_starts_m, dtype=float),
                 np.asarray(track.grades, dtype=float), bp, lim)
