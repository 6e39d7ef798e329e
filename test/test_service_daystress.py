"""Stress of a service day: both termini delayed at once and a train stuck on the points.

A small generated day (scissors at A, tail track at B, depots at both) where, at one
instant of the peak, the trains due out of both termini break down at their platforms
(both termini delayed at once) and a third train breaks down on the scissors crossover
of A while arriving (it stands on the points, blocking every route of A, then recovers).
Neither the interlocking nor the day loop may deadlock: the day finishes within a bounded
wall time with every trip run, the interlocking never holds conflicting routes
(:func:`check_safe` after every step, besides the plant's own count), and the trains wait
(no separation violation, no section held by two trains).  A stoppage longer than the day
is reported honestly: the run stops at its end time, says so and counts what did not run.
"""

from __future__ import annotations

from typing import Any, List, Tuple

from metro_atc.core.service.circulation import Trip
from metro_atc.core.service.daygen import day_failures, day_plant, generate_day
from metro_atc.core.service.dayplant import Breakdown, DayPlant
from metro_atc.core.service.interlocking import check_safe

SEED = 3
"""A small day with a scissors crossover at A and a tail track at B, depots at both."""
WALL_S = 300.0
"""Wall-time bound of a run [s] (the undisturbed day takes a few CPU seconds)."""


def _day() -> Any:
    gd = generate_day(SEED, n_stations=4, spacing_kind="dense", stock="light_metro",
                      period_min=(10, 20, 10))
    assert [t.layout.name for t in gd.plan.termini] == ["scissors", "tail_track_1"]
    assert all(t.depot is not None for t in gd.plan.termini)
    return gd


def _stress(gd: Any, stuck_s: float, delay_s: float) -> Tuple[List[Breakdown], str]:
    """The breakdowns: both termini's next departures at one instant, a train on A's points."""
    circ = day_plant(gd).circ
    owner = {t.trip_id: b.train for b in circ.blocks for t in b.trips}
    trips: List[Trip] = sorted((t for b in circ.blocks for t in b.trips),
                               key=lambda t: t.departure_s)
    peak = gd.plan.periods[1]
    up = next(t for t in trips if t.trip_id.startswith("up") and t.departure_s >= peak.start_s)
    down = next(t for t in trips if t.trip_id.startswith("down")
                and t.departure_s >= up.departure_s)
    assert down.departure_s == up.departure_s  # both termini due out at one instant
    at = up.departure_s - 60.0
    delayed = {owner[up.trip_id], owner[down.trip_id]}
    # the next train into A (a down trip) that is neither of them stops on the scissors
    into_a = next(t for t in sorted(trips, key=lambda t: t.arrival_s)
                  if t.trip_id.startswith("down") and t.arrival_s >= at
                  and owner[t.trip_id] not in delayed)
    stuck = owner[into_a.trip_id]
    return [Breakdown(owner[up.trip_id], at, delay_s), Breakdown(owner[down.trip_id], at, delay_s),
            Breakdown(stuck, at, stuck_s, terminus=0, section="x1")], stuck


def _run_checked(dp: DayPlant) -> Tuple[Any, int]:
    """Run ``dp`` with :func:`check_safe` on both interlockings after every step."""
    steps = [0]
    plant_checks = dp._checks

    def checks() -> None:
        plant_checks()
        for il in dp.il:
            why = check_safe(il)
            assert why is None, f"t={dp.t:.2f} s: {why}"
        steps[0] += 1

    dp._checks = checks  # type: ignore[method-assign]
    res = dp.run(max_wall_s=WALL_S)
    return res, steps[0]


def test_both_termini_delayed_and_a_train_stuck_on_the_points_do_not_deadlock() -> None:
    gd = _day()
    bds, stuck = _stress(gd, stuck_s=1200.0, delay_s=600.0)
    dp = day_plant(gd, breakdowns=bds)
    res, steps = _run_checked(dp)
    assert res.wall_s < WALL_S
    assert steps == dp.step_no > 0
    broke = [n for n in res.notes if "broke down" in n]
    assert len(broke) == 3, res.notes  # all three happened
    assert day_failures(res) == [], res.notes  # no violation, conflict, missed stop
    assert res.finished and res.trips_run == res.trips_planned
    assert res.trains_in_depot == res.fleet
    assert res.route_conflicts == 0 and res.separation_violations == 0
    # the stoppage was felt: trips ran late by a good part of the stuck time, and the train
    # stuck on the points reached A's platform after it recovered
    late = max(tb.terminal_delay_s for tb in res.turnbacks)
    assert late > 600.0
    note = next(n for n in broke if f"{stuck} broke" in n)
    t_stuck = float(note.split("t=")[1].split(" s")[0])
    arr_a = [r.arr_s for r in res.stops if r.train == stuck and r.station == 0
             and r.arr_s > t_stuck - 1.0]
    assert arr_a and min(arr_a) >= t_stuck + 1200.0


def test_a_stoppage_longer_than_the_day_is_reported_not_hidden() -> None:
    """Stuck on the points for 5 h: the run ends at its end time and says what is left."""
    gd = _day()
    bds, _ = _stress(gd, stuck_s=5 * 3600.0, delay_s=600.0)
    dp = day_plant(gd, breakdowns=bds)
    res, _ = _run_checked(dp)
    assert res.wall_s < WALL_S
    assert not res.finished
    assert any("end time" in n and "before every train was back in the depot" in n
               for n in res.notes), res.notes
    assert res.trips_run < res.trips_planned and res.trains_in_depot < res.fleet
    fails = day_failures(res)
    assert "unfinished" in fails and any("trips not run" in f for f in fails)
    assert res.route_conflicts == 0 and res.separation_violations == 0
    assert res.atp_violations == 0
