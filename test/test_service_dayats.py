"""The ATS of a service day (core/service/dayats.py): both directions regulated, ROS-free.

- ``none`` decides exactly what the day plant decided before the ATS was a separate object:
  the records of a mini day equal, bit for bit, a golden recorded from the plant of that
  time (``test/data/golden/dayplant_mini_none.json``; re-record only when the day's
  decisions are meant to change: ``python test/test_service_dayats.py``);
- a regulated mini day (LQR on both directions' traffic models) with a 180 s delay at the
  first station runs every trip with no violation and changes departures;
- the decisions on a hand-built schedule: the timetable, the turnback link, a regulated
  hold behind a late trip; bad input is refused in one line.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import sys
from pathlib import Path
from typing import Any, Dict, List, Optional

import numpy as np
import pytest

from metro_atc.core.atr.lines import atr_line_for, get_line
from metro_atc.core.line.scenario import load_scenario
from metro_atc.core.service.dayats import (DayAts, DaySchedule, DirectionSchedule,
                                           first_trip_from, incident_report)
from metro_atc.core.service.dayplant import DayPlant, main as day_main
from metro_atc.core.service.regulation import direction_line

from test_service_dayplant import CODES, LAYOUTS, MIN_TURNBACK_S, _day

GOLDEN = Path(__file__).resolve().parent / "data" / "golden" / "dayplant_mini_none.json"
HOLD_S = 400.0


def _golden_case() -> Any:
    """The golden's day: scissors at MN01, tail track at MN04, one held intermediate call."""
    layouts = LAYOUTS["scissors_A_tail_B"]
    circ, _, _ = _day(layouts())
    blk = next(b for b in circ.blocks if len(b.trips) >= 2)
    first = blk.trips[0]
    station = 1 if first.origin == CODES[0] else 2
    _, _, dp = _day(layouts(), extra={(blk.train, first.trip_id, station): HOLD_S})
    return dp


def _rows(res: Any) -> Dict[str, List[List[Any]]]:
    return {"stops": [list(dataclasses.astuple(r)) for r in res.stops],
            "turnbacks": [list(dataclasses.astuple(r)) for r in res.turnbacks],
            "depot": [list(dataclasses.astuple(r)) for r in res.depot]}


def _same(got: Any, exp: Any) -> bool:
    if isinstance(exp, float) and math.isnan(exp):
        return isinstance(got, float) and math.isnan(got)
    return bool(got == exp)


def test_none_reproduces_the_day_before_the_ats_bit_for_bit() -> None:
    res = _golden_case().run()
    assert res.finished
    exp = json.loads(GOLDEN.read_text(encoding="utf-8"))
    got = _rows(res)
    for key in ("stops", "turnbacks", "depot"):
        assert len(got[key]) == len(exp[key]), key
        for g, e in zip(got[key], exp[key]):
            assert len(g) == len(e) and all(_same(a, b) for a, b in zip(g, e)), (key, g, e)


def _mini_lines() -> Dict[str, Any]:
    base = atr_line_for(load_scenario("mini"))
    return {d: direction_line(base, d, 1.0) for d in ("up", "down")}


def _delayed_day(regulator: str) -> Any:
    layouts = LAYOUTS["tail_A_scissors_B"]
    circ, trips, _ = _day(layouts())
    ups = sorted((t for t in trips if t.origin == CODES[0]), key=lambda t: t.departure_s)
    owner = {t.trip_id: b.train for b in circ.blocks for t in b.trips}
    late = ups[1]
    extra = {(owner[late.trip_id], late.trip_id, 0): 180.0}
    ats = (None if regulator == "none" else
           functools.partial(DayAts, regulator=regulator, lines=_mini_lines()))
    _, _, dp = _day(layouts(), extra=extra)
    if ats is not None:  # the same day with the regulated ATS
        dp = DayPlant(dp.loop, dp.circ, dp.termini, extra_dwell=dp.extra, ats=ats)
    return late, dp, dp.run()


def test_a_regulated_mini_day_runs_safely_and_changes_departures() -> None:
    late, dp0, none = _delayed_day("none")
    _, dp, lqr = _delayed_day("lqr")
    assert dp.ats.regulator == "lqr"
    for res in (none, lqr):
        assert res.finished and res.trips_run == res.trips_planned
        assert res.atp_violations == 0 and res.separation_violations == 0
        assert res.route_conflicts == 0 and res.missed_stops == 0, res.notes
        assert max(abs(e) for e in res.stop_errors_m) <= 0.30
        # the delay at the origin happened, after the timetable
        rep = incident_report(res.stops, res.turnbacks, late.trip_id)
        assert rep["departure_delay_s"] >= 180.0 - 1e-6
        for tb in res.turnbacks:  # the turnback link and the timetable hold
            assert tb.dep_s >= tb.arr_s + MIN_TURNBACK_S - 1e-6
            assert tb.dep_s >= tb.sched_dep_s - 1e-6
    dep0 = {(r.trip_id, r.station): r.dep_s for r in none.stops}
    dep1 = {(r.trip_id, r.station): r.dep_s for r in lqr.stops}
    assert dep0.keys() == dep1.keys()
    changed = [k for k in dep0 if math.isfinite(dep0[k]) and abs(dep0[k] - dep1[k]) > 0.2]
    assert changed, "the regulator changed no departure"


# ---------------------------------------------------------------- a hand-built schedule
def _schedule(line: Any, direction: str, n_trips: int = 6, headway_s: float = 105.0
              ) -> DirectionSchedule:
    """Trips of ``line`` (one direction's model) at its scheduled run and steady dwell."""
    n = line.n_stations
    dwell = line.dwell_fixed_s + line.c() * line.headway_s
    dep = np.full((n_trips, n), math.nan)
    arr = np.full((n_trips, n), math.nan)
    for m in range(n_trips):
        t = 25200.0 + m * headway_s
        dep[m, 0] = t
        for j in range(1, n):
            arr[m, j] = t = t + float(line.run_s[j - 1])
            if j < n - 1:
                dep[m, j] = t = t + float(dwell[j])
    run = np.tile(np.asarray(line.run_s, dtype=float), (n_trips, 1))
    st = tuple(range(n)) if direction == "up" else tuple(range(n - 1, -1, -1))
    return DirectionSchedule(direction, tuple(f"{direction}{m:03d}" for m in range(n_trips)),
                             st, line.station_codes[0], line.station_codes[-1], dep, arr,
                             run, np.asarray(line.run_min_s, dtype=float),
                             np.cumsum(np.r_[0.0, line.distance_m]))


@functools.lru_cache(maxsize=1)
def _taipei() -> Dict[str, Any]:
    base = get_line("taipei_blue")
    return {"up": direction_line(base, "up", 1.0), "down": direction_line(base, "down", 0.55)}


def _day_schedule(lines: Dict[str, Any]) -> DaySchedule:
    return DaySchedule({d: _schedule(ln, d) for d, ln in lines.items()}, 20.0)


def test_none_decides_the_timetable_and_the_turnback_link() -> None:
    lines = _taipei()
    sch = _day_schedule(lines)
    ats = DayAts(sch)
    up = sch.directions["up"]
    d = ats.first_departure("up001", 0.0)  # ready long before: the timetable
    assert d.departure_s == up.departure_s[1, 0] and d.station == 0
    assert d.running_s == up.running_s[1, 0]
    late = up.departure_s[1, 0] + 250.0  # the turnback link binds
    assert ats.first_departure("up001", late).departure_s == late
    ats.on_departure("up001", "up", 0, up.departure_s[1, 0] + 180.0)
    got = ats.on_arrival("up001", "up", 1, up.arrival_s[1, 1] + 170.0)
    assert got is not None
    assert got.departure_s == up.departure_s[1, 1] and math.isnan(got.dwell_limit_s)
    assert got.running_s == up.running_s[1, 1]
    dn = sch.directions["down"]  # station indices are the line's, whatever the direction
    last = len(dn.stations) - 1
    assert ats.first_departure("down000", 0.0).station == last
    ats.on_departure("down000", "down", last, dn.departure_s[0, 0])
    got = ats.on_arrival("down000", "down", last - 1, dn.arrival_s[0, 1])
    assert got is not None and got.departure_s == dn.departure_s[0, 1]
    assert ats.on_arrival("down000", "down", 0, dn.arrival_s[0, -1] + 60.0) is None


@pytest.mark.parametrize("name", ["lqr", "aoc"])
def test_a_regulator_hurries_the_late_trip(name: str) -> None:
    """Lin 2010a, Experiment 2 in miniature: trip 1 leaves the first station 180 s late.

    At its next platform the timetable sends it on at the scheduled run (and the
    passenger-driven dwell); the regulators cut its dwell and shorten its running-time
    target (a negative u_1 for the late train of the staggered state, saturated at the
    minimum dwell and the flat-out run for a delay this large).
    """
    lines = _taipei()
    sch = _day_schedule(lines)
    ats = DayAts(sch, name, lines)
    if name == "aoc":  # the shipped weights of each direction, found by hash
        assert set(ats.weights_used) == {"up", "down"}
        assert ats.weights_used["up"] != ats.weights_used["down"]
    none = DayAts(sch)
    up = sch.directions["up"]
    got = {}
    for a in (ats, none):
        a.on_departure("up000", "up", 0, up.departure_s[0, 0])
        a.on_departure("up001", "up", 0, up.departure_s[1, 0] + 180.0)
        got[a.regulator] = a.on_arrival("up001", "up", 1, up.arrival_s[1, 1] + 180.0)
    reg, tt = got[name], got["none"]
    assert reg is not None and tt is not None
    assert tt.departure_s == up.departure_s[1, 1] and math.isnan(tt.dwell_limit_s)
    assert tt.running_s == up.running_s[1, 1]
    assert reg.adjustment_s < -1.0 and math.isfinite(reg.dwell_limit_s)
    assert reg.dwell_limit_s < up.departure_s[1, 1] - up.arrival_s[1, 1] - 1.0
    assert reg.dwell_limit_s >= sch.min_dwell_s
    assert reg.running_s < tt.running_s - 1.0


def test_bad_input_is_refused_in_one_line() -> None:
    lines = _taipei()
    sch = _day_schedule(lines)

    def one_line(exc: pytest.ExceptionInfo[BaseException]) -> str:
        msg = str(exc.value)
        assert msg and "\n" not in msg
        return msg

    with pytest.raises(ValueError) as e:
        DayAts(sch, "pid", lines)
    assert "unknown regulator 'pid'" in one_line(e)
    with pytest.raises(ValueError) as e:  # a model of the other direction
        DayAts(sch, "lqr", {"up": lines["down"], "down": lines["down"]})
    assert "up traffic model runs BL23..BL01" in one_line(e)
    with pytest.raises(ValueError) as e:
        DayAts(sch, "lqr", {"up": lines["up"]})
    assert "no traffic model for the down direction" in one_line(e)
    # weights of the other direction: refused by the traffic-model hash
    up_w = DayAts(sch, "aoc", lines).weights_used["up"]
    with pytest.raises(ValueError) as e:
        DayAts(sch, "aoc", lines, weights={"down": up_w})
    assert "trained on another line" in one_line(e)
    with pytest.raises(ValueError) as e:
        DayAts(sch, "lqr", lines, weights={"down": up_w})
    assert "not by regulator lqr" in one_line(e)
    # a line with no weights of its own: said, never a fallback
    mini = _mini_lines()
    with pytest.raises(ValueError) as e:
        DayAts(_day_schedule(mini), "dhp", mini)
    assert "no weights trained on the" in one_line(e)
    # events: unknown trip, a station it does not call at, the wrong direction, no state
    ats = DayAts(sch)
    for args in (("nope", "up", 1, 1.0), ("up000", "up", 99, 1.0), ("up000", "down", 1, 1.0),
                 ("up000", "up", True, 1.0), ("up000", "up", 1, math.nan)):
        with pytest.raises(ValueError) as e:
            ats.on_arrival(*args)  # type: ignore[arg-type]
        one_line(e)
    with pytest.raises(ValueError):
        ats.first_departure("up000", math.inf)
    d = ats.on_arrival("up000", "up", 1, 25300.0)  # the state was left unchanged
    assert d is not None
    with pytest.raises(ValueError):  # a duplicate
        ats.on_arrival("up000", "up", 1, 25300.0)


def test_the_day_command_refuses_bad_flags(capsys: pytest.CaptureFixture[str]) -> None:
    assert day_main(["--delay-s", "180", "--delay-trip", "nope"]) == 2
    assert "no such trip" in capsys.readouterr().err
    assert day_main(["--delay-s", "-1"]) == 2
    assert day_main(["--delay-trip", "up010"]) == 2
    with pytest.raises(SystemExit):
        day_main(["--regulator", "pid"])


def test_the_first_trip_of_the_peak() -> None:
    from metro_atc.core.service.circulation import Trip
    trips = [Trip("up1", "A", "B", 100.0, 900.0), Trip("dn1", "B", "A", 200.0, 1000.0),
             Trip("up0", "A", "B", 50.0, 850.0), Trip("up2", "A", "B", 300.0, 1100.0)]
    assert first_trip_from(trips, "A", 60.0).trip_id == "up1"
    assert first_trip_from(trips, "B", 0.0).trip_id == "dn1"
    with pytest.raises(ValueError):
        first_trip_from(trips, "A", 400.0)


def test_the_incident_report_reads_the_records() -> None:
    from metro_atc.core.service.records import StopRecord, TurnbackRecord
    nan = math.nan
    stops = [StopRecord("t1", "u1", "up", 0, nan, 100.0, nan, 280.0),
             StopRecord("t1", "u1", "up", 1, 200.0, 230.0, 390.0, 400.0),
             StopRecord("t1", "u1", "up", 2, 330.0, nan, 600.0, nan),
             StopRecord("t1", "d1", "down", 2, nan, 800.0, nan, 820.0),
             StopRecord("t1", "d1", "down", 1, 900.0, 930.0, 915.0, 935.0),
             StopRecord("t1", "d1", "down", 0, 1030.0, nan, 1040.0, nan)]
    tbs = [TurnbackRecord("t1", "C", "u1", "d1", 600.0, 820.0, 330.0, 800.0, 120.0)]
    rep = incident_report(stops, tbs, "u1")
    assert rep["train"] == "t1" and rep["departure_delay_s"] == 180.0
    assert rep["last_departure_delay_s"] == 170.0 and rep["max_departure_delay_s"] == 180.0
    assert rep["arrival_delay_s"] == 270.0
    assert rep["turnback"] == {"terminus": "C", "terminal_delay_s": 270.0, "buffer_s": 350.0,
                               "carried_delay_s": 20.0}
    assert rep["next_trip"]["trip_id"] == "d1"
    assert rep["next_trip"]["departure_delay_s"] == 20.0
    assert rep["next_trip"]["arrival_delay_s"] == 10.0
    last = incident_report(stops, tbs, "d1")  # the train pulled in after it
    assert last["turnback"] is None and last["next_trip"] is None
    with pytest.raises(ValueError):
        incident_report(stops, tbs, "x9")


def _record(path: Optional[Path] = None) -> None:
    """Write the golden (only when the day's decisions are meant to change)."""
    res = _golden_case().run()
    out = {"case": "test_service_dayats._golden_case: mini line, scissors at MN01, "
                   "two-siding tail track at MN04, 300 s then 240 s headway, the first "
                   f"trip of the first two-trip block held {HOLD_S:.0f} s at an "
                   "intermediate call; timetable ATS",
           **_rows(res)}
    (path or GOLDEN).write_text(json.dumps(out) + "\n", encoding="utf-8")


if __name__ == "__main__":
    _record(Path(sys.argv[1]) if len(sys.argv) > 1 else None)
