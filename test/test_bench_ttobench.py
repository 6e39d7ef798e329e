"""``bench ttobench`` on one interstation: every planner reported against the optimum."""

from __future__ import annotations

import json

import pytest

from metro_atc.bench import ttobench


def test_bench_one_interstation(capsys: pytest.CaptureFixture[str]) -> None:
    """JSON output with all planners, gaps against the optimum and substation energies."""
    assert ttobench.main(["--json", "--runs", "1", "--factors", "1.2", "--grid-m", "8"]) == 0
    out = json.loads(capsys.readouterr().out)
    (r,) = out["runs"]
    pl = r["planners"]
    assert set(pl) == set(ttobench.PLANNERS)
    assert pl["optimum"]["gap_pct"] == 0.0 and pl["optimum"]["status"] == "optimal"
    eta_t = 0.70   # CN_Beijing_Subway efficiency traction
    for name, row in pl.items():
        # substation energy: traction / eta minus a regeneration credit
        assert row["substation_kwh"] <= row["energy_kwh"] / eta_t + 1e-9, name
    for name in ("dp", "ectp"):
        assert abs(pl[name]["time_error_s"]) <= 0.5, name
    assert pl["fotp"]["time_s"] < r["target_s"]
    assert pl["fotp"]["energy_kwh"] > pl["optimum"]["energy_kwh"]
