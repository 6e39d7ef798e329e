"""A TSR known when a run is planned is a speed limit of the plan (ROS-free).

:mod:`metro_atc.core.ato.tsr_plan`: the merged limits against a brute-force minimum, the
choice of the TSRs a run respects, and the ECTP plan of ``gen_0039_inc``'s first run with
its TSR moved +60 m and limited to 30 km/h: planned without the TSR the profile coasts to
40 km/h and motors back before the TSR's braking curve (two speed minima on the approach
once the ATO brakes for the TSR); planned with it, one minimum and never above the limit
(with slack in the target the ECTP plan may still coast and motor back before the curve:
the ATO's hold rule covers that, ``test/test_tsr_hold.py``).
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np

from metro_atc.core.ato.controller import AtoCore
from metro_atc.core.ato.onboard import envelope_limits, tsr_zones
from metro_atc.core.ato.tsr_plan import track_with_tsrs, tsrs_for_run
from metro_atc.core.bridge import timetable_for, track_for, train_for
from metro_atc.core.line.vehicle import Track
from metro_atc.core.linegen import load_generated
from metro_atc.core.tsr_hunting import SpeedMinima


def _zone(a: float, b: float, v: float, known: float = 0.0, to: float = math.inf
          ) -> SimpleNamespace:
    return SimpleNamespace(start_m=a, end_m=b, limit_mps=v, known_s=known, from_s=known,
                           to_s=to)


def test_merged_limits_are_the_brute_force_minimum() -> None:
    """At 20 000 random points the merged limit is min(civil, every zone covering x)."""
    rng = np.random.default_rng(11)
    for _ in range(20):
        starts = np.concatenate(([-1e12], np.sort(rng.uniform(0.0, 5000.0, 6))))
        track = Track(np.array([-1e12]), np.array([0.0]), starts,
                      rng.uniform(10.0, 25.0, starts.size))
        zones = []
        for _ in range(int(rng.integers(1, 4))):
            a = float(rng.uniform(-200.0, 5000.0))
            zones.append((a, a + float(rng.uniform(50.0, 900.0)), float(rng.uniform(5.0, 20.0))))
        merged = track_with_tsrs(track, zones)
        xs = np.concatenate((rng.uniform(-500.0, 6000.0, 1000),
                             [z[0] for z in zones], [z[1] for z in zones]))
        want = np.array([min([float(track.limit_at(x))]
                             + [v for a, b, v in zones if a <= x < b]) for x in xs])
        np.testing.assert_array_equal(merged.limit_at(xs), want)
        np.testing.assert_array_equal(merged.grade_at(xs), track.grade_at(xs))
    assert track_with_tsrs(track, ()) is track


def test_the_tsrs_a_run_respects() -> None:
    """Known and not over at the planning time, overlapping the run +- the train length."""
    z = [_zone(1000.0, 1300.0, 8.0, known=100.0, to=500.0),
         _zone(-150.0, -50.0, 6.0),                 # the rear at the departure is inside
         _zone(2100.0, 2200.0, 6.0),                # beyond the stop + train length
         _zone(400.0, 300.0, 6.0),                  # empty: hostile
         _zone(500.0, 600.0, math.nan),             # no limit: hostile
         _zone(700.0, 800.0, 0.0)]                  # zero limit: hostile
    got = tsrs_for_run(z, 0.0, 2000.0, 100.0, 200.0)
    assert got == ((-150.0, -50.0, 6.0), (1000.0, 1300.0, 8.0))
    assert tsrs_for_run(z, 0.0, 2000.0, 100.0, 99.0) == ((-150.0, -50.0, 6.0),)
    assert tsrs_for_run(z, 0.0, 2000.0, 100.0, 500.0) == ((-150.0, -50.0, 6.0),)
    # the other direction (stop before start): the same span
    assert tsrs_for_run(z, 2000.0, 0.0, 100.0, 200.0) == got
    assert tsrs_for_run(z, 0.0, 2000.0, 100.0, math.nan) == ()


def _approach_minima(prof_v: np.ndarray, s: np.ndarray, z0: float) -> int:
    m = SpeedMinima()
    for vi in prof_v[(s >= z0 - 800.0) & (s <= z0)]:
        m.feed(float(vi))
    return m.close().minima


def test_the_plan_rides_into_a_known_tsr() -> None:
    """gen_0039_inc, TSR +60 m at 30 km/h, the timetable's target: one minimum, not two.

    The timetable's 169 s is below the fastest run through the TSR (~207 s): the plan with
    the TSR is that fastest run (``feasible`` False, as the ATO's closed loop gets it); the
    plan without it coasts and motors back before the TSR's braking curve.
    """
    import dataclasses
    base = load_generated(39, incidents=True)
    z0 = next(i for i in base.incidents if i.kind == "tsr")
    zi = dataclasses.replace(z0, start_m=z0.start_m + 60.0, end_m=z0.end_m + 60.0,
                             limit_kmh=30.0)
    scn = dataclasses.replace(base, incidents=[zi if i is z0 else i for i in base.incidents])
    train, track = train_for(scn), track_for(scn)
    limits = envelope_limits(scn, train)
    tt = timetable_for(scn)
    x0, x1 = float(tt.station_positions_m[0]), float(tt.station_positions_m[1])
    target = float(tt.running_s[0])
    zones = tsrs_for_run(tsr_zones(scn), x0, x1, train.length_m, zi.at_s)
    assert len(zones) == 1
    free = AtoCore(train, track, limits=limits).plan(x0, x1, target)
    core = AtoCore(train, track, limits=limits)
    prof = core.plan(x0, x1, target, zones)
    assert free.feasible and not prof.feasible
    assert prof.running_time_s > free.running_time_s + 20.0  # the TSR costs time
    s = prof.s_grid + x0
    a, b, v = zones[0]
    # never above the TSR (less the planning margin) with any part of the train in it
    inside = (s >= a) & (s - train.length_m < b)
    assert np.all(prof.v_profile[inside] <= v - limits.speed_margin_mps + 1e-6)
    # the TSR's braking curve applies to the free plan as the ATO's cap does: min(plan, curve)
    run = core.run
    assert run is not None
    cap = np.sqrt(2.0 * run.ceiling_e(prof.s_grid))
    assert np.all(prof.v_profile <= cap + 1e-6)
    capped_free = np.minimum(np.interp(prof.s_grid, free.s_grid, free.v_profile), cap)
    assert _approach_minima(capped_free, s, a) == 2
    assert _approach_minima(prof.v_profile, s, a) == 1
