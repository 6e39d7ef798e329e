"""Golden ECTP plans: today's planner reproduces the recorded plans (``test/ato_golden.py``).

The golden file was recorded from the numpy planner before the compiled strategy kernel
(:mod:`metro_atc.core.ato.switching_kernel`) existed: 20 interstations (5 of the Blue
line, 3 on each of five generated lines: high-speed stock and steep grades among them), four
running-time targets each (one below the minimum: the flat-out fallback).  Every plan must
give the same coasting point, running time, energy, feasibility, sections and speed profile
to float round-off (relative 1e-9).  All plans run with the compiled kernel (the numpy
reference is gone; these numbers are its).
"""

from __future__ import annotations

import json
from typing import Any

import numpy as np
import pytest

import ato_golden
from metro_atc.core.ato.planner import plan_profile

RTOL = 1e-9
GOLDEN: list[dict[str, Any]] = json.loads(ato_golden.PATH.read_text())
CASES = {(name, a, b): (run, h) for name, a, b, run, h in ato_golden.cases()}


def _check(row: dict[str, Any], got: dict[str, Any]) -> None:
    where = f"{row['scenario']} {row['from']}->{row['to']} target {row['target_s']}"
    assert got["feasible"] == row["feasible"], where
    assert got["n"] == row["n"], where
    assert got["modes"] == row["modes"], where
    for key in ("coast_point_m", "running_time_s", "energy_j", "v_sum"):
        exp = row[key]
        if exp is None or not np.isfinite(exp):
            assert not np.isfinite(got[key]), f"{where}: {key}"
        else:
            assert got[key] == pytest.approx(exp, rel=RTOL, abs=1e-9), f"{where}: {key}"
    for key in ("section_bounds_m", "codes_mps", "v_samples"):
        np.testing.assert_allclose(got[key], row[key], rtol=RTOL, atol=1e-9,
                                   err_msg=f"{where}: {key}")


def _replan(row: dict[str, Any]) -> dict[str, Any]:
    run, h = CASES[(row["scenario"], row["from"], row["to"])]
    assert h == row["h_m"]
    return ato_golden.summary(plan_profile(run, row["target_s"], "ectp", None, h_m=h))


def test_golden_covers_fallbacks_and_coasting() -> None:
    """The golden set has flat-out fallbacks and coasting plans on every scenario."""
    assert len(GOLDEN) == 4 * len(CASES) >= 80
    assert sum(not r["feasible"] for r in GOLDEN) >= len(CASES)
    for name, _ in ato_golden.SCENARIOS:
        assert any(r["scenario"] == name and r["feasible"] and 2 in r["modes"] for r in GOLDEN)


@pytest.mark.parametrize("name", [n for n, _ in ato_golden.SCENARIOS])
def test_plans_equal_golden(name: str) -> None:
    """Every golden plan of a scenario."""
    for row in GOLDEN:
        if row["scenario"] == name:
            _check(row, _replan(row))
