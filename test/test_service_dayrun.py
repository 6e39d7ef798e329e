"""A service day named like a scenario (core/service/dayrun.py) and the rules the graph's day
shares with the ROS-free one: the new cab read from the states (core/ato/cab.py) and the
held departure (core/plant/stations.HELD_S)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from metro_atc.core.ato.cab import CabWatch
from metro_atc.core.line.scenario import ScenarioError
from metro_atc.core.plant.stations import HELD_S
from metro_atc.core.plant.views import fleet_state_rows
from metro_atc.core.service.day import day_file
from metro_atc.core.service.dayrun import (day_names, day_plant, day_table, last_arrival_s,
                                           load_day_run, load_run_scenario)


def test_the_shipped_day_is_found_by_name_and_path() -> None:
    """taipei_blue_day is a day; a one-way scenario (by name or file) is not."""
    assert "taipei_blue_day" in day_names()
    table = day_file()
    assert day_table("taipei_blue_day") == table
    assert day_table(str(table)) == Path(str(table))
    assert day_table("taipei_blue") is None
    scn_file = Path(__file__).resolve().parent.parent / "metro_atc" / "scenarios" / "mini.yaml"
    assert day_table(str(scn_file)) is None


def test_the_ato_nodes_scenario_is_the_fleet_plants() -> None:
    """The train ids an ATO node of the day hosts are the simulator's slots, in order."""
    run = load_day_run("taipei_blue_day")
    dp = day_plant(run)
    scn = load_run_scenario("taipei_blue_day")
    assert list(scn.train_ids) == list(dp.sim.train_ids)
    assert len(scn.train_ids) == len({b.train for b in dp.circ.blocks}) == len(dp.trains)
    assert scn.line == dp.sim.scn.line
    assert last_arrival_s(run) == max(t.arrival_s for b in dp.circ.blocks for t in b.trips)
    assert load_run_scenario("mini").name == "mini"


def test_bad_day_names_and_tables_are_refused_in_one_line(tmp_path: Path) -> None:
    """Not a day, a broken period table, unknown trip times: one line each."""
    with pytest.raises(ValueError, match="not a service day"):
        load_day_run("mini")
    with pytest.raises(ValueError, match="trip_times"):
        load_day_run("taipei_blue_day", trip_times="fast")
    bad = tmp_path / "day.yaml"
    bad.write_text("name: x\nline: taipei_blue\nperiods: []\ntermini: []\n")
    with pytest.raises(ScenarioError) as exc:
        load_run_scenario(str(bad))
    assert "\n" not in str(exc.value)


def test_a_new_cab_at_pull_out_and_at_each_new_lap() -> None:
    """First state, a gap in the steps (back from the depot), a stop index going back."""
    cab = CabWatch()
    seq = [(10, 0, True), (11, 0, False), (12, 3, False), (13, 3, False),  # running
           (14, 0, True),                                                   # a new lap
           (15, 1, False), (40, 5, True),                                   # depot, back
           (41, 5, False), (41, 5, True)]                                   # not the next
    assert [cab.new_cab(k, j) for k, j, _ in seq] == [want for _, _, want in seq]


def test_a_held_train_has_no_departure_time_in_its_state() -> None:
    """A departure at HELD_S holds the train: its state says NaN (no departure decided)."""
    dp = day_plant(load_day_run("taipei_blue_day"))
    dp.start()
    while not any(tr.in_service for tr in dp.trains):
        dp.end_step(dp.control(dp.begin_step()))
    rows = np.array([tr.i for tr in dp.trains if tr.in_service], dtype=np.intp)
    j = dp.sim.fleet.cur_station[rows]
    assert np.all(dp.sim.stations.cmd_dep[rows, j] >= HELD_S)
    dep = fleet_state_rows(dp.sim, rows)["departure_time_s"]
    assert all(math.isnan(x) for x in dep)


def test_a_period_tables_tsrs_reach_the_loop(tmp_path: Path) -> None:
    """``tsrs`` per track in a period table: on the loop where that track runs; bad ones
    refused in one line."""
    import yaml

    from metro_atc.core.line.scenario import load_scenario
    raw = yaml.safe_load(day_file().read_text())
    c = [s.position_m for s in load_scenario("taipei_blue").line.stations]
    good = {"track": "down", "start_m": c[3], "end_m": c[3] + 500.0, "limit_kmh": 40,
            "from_h": 7, "to_h": 9}
    raw["tsrs"] = [good]
    raw["track_curves"] = [{"track": "up", "start_m": c[2], "end_m": c[2] + 200.0,
                            "radius_m": 300}]
    f = tmp_path / "day.yaml"
    f.write_text(yaml.safe_dump(raw))
    scn = load_run_scenario(str(f))
    assert [(round(x.end_m - x.start_m, 6), x.radius_m) for x in scn.line.curves
            if x.start_m < c[-1] - c[0]] == [(200.0, 300.0)]  # the up track's own curve
    (z,) = scn.line.temporary_speed_limits
    assert z.limit_kmh == 40.0 and (z.from_s, z.to_s) == (7 * 3600.0, 9 * 3600.0)
    assert z.end_m - z.start_m == pytest.approx(500.0)
    assert z.start_m > c[-1] - c[0]  # on the down half of the loop
    for bad, why in (({"track": "both"}, "up or down"), ({"end_m": c[3] - 1.0}, "start_m <")):
        raw["tsrs"] = [dict(good, **bad)]
        f.write_text(yaml.safe_dump(raw))
        with pytest.raises(ScenarioError, match=why) as exc:
            load_run_scenario(str(f))
        assert "\n" not in str(exc.value)


def test_the_status_reads_each_record_once() -> None:
    """The running figures of the graph's day status equal those of the whole lists."""
    from metro_atc.nodes.sim_day import _Seen
    seen = _Seen()
    assert math.isnan(seen.err_max_m) and math.isnan(seen.late_max_s)
    seen.take([0.1, 0.4], [5.0])
    seen.take([], [])
    seen.take([0.2, 0.31], [-3.0, 7.5])
    assert (seen.errors, seen.turnbacks) == (4, 3)
    assert (seen.err_max_m, seen.err_out, seen.late_max_s) == (0.4, 2, 7.5)
