"""KPIs of a service day from its records: planned day, injected delays, hand-built cases."""

from __future__ import annotations

import json
import math
from typing import List

import pytest

from metro_atc.core.service.circulation import propagate_block
from metro_atc.core.service.day import run_day, taipei_blue_day, trips
from metro_atc.core.service.daykpi import day_kpis, fleet_profile, kpi_table
from metro_atc.core.service.planned import Incident, planned_records
from metro_atc.core.service.records import DepotRecord, StopRecord

PLAN = taipei_blue_day()
CIRC, _ = run_day(PLAN)
H7 = 7 * 3600.0


def _peak_up_trip_with_next() -> tuple:
    """A morning-peak up trip that is not its block's last, with its block and index."""
    for blk in CIRC.blocks:
        for i, t in enumerate(blk.trips[:-1]):
            if t.trip_id.startswith("up") and t.departure_s >= 7.5 * 3600:
                return blk, i, t
    raise AssertionError("no such trip")


def test_planned_day_runs_to_time() -> None:
    """No incident: every instant is the timetable; all trips run; fleet = circulation."""
    rec = planned_records(PLAN, CIRC)
    assert all(r.departure_delay_s == 0.0 for r in rec.stops if math.isfinite(r.dep_s))
    assert all(r.arrival_delay_s == 0.0 for r in rec.stops if math.isfinite(r.arr_s))
    k = day_kpis(PLAN, rec.stops, rec.turnbacks, rec.depot)
    assert k["trips_planned"] == k["trips_run"] == len(trips(PLAN)) == 586
    assert k["punctuality"] == 1.0
    assert k["fleet_max"] == CIRC.fleet
    for p in k["periods"]:
        assert p["turnbacks"]["carried"] == 0
        for d in ("up", "down"):
            r = p["directions"][d]
            assert r["headway_ratio_cv_mean"] == pytest.approx(0.0, abs=1e-12)
            assert r["headway_deviation_rms_s"] == pytest.approx(0.0, abs=1e-9)
    json.dumps(k, allow_nan=False)


@pytest.mark.parametrize("delay", [5.0, 180.0, 600.0])
def test_delay_carried_as_propagate_block_predicts(delay: float) -> None:
    """Without knock-on on followers a delay on a trip is carried exactly as propagate_block.

    Terminal delay = injected delay; each turnback carries max(0, delay - buffer).
    """
    blk, i, trip = _peak_up_trip_with_next()
    rec = planned_records(PLAN, CIRC, [Incident(trip.trip_id, 3, delay)], separation_s=0.0)
    tb = {t.station: t.min_turnback_s for t in PLAN.termini}
    expect = propagate_block(blk, tb, i, delay)
    mine = {r.arr_trip_id: r for r in rec.turnbacks if r.train == blk.train}
    got = [mine[t.trip_id].carried_delay_s for t in blk.trips[i:-1]]
    assert got == pytest.approx(expect, abs=1e-9)
    first = mine[trip.trip_id]
    assert first.terminal_delay_s == pytest.approx(delay)
    assert first.carried_delay_s == pytest.approx(max(0.0, delay - first.buffer_s))
    # the others only queue behind it (no overtaking): never later than the delay itself
    others = [r.departure_delay_s for r in rec.stops
              if r.train != blk.train and math.isfinite(r.dep_s)]
    assert 0.0 <= min(others) and max(others) <= delay
    if delay <= 5.0:            # within the headway slack nobody else is touched
        assert max(others) == 0.0


def test_knock_on_keeps_followers_behind() -> None:
    """With the line's separation the followers wait: no overtaking, delays > 0 behind."""
    _, _, trip = _peak_up_trip_with_next()
    rec = planned_records(PLAN, CIRC, [Incident(trip.trip_id, 0, 180.0)])
    k = day_kpis(PLAN, rec.stops, rec.turnbacks, rec.depot)
    peak = k["periods"][1]["directions"]["up"]
    assert peak["punctuality"] < 1.0 and peak["schedule_deviation_s"]["max"] == 180.0
    assert peak["headway_ratio_cv_mean"] > 0.0
    at5 = sorted((r for r in rec.stops if r.station == 5 and r.direction == "up"),
                 key=lambda r: r.sched_dep_s)
    deps = [r.dep_s for r in at5]
    assert deps == sorted(deps)
    assert min(b - a for a, b in zip(deps, deps[1:])) >= 0.0


def _call(trip: str, st: int, sched: float, dep: float, direction: str = "up",
          train: str = "t1") -> StopRecord:
    return StopRecord(train, trip, direction, st, math.nan if st == 0 else sched - 30.0,
                      sched, math.nan if st == 0 else sched - 30.0, dep)


def test_punctuality_threshold_is_inclusive_60_s() -> None:
    """Departures 0, 30, 60 and 61 s late: 3 of 4 punctual (PUNCTUAL_S = 60 s, <=)."""
    stops = [_call(f"up{i}", 1, H7 + 600.0 * i, H7 + 600.0 * i + d)
             for i, d in enumerate((0.0, 30.0, 60.0, 61.0))]
    k = day_kpis(PLAN, stops, [], [])
    r = k["periods"][1]["directions"]["up"]
    assert r["punctuality"] == 0.75 and k["punctual_threshold_s"] == 60.0
    assert r["schedule_deviation_s"]["max"] == 61.0


def test_headway_terms_known_answer() -> None:
    """Actual 0/100/300 s against scheduled 0/150/300 s: CV 1/3, deviation RMS 50 s."""
    stops = [_call(f"up{i}", 2, H7 + s, H7 + a)
             for i, (s, a) in enumerate(((0.0, 0.0), (150.0, 100.0), (300.0, 300.0)))]
    r = day_kpis(PLAN, stops, [], [])["periods"][1]["directions"]["up"]
    assert r["headway_cv_mean"] == pytest.approx(50.0 / 150.0)
    assert r["headway_deviation_rms_s"] == pytest.approx(50.0)
    # ratio 100/150 and 200/150: mean 1, std 1/3
    assert r["headway_ratio_cv_mean"] == pytest.approx(1.0 / 3.0)


def test_fleet_in_service_known_answer() -> None:
    """Pull-outs at 0 and 1800 s, a pull-in at 2700 s of a 1 h window: max 2, mean 1.25."""
    dep = [DepotRecord("a", "pull_out", "BL01", H7, H7),
           DepotRecord("b", "pull_out", "BL01", H7 + 1800.0, H7 + 1800.0),
           DepotRecord("a", "pull_in", "BL01", H7 + 2700.0, H7 + 2700.0),
           DepotRecord("c", "pull_in", "BL01", H7 + 10.0, H7)]       # never pulled out
    ts, ns, bad = fleet_profile(dep)
    assert bad == 1 and list(ns) == [1, 2, 1]
    k = day_kpis(PLAN, [], [], dep)
    p = k["periods"][1]                       # 07:00-09:00
    assert p["fleet_in_service_max"] == 2
    assert p["fleet_in_service_mean"] == pytest.approx((900 * 1 + 2 * 900 + 1 * 5400)
                                                       / 7200.0)
    assert k["unmatched_depot_moves"] == 1


def test_energy_per_direction_and_rejections() -> None:
    """Energy sums per direction [kWh]; unknown trips counted; bad records rejected."""
    stops: List[StopRecord] = [_call("up0", 0, H7, H7), _call("dn0", 0, H7, H7, "down"),
                               _call("xx", 0, H7, H7, "sideways")]
    k = day_kpis(PLAN, stops, [], [], {"up0": 3.6e6, "dn0": 7.2e6, "ghost": 1.0})
    assert k["energy_kwh"] == {"up": 1.0, "down": 2.0}
    assert k["energy_trips_missing"] == 1 and k["rejected_records"] == 1
    assert k["periods"][1]["directions"]["down"]["energy_kwh"] == 2.0


def test_table_and_incident_validation() -> None:
    """The table has one row per period and direction; bad incidents refused in one line."""
    rec = planned_records(PLAN, CIRC)
    text = kpi_table(day_kpis(PLAN, rec.stops, rec.turnbacks, rec.depot))
    for p in PLAN.periods:
        assert p.name in text
    assert len(text.splitlines()) == 3 + 2 * len(PLAN.periods) + 1
    for inc in (Incident("nope", 0, 1.0), Incident("up000", 99, 1.0),
                Incident("up000", 0, -1.0), Incident("up000", 0, math.nan)):
        with pytest.raises(ValueError) as ei:
            planned_records(PLAN, CIRC, [inc])
        assert "\n" not in str(ei.value)
