"""The service day through the ROS graph: ``run --scenario taipei_blue_day``.

The run regulates both directions with ``lqr`` (the day plant's ATS in the simulator).

The graph's day is the ROS-free day: the simulator node steps the same
:class:`DayPlant` (pull-outs, routes, authorities before the fleet state; the plant step,
events, occupancy and grants after the ATOs' commands), the ATO nodes compute the efforts
(a new cab read from the states as the day plant reads it).  So the calls, turnbacks and
depot moves the graph writes are those of the ROS-free day run to the same instant, bit for
bit.  A day cut by ``--duration`` says so (exit 6, ``finished`` false, the trips not run);
options a day through the graph does not support are refused before anything starts.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from graph_runs import DAY, DAY_DURATION_S, DAY_REGULATOR
from harness import ROOT, DomainAllocator

from metro_atc.core.service.dayrun import day_plant, load_day_run
from metro_atc.core.service.records import write_records_csv
from metro_atc.exit_codes import Exit


@pytest.fixture(scope="module")
def rosfree(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """The ROS-free day run to the graph run's cut, its records written as the graph's."""
    dp = day_plant(load_day_run(DAY), regulator=DAY_REGULATOR)
    dp.start()
    res = dp.run(dp.t_start + DAY_DURATION_S)
    out = tmp_path_factory.mktemp("day_rosfree")
    write_records_csv(res.stops, out / "day_calls.csv")
    write_records_csv(res.turnbacks, out / "day_turnbacks.csv")
    write_records_csv(res.depot, out / "day_depot.csv")
    return {"res": res, "out": out, "dp": dp}


def test_a_cut_day_says_so(day_graph_run: dict[str, Any]) -> None:
    """Cut by --duration: exit 6, not finished, the trips not run counted."""
    r = day_graph_run
    assert r["code"] == Exit.CUT, r["stderr"][-3000:]
    k = r["kpis"]
    assert k["finished"] is False and k["cut_at_s"] is not None
    day = k["day"]
    assert 0 < day["trips_run"] < day["trips_planned"]
    assert f"{day['trips_planned'] - day['trips_run']} of {day['trips_planned']} trips " \
        "not run" in k["end"]
    assert day["route_conflicts"] == 0 and day["separation_violations"] == 0
    assert day["missed_stops"] == 0 and day["stops_outside_0p30_m"] == 0
    assert k["atp_violations"] == 0 and k["lockstep_misses"] == 0
    assert day["not_in_graph"], "what the graph's day leaves to the day plant is said"
    assert k["regulator"] == DAY_REGULATOR
    # the simulated time run counts from the day's first step, not from midnight
    assert k["sim_time_s"] - k["sim_start_s"] == pytest.approx(DAY_DURATION_S, abs=1.0)
    assert k["real_time_factor"] < 1e4


@pytest.mark.parametrize("name", ["day_calls.csv", "day_turnbacks.csv", "day_depot.csv"])
def test_the_graph_runs_the_rosfree_day(day_graph_run: dict[str, Any],
                                        rosfree: dict[str, Any], name: str) -> None:
    """The graph's records are the ROS-free day's, byte for byte (and not empty)."""
    got = (Path(day_graph_run["out"]) / name).read_bytes()
    want = (rosfree["out"] / name).read_bytes()
    assert got.count(b"\n") > 1, f"{name}: no records"
    assert got == want


def test_the_day_pictures_are_written(day_graph_run: dict[str, Any]) -> None:
    """The day's KPI tables and pictures are in the run's out directory."""
    out = Path(day_graph_run["out"])
    for f in ("day_kpis.json", "day_kpis.txt", "day_train_graph.png", "day_circulation.png",
              "day_kpi_table.png", "kpis.json"):
        assert (out / f).stat().st_size > 0, f


@pytest.mark.parametrize("extra,why", [
    (["--weights", "w.pt"], "shipped weights of each"),
    (["--single-process"], "multi-process graph"),
    (["--resume"], "not checkpointed"),
])
def test_unsupported_day_options_are_refused(extra: list[str], why: str, tmp_path: Path
                                             ) -> None:
    """Refused before anything starts: exit 2, one line naming the option."""
    with DomainAllocator().allocate() as dom:
        p = subprocess.run([sys.executable, "-m", "metro_atc", "run", "--scenario", DAY,
                            "--out", str(tmp_path / "o"), *extra], capture_output=True,
                           text=True, timeout=120, cwd=ROOT,
                           env=dict(os.environ, ROS_DOMAIN_ID=str(dom)))
    assert p.returncode == Exit.REFUSED, p.stderr
    lines = [ln for ln in p.stderr.splitlines() if "error" in ln]
    assert len(lines) == 1 and why in lines[0] and extra[0] in lines[0], p.stderr
