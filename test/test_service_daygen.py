"""Generated two-direction days (core/service/daygen.py) and the refusals of a bad day.

Small generated days (4 stations, dense light-metro lines, 20-minute days) with tail tracks
and scissors, one or two depots, with and without holds: every planned trip runs, every
train ends in the depot, no ATP or separation violation, no route conflict, no missed stop,
berthing within the platform-door window.  Bad input is refused in one line before
anything runs: a fleet too small for a period, a headway a terminus cannot turn trains at,
a depot at a station that does not exist or is not a terminus, a crossover on a platform.
"""

from __future__ import annotations

import copy
import dataclasses
from typing import Any, Dict

import pytest

from metro_atc.core.line.scenario import load_scenario, validate_scenario
from metro_atc.core.service.day import DayError, parse_day
from metro_atc.core.service.daygen import (GeneratedDay, day_failures, generate_day,
                                           run_generated_day)
from metro_atc.core.service.dayplant import service_day
from metro_atc.core.service.interlocking import scissors_terminus, tail_track_terminus
from metro_atc.core.service.loop import LoopError, build_loop

SMALL = dict(n_stations=4, spacing_kind="dense", stock="light_metro", period_min=(5, 10, 5))
"""Short days: 20 simulated minutes of service on a 4-station light-metro line."""
_DAYS: Dict[Any, GeneratedDay] = {}


def _gen(seed: int, incidents: bool = False) -> GeneratedDay:
    key = (seed, incidents)
    if key not in _DAYS:
        _DAYS[key] = generate_day(seed, incidents=incidents, **SMALL)  # type: ignore[arg-type]
    return _DAYS[key]


def test_generated_days_cover_layouts_and_depots() -> None:
    """The three small days: tail tracks, scissors, one and two depots, holds."""
    days = [_gen(0, True), _gen(1), _gen(2, True)]
    kinds = {t.layout.name.split("_")[0] for d in days for t in d.plan.termini}
    assert kinds == {"tail", "scissors"}
    assert {sum(t.depot is not None for t in d.plan.termini) for d in days} == {1, 2}
    assert all(d.holds for d in (days[0], days[2])) and not days[1].holds
    for d in days:
        assert d.plan.termini[0].depot is not None  # the up origin always has one
        assert len(d.plan.periods) == 3 and d.plan.fleet >= 2
        # headways the termini can turn trains at (the parse-time refusal's bound)
        for p in d.plan.periods:
            for t in d.plan.termini:
                assert p.headway_s >= t.layout.min_headway_s(t.layover_s)
    assert generate_day(0, incidents=True, **SMALL).table == days[0].table  # type: ignore


SHORT = (5.0, 10.0, 5.0)
"""Period lengths [min] of the drawn lines' short days (the line and layouts as drawn)."""


def _gen_drawn(seed: int, incidents: bool = False) -> GeneratedDay:
    """A day on the line drawn for ``seed`` (stations, stock, spacing drawn), 20 minutes."""
    key = ("drawn", seed, incidents)
    if key not in _DAYS:
        _DAYS[key] = generate_day(seed, incidents=incidents, period_min=SHORT)
    return _DAYS[key]


def test_scissors_the_loop_refuses_becomes_a_tail_track() -> None:
    """Line 37: scissors drawn at both ends, B's crossover would lie on G06's platform.

    Line 19: A's scissors would put its entry signal 9 m beyond G02's down stop point (the
    ATO berths there only with 10 m of authority beyond it: the train rested short of the
    platform, never called, never asked for A's route, and the day stood still).  Each
    refused scissors becomes a tail track; the other terminus keeps its scissors.
    """
    b37 = _gen_drawn(37).table["termini"]
    assert [t["layout"] for t in b37] == ["scissors", "tail_track"]
    a19 = _gen_drawn(19).table["termini"]
    assert [t["layout"] for t in a19] == ["tail_track", "scissors"]


@pytest.mark.parametrize("seed,incidents", [(0, True), (1, False), (2, True),
                                            ("drawn", 19), ("drawn", 37)])
def test_generated_day_runs_every_trip_safely(seed: Any, incidents: Any) -> None:
    """Small days; and short days on the drawn lines 19 and 37 (holds on 37)."""
    gd = _gen(seed, incidents) if seed != "drawn" else _gen_drawn(incidents, incidents == 37)
    res = run_generated_day(gd, max_wall_s=300.0)
    assert day_failures(res) == [], res.notes
    assert res.finished and res.trips_run == res.trips_planned > 0
    assert res.trains_in_depot == res.fleet
    assert res.atp_violations == res.separation_violations == 0
    assert res.route_conflicts == 0 and res.missed_stops == 0
    assert res.stop_errors_m and max(abs(e) for e in res.stop_errors_m) <= 0.30
    for (trip, station), hold in gd.holds.items():  # the holds happened
        # a hold is added to the call's scheduled departure (DayPlant's extra dwell): a
        # late train (line 37's first down trip, 34 s late) dwells less than the hold
        r = next(x for x in res.stops if x.trip_id == trip and x.station == station)
        assert r.dep_s >= r.sched_dep_s + hold
        assert r.dep_s - r.arr_s >= gd.scenario.passengers.min_dwell_s


# ----------------------------------------------------------------------------- refusals

def _table(**edit: Any) -> Dict[str, Any]:
    t = copy.deepcopy(_gen(1).table)
    for k, fn in edit.items():
        fn(t)
    return t


def test_fleet_too_small_is_refused_with_the_period_and_the_need() -> None:
    gd = _gen(1)
    need = service_day(gd.scenario, gd.plan, trip_times="plant").circ.fleet
    t = _table(f=lambda t: t.__setitem__("fleet", need - 1))
    plan = parse_day(t, "t.yaml", gd.line)
    with pytest.raises(DayError) as ei:
        service_day(gd.scenario, plan, trip_times="plant")
    msg = str(ei.value)
    assert "\n" not in msg and "period peak" in msg
    assert f"needs {need} trains" in msg and f"fleet is {need - 1}" in msg


def test_headway_a_terminus_cannot_turn_is_refused() -> None:
    """Berths x headway must hold the minimum turnback (Little's law); one line."""
    gd = _gen(1)
    t = _table()
    term = gd.plan.termini[1]  # a scissors: 2 berths
    assert len(term.layout.berths) == 2
    tb = 3.0 * t["periods"][1]["headway_s"]
    t["termini"][1]["min_turnback_s"] = tb
    with pytest.raises(DayError) as ei:
        parse_day(t, "t.yaml", gd.line)
    msg = str(ei.value)
    assert "\n" not in msg and "period early" not in msg and "period peak" in msg
    assert f"turns a train in {tb:.0f} s" in msg and f"needs a headway >= {tb / 2:.0f} s" in msg
    # at exactly the bound it is accepted
    t["termini"][1]["min_turnback_s"] = 2.0 * t["periods"][1]["headway_s"]
    parse_day(t, "t.yaml", gd.line)


@pytest.mark.parametrize("station,words", [("G99", "not a station"),
                                           ("G02", "not at terminus G01")])
def test_depot_off_a_terminus_is_refused(station: str, words: str) -> None:
    t = _table(d=lambda t: t["termini"][0].__setitem__("depot_station", station))
    with pytest.raises(DayError) as ei:
        parse_day(t, "t.yaml", _gen(1).line)
    assert words in str(ei.value) and station in str(ei.value)


def test_missing_depot_at_the_start_is_refused() -> None:
    """No depot at B and no down offset: B's first departure has no train; one line."""
    gd = _gen(1)
    t = _table(d=lambda t: t["termini"][1].update(depot=None, depot_station=None))
    with pytest.raises(DayError) as ei:
        service_day(gd.scenario, parse_day(t, "t.yaml", gd.line), trip_times="plant")
    msg = str(ei.value)
    assert "period early" in msg and "G04 has no depot connection" in msg


def _mini_with_first_gap(gap_m: float) -> Any:
    scn = load_scenario("mini")
    st = list(scn.line.stations)
    st[0] = dataclasses.replace(st[0], position_m=st[1].position_m - gap_m)
    return validate_scenario(dataclasses.replace(
        scn, line=dataclasses.replace(scn.line, stations=st)), "mini")


def test_crossover_on_a_platform_is_refused() -> None:
    """A scissors before terminus A lies on station 2's platform when the gap is short.

    The arrival crossover (3 x 60 m of diagonal) ends where A's 150 m platform begins, so the
    interstation must be >= 180 + 150 = 330 m (the train is 141 m, shorter than the platform);
    the entry signal's room asks 10 m more (the test after this one).
    """
    lays = (scissors_terminus(platform_m=150.0), tail_track_terminus(2, platform_m=150.0))
    with pytest.raises(LoopError) as ei:
        build_loop(_mini_with_first_gap(320.0), lays)
    msg = str(ei.value)
    assert "\n" not in msg and "terminus MN01 (scissors)" in msg
    assert "overlaps the platform of" in msg and "must be >= 330 m, it is 320 m" in msg
    build_loop(_mini_with_first_gap(341.0), lays)  # clear of the platform
    # a tail track turns beyond the platform: nothing of it lies before station 2
    build_loop(_mini_with_first_gap(320.0), lays[::-1])


def test_bench_line_days_arguments(capsys: pytest.CaptureFixture[str]) -> None:
    """No days: totals and exit 0; bad arguments: exit 2 before anything runs."""
    from metro_atc.bench.line_days import main
    from metro_atc.cli import main as cli_main
    assert main(["--count", "0"]) == 0
    assert "totals: days 0" in capsys.readouterr().out
    # python -m metro_atc bench lines --days: the same bench
    assert cli_main(["bench", "lines", "--days", "--count", "0"]) == 0
    out = capsys.readouterr().out
    assert "totals: days 0" in out and "coverage: terminus_a {}" in out
    with pytest.raises(SystemExit) as ei:
        cli_main(["bench", "lines", "--count", "0", "--days", "--stations", "2"])
    assert ei.value.code == 2
    assert "bench lines --days" in capsys.readouterr().err
    for bad in (["--jobs", "0"], ["--count", "-1"], ["--stations", "2"],
                ["--max-wall-s", "0"]):
        with pytest.raises(SystemExit) as ei:
            main(bad)
        assert ei.value.code == 2


def test_bad_holds_and_breakdowns_are_refused() -> None:
    """A hold of an unknown trip, at its destination or negative; a breakdown off the day.

    (A hold at the trip's origin is a delay of its first departure: accepted.)
    """
    from metro_atc.core.service.dayplant import Breakdown
    gd = _gen(1)
    last = len(gd.scenario.line.stations) - 1
    for holds, words in (({("up999", 1): 60.0}, "no such trip"),
                         ({("up000", last): 60.0}, "intermediate station"),
                         ({("up000", 1): -5.0}, "finite hold")):
        with pytest.raises(ValueError, match=words):
            service_day(gd.scenario, gd.plan, trip_times="plant", holds=holds)
    for bd, words in ((Breakdown("train_99", 0.0, 60.0), "not a train"),
                      (Breakdown("train_01", 0.0, 0.0), "duration_s"),
                      (Breakdown("train_01", 0.0, 60.0, 1, "nowhere"), "no section")):
        with pytest.raises(ValueError, match=words):
            service_day(gd.scenario, gd.plan, trip_times="plant", breakdowns=[bd])


def test_entry_signal_too_close_to_a_platform_is_refused() -> None:
    """A scissors's entry signal within the ATO's 10 m authority margin of a stop point.

    A's entry signal stands 180 m (crossover) + 150 m (platform) before its stop point: with
    a 335 m interstation it stands 5 m beyond station 2's down stop point (the crossover
    itself is clear of the platform), a train standing there has its authority end 5 m
    beyond the stop point and the ATO, which aims 10 m short of its authority, would rest
    short of the stop point.  The interstation must be >= 340 m.
    """
    lays = (scissors_terminus(platform_m=150.0), tail_track_terminus(2, platform_m=150.0))
    with pytest.raises(LoopError) as ei:
        build_loop(_mini_with_first_gap(335.0), lays)
    msg = str(ei.value)
    assert "\n" not in msg and "terminus MN01 (scissors): its entry signal" in msg
    assert "stands 5.0 m beyond the stop point of" in msg
    assert "must be >= 340 m, it is 335 m" in msg
    build_loop(_mini_with_first_gap(340.0), lays)


def test_generator_refuses_a_day_above_its_fleet_limit_naming_the_period() -> None:
    """A small day held to 3 trains: its peak needs 4; one line, the period and the need."""
    with pytest.raises(ValueError) as ei:
        generate_day(1, max_fleet=3, **SMALL)  # type: ignore[arg-type]
    msg = str(ei.value)
    assert "\n" not in msg and msg.startswith("generated day 1: ")
    assert "period peak: needs 4 trains" in msg and "(at most 3)" in msg


def test_generated_day_berths_in_the_door_window_and_fits_short_periods() -> None:
    """The plant takes a standstill as the arrival only within the +-0.30 m door window.

    With the plant's default 1.0 m, line 31 (heavy 8-car, 115 s peak) ended seven peak
    calls 0.7 m short: the train held behind the one ahead restarted 32 m short, came to
    rest 0.7 m short and the plant opened the doors there; within 0.30 m the ATO creeps on.
    Its 5-minute periods: the drawn 300 s transition is cut to half the shortest period
    (a transition as long as a period is refused by parse_day).
    """
    from metro_atc.core.closed_loop import STOP_WINDOW_M
    gd = _gen_drawn(31)
    assert gd.scenario.line.stop_tolerance_m == STOP_WINDOW_M == 0.30
    assert gd.table["transition_s"] == 150.0
    assert _gen(1).scenario.line.stop_tolerance_m == STOP_WINDOW_M
