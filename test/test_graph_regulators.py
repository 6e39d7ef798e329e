"""AOC on a generated line end to end through ``run`` (small)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from background import job
from harness import DomainAllocator

from metro_atc.exit_codes import Exit

pytestmark = pytest.mark.integration

DURATION_S = 500.0
"""Simulated time of the run [s]: the three trains (125 s headway, ~100 s between stations)
have all left station 1 and the first has reached the terminus (was 900 s: the longer run
asserted nothing more)."""


@job("aoc_generated_line_run")
def _aoc_generated_line_run(tmp_path: Path) -> dict[str, Any]:
    """Train AOC weights into a cache for a generated line, then ``run`` with them (a
    background job on its own domain): both processes' results, the cached files, the
    run's out directory."""
    from metro_atc.core.linegen import generate_line, scenario_yaml
    f = tmp_path / "gen.yaml"
    f.write_text(scenario_yaml(generate_line(21, n_stations=4, n_trains=3,
                                             stock="taipei_mrt_6car")))
    with DomainAllocator().allocate() as dom:
        env = dict(os.environ, ROS_DOMAIN_ID=str(dom),
                   METRO_ATC_ATR_CACHE=str(tmp_path / "cache"))
        train = subprocess.run([sys.executable, "-m", "metro_atc", "train", "aoc", "--scenario",
                                str(f), "--cache", "--epochs", "5"], env=env,
                               capture_output=True, text=True, timeout=300, cwd=tmp_path)
        cached = list((tmp_path / "cache").glob("*-aoc.pt"))
        out = tmp_path / "o"
        run = None
        if train.returncode == 0:
            run = subprocess.run([sys.executable, "-m", "metro_atc", "run", "--scenario",
                                  str(f), "--regulator", "aoc", "--train-regulator", "never",
                                  # 5 epochs: possibly worse than the timetable (stated)
                                  "--accept-worse-regulator",
                                  "--json", "--no-plots", "--duration", str(DURATION_S),
                                  "--out", str(out)], env=env, capture_output=True, text=True,
                                 timeout=600, cwd=tmp_path)
    return {"train": train, "cached": cached, "run": run, "out": out}


@pytest.fixture
def aoc_generated_line_run(installed: Path, background_jobs: Any) -> dict[str, Any]:
    """The result of the job :func:`_aoc_generated_line_run`."""
    return dict(background_jobs.result("aoc_generated_line_run"))


def test_aoc_runs_on_a_generated_line_from_the_cache(aoc_generated_line_run: dict[str, Any]
                                                     ) -> None:
    """Weights trained into the cache for a generated 4-station line (a few epochs: this
    checks the plumbing, not the policy); ``run --train-regulator never`` finds them, the
    graph runs to the cut (exit 6, ``cut_at_s``), no ATS timeout, and the KPIs name aoc as
    the regulator that sent the departure commands. The run is cut at ``DURATION_S``: by
    then every train has been dispatched by the ATS at an intermediate station."""
    r = aoc_generated_line_run["train"]
    assert r.returncode == 0, r.stderr[-2000:]
    assert "epoch 5/5" in r.stderr
    assert len(aoc_generated_line_run["cached"]) == 1
    out = aoc_generated_line_run["out"]
    r = aoc_generated_line_run["run"]
    assert r.returncode == Exit.CUT, r.stderr[-3000:]
    k = json.loads(r.stdout.strip().splitlines()[-1])
    assert k["cut_at_s"] == pytest.approx(DURATION_S) and k["finished"] is False
    assert k["regulator"] == "aoc" and set(k["regulators_seen"]) == {"aoc"}
    assert k["ats_timeouts"] == 0 and k["atp_violations"] == 0
    assert k["planner"] != "none"
    # the cut run still has an ATS decision at an intermediate station for every train
    assert len(k["per_train"]) == 3 and all(int(t["departures"]) >= 2 for t in k["per_train"])
    log = (out / "logs" / "ats_regulator.log").read_text(errors="replace")
    assert "regulator 'aoc'" in log
