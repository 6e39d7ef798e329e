"""Bench commands (reduced runs): JSON shapes, plots, and the shipped default weights."""

import json

import numpy as np
import pytest

from metro_atc.bench import regulation, regulator_synthesis
from metro_atc.core.atr.lines import get_line
from metro_atc.core.atr.cost import CostWeights
from metro_atc.core.atr.evaluation import incident_scenario, kpis, simulate
from metro_atc.core.atr.problems import AtrProblem
from metro_atc.core.atr.regulators import default_weights_path, make_regulator


def test_regulator_synthesis_json(capsys):
    assert regulator_synthesis.main(["--json", "--epochs", "2"]) == 0
    out = json.loads(capsys.readouterr().out)
    for m in ("aoc", "dhp"):
        r = out["methods"][m]
        assert isinstance(r["converged"], bool)
        assert r["tracking_rmse"] >= 0.0 and np.isfinite(r["critic_error"])
        assert r["epochs"] == 2
    assert out["paper"]["aoc"]["converged"] is True
    assert "Narendra" in out["eq51_check"]


def test_regulation_json_and_plot(capsys, tmp_path):
    argv = ["--json", "--quick", "--epochs", "3", "--realisations", "1", "--out", str(tmp_path)]
    assert regulation.main(argv) == 0
    out = json.loads(capsys.readouterr().out)
    for m in ("lqr", "dhp", "aoc", "none"):
        r = out["methods"][m]
        for key in ("cost", "cost_std", "improvement_vs_lqr_pct", "worst_terminal_delay_s",
                    "running_time_dev_index", "headway_dev_index", "recovery_time_s"):
            assert np.isfinite(r[key]), (m, key)
    assert out["methods"]["lqr"]["improvement_vs_lqr_pct"] == 0.0
    # regulation beats doing nothing after a 180 s delay
    assert out["methods"]["lqr"]["cost"] < out["methods"]["none"]["cost"]
    assert out["paper"]["aoc_worst_terminal_delay_s"] == 104.0
    assert out["timing"]["aoc_decide_ms"] > 0.0
    for f in out["plots"]:
        assert (tmp_path / f.split("/")[-1]).stat().st_size > 1000


@pytest.mark.parametrize("method", ["aoc", "dhp"])
def test_shipped_weights_load_and_are_small(method):
    path = default_weights_path(method, "taipei_blue")
    assert path.stat().st_size < 200_000
    reg = make_regulator(method, get_line("taipei_blue"), weights_path=path)
    assert reg.meta["info"]["seed"] == 0 and "atr_train" in reg.meta["info"]["command"]
    x = np.zeros(23)
    x[0] = 180.0
    assert np.all(np.isfinite(reg.decide(x)))


def test_shipped_aoc_beats_lqr_on_the_reference_incident():
    """On the line it was trained for (the taipei_blue scenario, as the ATS node models it)."""
    line, w = get_line("taipei_blue"), CostWeights()
    p0 = AtrProblem(line, w).p0_np
    sc = incident_scenario(line, 180.0, 4242, w.horizon)
    cost = {}
    for m in ("none", "lqr", "aoc"):
        reg = make_regulator(m, line, w, default_weights_path(m, "taipei_blue")
                             if m == "aoc" else None)
        traj = simulate(line, reg, sc["x0"], sc["w"], w.horizon)
        cost[m] = kpis(traj, line, w, p0)["cost"]
    assert cost["aoc"] < cost["lqr"] < cost["none"]


def test_shipped_policies_leave_the_timetable_alone():
    """Anchored policies: no adjustment at the timetable, a speed-up for a late train."""
    line = get_line("taipei_blue")
    for m in ("aoc", "dhp"):
        reg = make_regulator(m, line, CostWeights(), default_weights_path(m, "taipei_blue"))
        assert np.allclose(reg.decide(np.zeros(line.n_stations)), 0.0, atol=1e-9), m
    aoc = make_regulator("aoc", line, CostWeights(), default_weights_path("aoc", "taipei_blue"))
    x = np.zeros(line.n_stations)
    x[5] = 120.0                                 # a train left station 5 two minutes late
    assert aoc.decide(x)[6] < -30.0              # its run into 6 + dwell there: shorter
