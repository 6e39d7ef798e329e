"""A two-direction service day on the plant (core/service/dayplant.py), ROS-free.

Short days on the ``mini`` line (4 stations) with both terminus layouts: every planned
trip runs, every train ends in the depot, no ATP violation, no route conflict (the
interlocking's brute-force safety check every step), no missed stop, berthing within the
platform-door window; a late arrival larger than the turnback buffer delays the next trip by
exactly delay - buffer (:func:`propagate_delay`).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np
import pytest

from metro_atc.core.line.scenario import load_scenario
from metro_atc.core.plant.driver import simple_driver
from metro_atc.core.plant.line import LineSim
from metro_atc.core.service.circulation import build_circulation, propagate_delay
from metro_atc.core.service.dayplant import DayPlant, DayTerminus, day_trips
from metro_atc.core.service.interlocking import scissors_terminus, tail_track_terminus
from metro_atc.core.service.loop import build_loop

CODES = ("MN01", "MN04")
MIN_TURNBACK_S = 240.0
PLATFORM_M = 150.0  # the berths hold the 141 m train

LAYOUTS = {
    "scissors_A_tail_B": lambda: (scissors_terminus(platform_m=PLATFORM_M),
                                  tail_track_terminus(2, platform_m=PLATFORM_M)),
    "tail_A_scissors_B": lambda: (tail_track_terminus(1, platform_m=PLATFORM_M),
                                  scissors_terminus(platform_m=PLATFORM_M)),
}


def _day(layouts, extra=None, depots=CODES):  # type: ignore[no-untyped-def]
    scn = load_scenario("mini")
    scn = dataclasses.replace(scn, disturbances=dataclasses.replace(
        scn.disturbances, departure_delay_prob=0.0))
    loop = build_loop(scn, layouts)
    sv = LineSim(loop.scenario, trace_period_s=0.0).service
    # two periods of 20 min: 300 s then 240 s headway
    trips = day_trips(loop, sv, CODES, [(3600.0, 4800.0, 300.0), (4800.0, 6000.0, 240.0)])
    circ = build_circulation(trips, {c: MIN_TURNBACK_S for c in CODES}, set(depots))
    dp = DayPlant(loop, circ, [DayTerminus(c, MIN_TURNBACK_S, c in depots) for c in CODES],
                  extra_dwell=extra)
    return circ, trips, dp


@pytest.mark.parametrize("name", sorted(LAYOUTS))
def test_short_day_runs_every_trip_safely(name: str) -> None:
    circ, trips, dp = _day(LAYOUTS[name]())
    res = dp.run()
    assert res.finished, res.notes
    assert 3 <= circ.fleet <= 6
    assert res.trips_run == res.trips_planned == len(trips)
    assert res.trains_in_depot == res.fleet == circ.fleet
    assert res.atp_violations == 0 and res.separation_violations == 0
    assert res.route_conflicts == 0, res.notes
    assert res.missed_stops == 0
    assert max(abs(e) for e in res.stop_errors_m) <= 0.30
    assert not res.forced_stop_errors_m
    # the records: one per call of every trip, its turnbacks, the depot moves
    assert len(res.stops) == len(trips) * 4
    assert sum(1 for d in res.depot if d.kind == "pull_out") == sum(circ.pull_outs.values())
    assert sum(1 for d in res.depot if d.kind == "pull_in") == sum(circ.pull_ins.values())
    assert len(res.turnbacks) == sum(len(b.trips) - 1 for b in circ.blocks)
    for tb in res.turnbacks:  # the minimum turnback holds, the timetable holds
        assert tb.dep_s >= tb.arr_s + MIN_TURNBACK_S - 1e-6
        assert tb.dep_s >= tb.sched_dep_s - 1e-6
    # each train ran its own blocks' trips, in order (identity kept across trips)
    for b in circ.blocks:
        ran = [r.trip_id for r in res.stops if r.train == b.train and math.isnan(r.sched_arr_s)]
        mine = {t.trip_id for t in b.trips}
        assert [t.trip_id for t in b.trips] == [x for x in ran if x in mine]
    for r in res.stops:  # every call happened, departures after arrivals
        assert math.isfinite(r.arr_s) or math.isnan(r.sched_arr_s)
        assert math.isfinite(r.dep_s) or math.isnan(r.sched_dep_s)
        if math.isfinite(r.arr_s) and math.isfinite(r.dep_s):
            assert r.dep_s > r.arr_s
    # energy per trip (departure to arrival): every trip draws from the substations, the
    # trips' sum is the whole day's less what the layovers' auxiliaries drew
    e = dp.trip_energy_j
    assert sorted(e) == sorted(t.trip_id for t in trips)
    assert min(e.values()) > 0.0
    total = float(dp.sim.energy.e_substation.sum())
    assert 0.5 * total < sum(e.values()) < total


def test_late_arrival_delays_the_next_trip_by_delay_minus_buffer() -> None:
    layouts = LAYOUTS["scissors_A_tail_B"]
    circ, _, dp0 = _day(layouts())
    blk = next(b for b in circ.blocks if len(b.trips) >= 2)
    first, second = blk.trips[0], blk.trips[1]
    buffer = (second.departure_s - first.arrival_s) - MIN_TURNBACK_S
    hold = buffer + 60.0
    station = 1 if first.origin == CODES[0] else 2  # an intermediate call of the first trip
    _, _, dp = _day(layouts(), extra={(blk.train, first.trip_id, station): hold})
    res = dp.run()
    assert res.finished and res.route_conflicts == 0 and res.atp_violations == 0
    tb = next(x for x in res.turnbacks if x.train == blk.train and x.arr_trip_id ==
              first.trip_id)
    assert tb.terminal_delay_s > buffer + 30.0  # the hold made it late beyond the buffer
    expect = propagate_delay(tb.terminal_delay_s, tb.sched_dep_s - tb.sched_arr_s,
                             MIN_TURNBACK_S)
    assert expect > 0.0
    assert abs(tb.carried_delay_s - expect) <= 0.5  # one control period and rounding
    # the undisturbed day leaves that trip on time
    res0 = dp0.run()
    tb0 = next(x for x in res0.turnbacks if x.train == blk.train and x.arr_trip_id ==
               first.trip_id)
    assert tb0.carried_delay_s <= 0.5


def test_a_follower_waits_behind_a_held_train() -> None:
    """The train ahead on the track (by path position) bounds the authority: no catch-up."""
    layouts = LAYOUTS["tail_A_scissors_B"]
    circ, trips, _ = _day(layouts())
    ups = sorted((t for t in trips if t.origin == CODES[0]), key=lambda t: t.departure_s)
    lead_trip, next_trip = ups[0], ups[1]
    owner = {t.trip_id: b.train for b in circ.blocks for t in b.trips}
    hold = 2.0 * (next_trip.departure_s - lead_trip.departure_s)
    _, _, dp = _day(layouts(), extra={(owner[lead_trip.trip_id], lead_trip.trip_id, 1): hold})
    res = dp.run()
    assert res.finished and res.trips_run == res.trips_planned
    assert res.atp_violations == 0 and res.separation_violations == 0
    assert res.route_conflicts == 0 and res.missed_stops == 0
    assert max(abs(e) for e in res.stop_errors_m) <= 0.30
    call = {(r.trip_id, r.station): r for r in res.stops}
    left = call[(lead_trip.trip_id, 1)].dep_s
    assert left - call[(lead_trip.trip_id, 1)].arr_s >= hold
    # the follower reached that platform only once the held train had left it
    assert call[(next_trip.trip_id, 1)].arr_s > left
    assert call[(next_trip.trip_id, 1)].sched_arr_s < left  # it was due before


def _step_at(items, x, key):  # type: ignore[no-untyped-def]
    v = getattr(items[0], key)
    for it in items:
        if it.start_m <= x:
            v = getattr(it, key)
    return v


@pytest.mark.parametrize("name", sorted(LAYOUTS))
def test_loop_mirrors_the_line(name: str) -> None:
    """Down platforms, grades (sign reversed), limits and curves mirror the chainage."""
    scn = load_scenario("mini")
    layouts = LAYOUTS[name]()
    loop = build_loop(scn, layouts)
    c = [s.position_m for s in scn.line.stations]
    length = c[-1] - c[0]
    b = loop.termini[1]
    d0 = loop.stops[b.departure_stop].s_m
    # the turnback of B is its routes end to end: platform stop to departure platform
    assert d0 - length == pytest.approx(0.0 if b.arrival_stop == b.departure_stop else sum(
        max(b.layout.route_length_m(r.name) for r in b.layout.routes if r.stage == st)
        for st in (1, 2)))
    for j, cj in enumerate(c):
        assert loop.stops[loop.up_stop[j]].s_m == pytest.approx(cj - c[0])
        if 0 < j < len(c) - 1:
            assert loop.stops[loop.down_stop[j]].s_m == pytest.approx(d0 + c[-1] - cj)
    line = loop.scenario.line
    for cj in (800.0, 2100.0, 2400.0, 1300.0, 450.0):  # inside grades and limits
        up, down = cj - c[0], d0 + c[-1] - cj
        g = _step_at(scn.line.gradients, cj, "grade_permille")
        assert _step_at(line.gradients, up, "grade_permille") == g
        assert _step_at(line.gradients, down, "grade_permille") == -g
        lim = _step_at(scn.line.speed_limits, cj, "limit_kmh")
        assert _step_at(line.speed_limits, up, "limit_kmh") == lim
        assert _step_at(line.speed_limits, down, "limit_kmh") == lim
    assert len(line.curves) == 2 * len(scn.line.curves)
    for tp in loop.termini:  # every route's limit holds over its points and its berth
        pts = set(tp.layout.point_section.values())
        for sp in tp.spans.values():
            for s, a, z in sp.sections:
                if s not in pts and s != sp.route.destination or s == tp.layout.exit_section:
                    continue
                for x in (a + 0.5, 0.5 * (a + z), z - 0.5):
                    assert _step_at(line.speed_limits, x, "limit_kmh") <= (
                        sp.route.speed_limit_mps * 3.6 + 1e-9)
    assert loop.stops[-1].role == "wrap" and loop.stops[-1].station == 0


def test_fleet_plant_reads_each_trains_authority_end() -> None:
    """External authority ends per slot bound each train; no train ahead by slot index."""
    scn = load_scenario("mini")
    sim = LineSim(scn, seed=0, trace_period_s=0.0)
    sim.external_authority()
    x0 = float(sim.geometry.station_positions_m[0])
    end = x0 + 300.0  # train 0 may run 300 m past its first stop; train 1 is free
    sim.set_authority_ends([0, 1], [end, math.inf])
    top = np.zeros(sim.n)
    while sim.t < 600.0:
        sim.step(simple_driver(sim))
        top = np.maximum(top, np.where(sim.fleet.run, sim.fleet.x, -math.inf))
    assert top[0] <= end and top[0] > end - 60.0  # held at its end, close to it
    assert top[1] > end + 500.0  # the other ran on (its authority is not train 0's rear)
    assert sim.atp.eoa[0] == end
    with pytest.raises(ValueError):
        sim.set_authority_ends([0], [math.nan])


def test_depot_slots_are_idle() -> None:
    """A train in the depot does not move, meters no energy and gives no sensor samples."""
    circ, _, dp = _day(LAYOUTS["scissors_A_tail_B"]())
    first = min(b.trips[0].departure_s for b in circ.blocks)
    dp.run(end_s=first + 900.0)
    out = [tr.i for tr in dp.trains if not tr.in_service]
    assert out and any(tr.in_service for tr in dp.trains)
    sim = dp.sim
    before = (sim.fleet.x[out].copy(), sim.energy.e_trac[out].copy(),
              sim.energy.e_fric[out].copy(), sim.energy.e_res[out].copy())
    res = dp.run(end_s=first + 960.0, sensors=True)
    still = [k for k, i in enumerate(out) if not dp.trains[i].in_service]
    assert still and res.sensor_samples > 0
    after = (sim.fleet.x[out], sim.energy.e_trac[out], sim.energy.e_fric[out],
             sim.energy.e_res[out])
    for b, a in zip(before, after):
        assert np.array_equal(b[still], a[still])
    assert not sim.sensors.mask[[out[k] for k in still]].any()


def test_ato_memos_keep_their_newest_entries() -> None:
    """The ATOs' mass- and TSR-keyed memos keep their newest entries (bounded over a day)."""
    from metro_atc.core.ato.controller import memo_put, memo_slot
    memo: dict = {}
    for k in range(10):
        memo_put(memo, k, k, keep=3)
    assert list(memo) == [7, 8, 9]
    sub = memo_slot(memo, "m")
    assert memo_slot(memo, "m") is sub and list(memo) == [7, 8, 9, "m"]


def test_a_day_keeps_the_ato_memos_bounded() -> None:
    """Over a short day the shared memos never hold more than MEMO_KEEP entries."""
    from metro_atc.core.ato.controller import MEMO_KEEP
    _, _, dp = _day(LAYOUTS["scissors_A_tail_B"]())
    dp.run()
    sizes = {k: len(v) for k, v in dp.shared.items() if isinstance(v, dict)}
    assert sizes["plans"] > 0 and all(n <= MEMO_KEEP for n in sizes.values())


def test_the_depot_feeds_a_peak_on_time_at_tail_tracks() -> None:
    """Departure berths serve trips in timetable order: a peak fed by the depot keeps time.

    Tail tracks at both ends, a 120 s peak after a 360 s shoulder: the first peak trips
    are pull-outs while the trains turned from the shoulder stand in the sidings for later
    trips.  A turned train that took the single departure platform before a pull-out due
    earlier would hold it until its own later trip and the pull-out behind it (measured
    before the rule: 2000+ s late); every departure from a terminus now leaves within 60 s
    of its timetable.
    """
    scn = load_scenario("mini")
    scn = dataclasses.replace(scn, disturbances=dataclasses.replace(
        scn.disturbances, departure_delay_prob=0.0))
    loop = build_loop(scn, (tail_track_terminus(2, platform_m=PLATFORM_M),
                            tail_track_terminus(2, platform_m=PLATFORM_M)))
    sv = LineSim(loop.scenario, trace_period_s=0.0).service
    trips = day_trips(loop, sv, CODES, [(3600.0, 4800.0, 360.0), (4800.0, 7200.0, 120.0)])
    min_tb, layover = 120.0, 350.0
    circ = build_circulation(trips, {c: layover for c in CODES}, set(CODES), 1800.0,
                             "longest_wait")
    assert sum(circ.pull_outs.values()) > 4  # the peak needs the depot
    dp = DayPlant(loop, circ, [DayTerminus(c, min_tb, True) for c in CODES])
    res = dp.run()
    assert res.finished and res.trips_run == res.trips_planned
    assert res.atp_violations == 0 and res.route_conflicts == 0, res.notes
    assert res.missed_stops == 0
    late = [r.dep_s - r.sched_dep_s for r in res.stops if math.isnan(r.sched_arr_s)]
    assert len(late) == len(trips)
    assert max(late) <= 60.0, sorted(late)[-5:]


def test_an_authority_never_rests_a_train_inside_the_stop_window_short_of_its_stop() -> None:
    """No end of authority has the ATO rest inside the stop window short of the stop point.

    The ATO comes to rest AUTHORITY_MARGIN_M short of the end of authority; inside the stop
    window (+-tol) short of the next stop point the plant would count that standstill as the
    arrival with the shortfall as its stop error.  A growing authority stays growing (no
    jump back under the ATP).
    """
    import numpy as np

    from metro_atc.core.ato.control_kernel import AUTH_MARGIN as AUTHORITY_MARGIN_M
    from metro_atc.core.service.dayplant import clear_of_stop
    stop, tol, x = 1000.0, 1.0, 700.0
    prev = -math.inf
    for ma in np.arange(900.0, 1100.0, 0.05):
        got = clear_of_stop(float(ma), x, stop, tol)
        rest = got - AUTHORITY_MARGIN_M
        assert not (stop - 2.0 * tol < rest < stop), (ma, got)
        assert got <= ma and got >= prev
        prev = got
        if ma >= stop + AUTHORITY_MARGIN_M:
            assert got == ma  # the authority covers the stop: unchanged
        if ma <= stop + AUTHORITY_MARGIN_M - 2.0 * tol:
            assert got == ma  # the train rests outside the window anyway
    # a train past its stop point (or standing at it) keeps its authority
    assert clear_of_stop(1005.0, 1000.5, stop, tol) == 1005.0


def test_a_tsr_on_one_track_slows_that_track_only() -> None:
    """A 30 km/h TSR on the down track between Charlie and Bravo: the trains running down
    through it keep to 30 km/h; those running up over the same chainage do not slow."""
    from metro_atc.core.service.day import TrackTsr
    from metro_atc.core.service.loop import LoopError
    scn = load_scenario("mini")
    scn = dataclasses.replace(scn, disturbances=dataclasses.replace(
        scn.disturbances, departure_delay_prob=0.0))
    layouts = LAYOUTS["scissors_A_tail_B"]()
    zone = TrackTsr("down", 1200.0, 1600.0, 30.0)
    loop = build_loop(scn, layouts, tsrs=[zone])
    with pytest.raises(LoopError, match="stations lie at"):
        build_loop(scn, layouts, tsrs=[TrackTsr("down", 2500.0, 2900.0, 30.0)])
    sv = LineSim(loop.scenario, trace_period_s=0.0).service
    trips = day_trips(loop, sv, CODES, [(3600.0, 4200.0, 300.0)])
    circ = build_circulation(trips, {c: MIN_TURNBACK_S for c in CODES}, set(CODES))
    dp = DayPlant(loop, circ, [DayTerminus(c, MIN_TURNBACK_S, True) for c in CODES])
    up = [s for s in loop.stops if s.direction == "up"]
    down = [s for s in loop.stops if s.direction == "down"]
    # the zone on the loop: down from s(Charlie down) + 900 - 1600 .. + 900 - 1200
    c_down = next(s.s_m for s in down if s.station == 2)
    lo_d, hi_d = c_down + (1900.0 - 1600.0), c_down + (1900.0 - 1200.0)
    lo_u, hi_u = next(s.s_m for s in up if s.station == 0) + 1200.0, \
        next(s.s_m for s in up if s.station == 0) + 1600.0
    vmax = {"down": 0.0, "up": 0.0}
    dp.start()
    while not dp.finished and dp.t < 9000.0:
        dp.end_step(dp.control(dp.begin_step()))
        fl = dp.sim.fleet
        for tr in dp.trains:
            if not tr.in_service:
                continue
            x, v = float(fl.x[tr.i]), float(fl.v[tr.i])
            rear = x - dp.length
            if rear < hi_d and x > lo_d:
                vmax["down"] = max(vmax["down"], v)
            if rear < hi_u and x > lo_u:
                vmax["up"] = max(vmax["up"], v)
    assert dp.finished
    assert 0.0 < vmax["down"] <= 30.0 / 3.6 + 0.05
    assert vmax["up"] > 40.0 / 3.6
    assert int(np.sum(dp.sim.atp.violations)) == 0


def test_a_track_limit_lowers_that_tracks_limit_only() -> None:
    """A 35 km/h permanent limit of the up track over 1200..1600 m: the loop's limit there
    on the up side is 35 km/h, on the down side over the same chainage the line's."""
    from metro_atc.core.service.day import TrackLimit
    scn = load_scenario("mini")
    loop = build_loop(scn, LAYOUTS["scissors_A_tail_B"](),
                      track_limits=[TrackLimit("up", 1200.0, 1600.0, 35.0)])
    ref = build_loop(scn, LAYOUTS["scissors_A_tail_B"]())

    def at(lp: Any, s: float) -> float:
        return [x.limit_kmh for x in lp.scenario.line.speed_limits if x.start_m <= s][-1]

    up0 = next(x.s_m for x in loop.stops if x.direction == "up" and x.station == 0)
    c_down = next(x.s_m for x in loop.stops if x.direction == "down" and x.station == 2)
    assert at(loop, up0 + 1400.0) == 35.0 < at(ref, up0 + 1400.0)
    for s in (up0 + 1100.0, up0 + 1700.0, c_down + 1900.0 - 1400.0):
        assert at(loop, s) == at(ref, s)


def test_a_tracks_own_curves_replace_the_lines_on_that_track_only() -> None:
    """The down track with a curve of its own: the loop's down half has exactly it, the up
    half keeps the line's curves (mirrored on the down half without an override)."""
    from metro_atc.core.line.scenario import CurveSpec
    from metro_atc.core.service.day import TrackCurve
    scn = load_scenario("mini")
    scn = dataclasses.replace(scn, line=dataclasses.replace(
        scn.line, curves=[CurveSpec(start_m=300.0, end_m=500.0, radius_m=400.0)]))
    lay = LAYOUTS["scissors_A_tail_B"]()
    ref = build_loop(scn, lay)
    own = build_loop(scn, lay, track_curves=[TrackCurve("down", 1000.0, 1300.0, 250.0)])
    half = ref.period_m / 2.0

    def curves(lp: Any, down: bool) -> list:  # type: ignore[type-arg]
        return [(round(c.start_m, 6), round(c.end_m, 6), c.radius_m)
                for c in lp.scenario.line.curves if (c.start_m > half) == down]

    assert curves(own, False) == curves(ref, False) == [(300.0, 500.0, 400.0)]
    assert len(curves(ref, True)) == 1 and curves(ref, True)[0][2] == 400.0
    (a, b, r), = curves(own, True)
    assert (round(b - a, 6), r) == (300.0, 250.0)
