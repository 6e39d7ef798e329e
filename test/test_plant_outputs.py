"""Outputs: KPI JSON, events CSV, PNGs (plots.write_outputs) and the perf benchmark CLI."""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from pathlib import Path

from metro_atc.core.plant.driver import simple_driver
from metro_atc.core.plant.line import LineSim
from metro_atc.core.line.scenario import load_scenario
from metro_atc.plots import write_outputs

ROOT = Path(__file__).resolve().parent.parent


def test_write_outputs(tmp_path: Path) -> None:
    """KPIs JSON, one CSV row per event, train graph / speed / energy PNGs."""
    sim = LineSim(load_scenario("mini"), seed=0)
    while not sim.done:
        sim.step(simple_driver(sim))
    files = write_outputs(sim, tmp_path)
    names = {f.name for f in files}
    assert {"kpis.json", "events.csv", "train_graph.png", "speed_train_01.png",
            "speed_train_02.png", "energy.png"} <= names
    k = json.loads((tmp_path / "kpis.json").read_text())
    assert k["completed_trains"] == 2 and k["atp_violations"] == 0
    rows = list(csv.DictReader((tmp_path / "events.csv").open()))
    assert len(rows) == len(sim.event_log()) == 2 * 2 * sim.n_st
    assert rows[0]["train_id"] == "train_01" and rows[0]["kind"] == "arrival"
    for f in files:
        if f.suffix == ".png":
            assert f.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and f.stat().st_size > 10_000


def test_perf_bench_json_quick() -> None:
    """`python -m metro_atc.bench.perf --quick --json --no-graph` prints one JSON object.

    (The graph part runs the ROS graph; it is a benchmark, not a test.)
    """
    r = subprocess.run([sys.executable, "-m", "metro_atc.bench.perf", "--quick", "--json",
                        "--no-graph"],
                       cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    assert out["graph_rtf"] is None and out["core_rtf"] > 0
    assert out["trains"] >= 25 and out["sim_time_s"] == 900.0
    assert out["atp_violations"] == 0 and out["energy_balance_error"] < 1e-3
    day = out["day"]  # the service day's row: the first pull-outs, sensor samples read
    assert day["end_h"] == 6.25 and day["sensor_samples"] > 0 and day["plant_rtf_cpu"] > 0
    assert day["atp_violations"] == 0 and day["route_conflicts"] == 0


def test_recovery_kpis_follow_an_incident() -> None:
    """A 200 s hold makes departures late until the line recovers; none without it."""
    import dataclasses

    from metro_atc.core.line.scenario import IncidentSpec

    base = load_scenario("mini")
    quiet = dataclasses.replace(base, disturbances=dataclasses.replace(
        base.disturbances, departure_delay_prob=0.0))
    held = dataclasses.replace(quiet, incidents=[IncidentSpec(
        kind="hold", train="train_01", station=base.line.stations[0].code or "Alpha",
        duration_s=200.0)])
    out = {}
    for name, scn in (("quiet", quiet), ("held", held)):
        sim = LineSim(scn, seed=0)
        while not sim.done:
            sim.step(simple_driver(sim))
        out[name] = sim.kpis()
    assert out["quiet"]["late_departures"] == 0 and out["quiet"]["recovery_time_s"] == 0.0
    k = out["held"]
    # train_01 leaves every station but the terminus > 60 s late
    assert k["late_departures"] >= 3
    assert k["recovery_time_s"] > 0.0 and k["recovery_tolerance_s"] == 60.0
    assert k["max_delay_s"] >= 200.0 - 1e-6
