"""The synthetic days of ``bench day-scale`` as period tables (no graph, no stepping)."""

from __future__ import annotations

from pathlib import Path

import pytest

from metro_atc.bench import day_scale
from metro_atc.core.line.scenario import load_scenario
from metro_atc.core.service.day import load_day
from metro_atc.core.service.dayplant import service_day
from metro_atc.core.service.dayrun import day_table


@pytest.mark.parametrize("n", [10, 120])
def test_written_table_loads_back_as_the_synthetic_day(tmp_path: Path, n: int) -> None:
    """The table loads with ``load_day``: one period of the cycle's headway, shipped termini."""
    path = day_scale.synthetic_table(n, 300.0, tmp_path / f"day_scale_{n}_periods.yaml")
    assert day_table(str(path)) == path  # run --scenario PATH takes it as a day
    plan, shipped = load_day(path), load_day(None)
    assert plan.name == f"day_scale_{n}"
    assert plan.termini == shipped.termini
    assert plan.line.name == shipped.line.name
    assert (plan.transition_s, plan.down_offset_s) == (shipped.transition_s,
                                                       shipped.down_offset_s)
    assert plan.fleet == max(4 * n, shipped.fleet)
    (p,) = plan.periods
    # the headway: the shipped day's cycle (its first trips) over the trains
    probe = service_day(load_scenario("taipei_blue"), shipped, trip_times="plant")
    assert p.headway_s == max(day_scale.MIN_HEADWAY_S, round(day_scale.cycle_s(probe) / n))
    dp = day_scale.synthetic_day(path)
    cyc = day_scale.cycle_s(dp)
    assert p.start_s == day_scale.START_S
    # the period covers the first cycle, the window and a cycle's margin
    t_on, t_off = day_scale.window_s_of(dp, 300.0)
    assert p.end_s >= day_scale.START_S + 2.0 * cyc + 300.0 > t_off > t_on
    # the headways the circulation runs from each terminus are the period's
    for term in plan.termini:
        deps = sorted(t.departure_s for b in dp.circ.blocks for t in b.trips
                      if t.origin == term.station and t.departure_s < t_on)
        assert {round(b - a, 6) for a, b in zip(deps, deps[1:])} == {p.headway_s}


def test_trains_beyond_a_table_fleet_refused() -> None:
    """A target whose fleet no period table can hold is refused in one line."""
    with pytest.raises(SystemExit):
        day_scale.main(["--trains", str(day_scale.MAX_TRAINS + 1), "--no-rss"])


def test_graph_window_must_be_whole_progress_periods(capsys: pytest.CaptureFixture[str]) -> None:
    """The graph's window is timed between progress lines: another window is refused."""
    with pytest.raises(SystemExit):
        day_scale.main(["--graph", "--window-s", "300", "--no-rss"])
    assert "whole progress periods" in capsys.readouterr().err
