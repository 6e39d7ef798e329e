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


def test_shipped_reference_reproduces() -> None:
    """The shipped optimal energy of one instance is what the oracle computes today."""
    from metro_atc.core.ato import coasting
    from metro_atc.core.ato.envelope import RunModel
    from metro_atc.core.ato.oracle import solve_oracle
    from metro_atc.core.bridge import ato_limits_for, track_for, train_for

    ref = json.loads((ttobench.data_dir() / ttobench.REFERENCE_FILE).read_text())
    rows = [v for v in ref["values"] if v["interstation"] == 1 and v["factor"] == 1.2]
    assert len(ref["values"]) == 13 * 3 and len(rows) == 1
    scn = ttobench.metro_scenario()
    train = train_for(scn)
    pos = [s.position_m for s in scn.line.stations]
    run = RunModel(train, track_for(scn), pos[1], pos[2], ato_limits_for(train))
    target = 1.2 * coasting.fotp(run, float("inf")).time_s
    assert target == pytest.approx(rows[0]["target_s"], abs=1e-2)
    e = solve_oracle(run, target, ref["instance"]["oracle_grid_m"]).energy_j / 3.6e6
    assert e == pytest.approx(rows[0]["energy_kwh"], rel=1e-4)
