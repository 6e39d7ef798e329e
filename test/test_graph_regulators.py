"""AOC on a generated line end to end through ``run`` (issue 11 item 4 acceptance, small)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.integration

DURATION_S = 500.0
"""Simulated time of the run [s]: the three trains (125 s headway, ~100 s between stations)
have all left station 1 and the first has reached the terminus (was 900 s: the longer run
asserted nothing more)."""


def test_aoc_runs_on_a_generated_line_from_the_cache(ros_env: dict[str, str],
                                                     installed: Path, tmp_path: Path) -> None:
    """Weights trained into the cache for a generated 4-station line (a few epochs: this
    checks the plumbing, not the policy); ``run --train-regulator never`` finds them, the
    graph runs to the end with exit 0, no ATS timeout, and the KPIs name aoc as the
    regulator that sent the departure commands. The run is cut at ``DURATION_S``: by then
    every train has been dispatched by the ATS at an intermediate station."""
    from metro_atc.core.linegen import generate_line, scenario_yaml
    f = tmp_path / "gen.yaml"
    f.write_text(scenario_yaml(generate_line(21, n_stations=4, n_trains=3,
                                             stock="taipei_mrt_6car")))
    env = dict(ros_env, METRO_ATC_ATR_CACHE=str(tmp_path / "cache"))
    r = subprocess.run([sys.executable, "-m", "metro_atc", "train", "aoc", "--scenario",
                        str(f), "--cache", "--epochs", "5"], env=env, capture_output=True,
                       text=True, timeout=300, cwd=tmp_path)
    assert r.returncode == 0, r.stderr[-2000:]
    assert "epoch 5/5" in r.stderr
    cached = list((tmp_path / "cache").glob("*-aoc.pt"))
    assert len(cached) == 1
    out = tmp_path / "o"
    r = subprocess.run([sys.executable, "-m", "metro_atc", "run", "--scenario", str(f),
                        "--regulator", "aoc", "--train-regulator", "never", "--json",
                        "--no-plots", "--duration", str(DURATION_S), "--out", str(out)],
                       env=env, capture_output=True, text=True, timeout=600, cwd=tmp_path)
    assert r.returncode == 0, r.stderr[-3000:]
    k = json.loads(r.stdout.strip().splitlines()[-1])
    assert k["regulator"] == "aoc" and set(k["regulators_seen"]) == {"aoc"}
    assert k["ats_timeouts"] == 0 and k["atp_violations"] == 0
    assert k["planner"] != "none"
    # the cut run still has an ATS decision at an intermediate station for every train
    assert len(k["per_train"]) == 3 and all(int(t["departures"]) >= 2 for t in k["per_train"])
    log = (out / "logs" / "ats_regulator.log").read_text(errors="replace")
    assert "regulator 'aoc'" in log
