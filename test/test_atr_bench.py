"""Bench commands (reduced runs): JSON shapes, plots, and the shipped default weights."""

import json

import numpy as np
import pytest

from metro_atc.bench import regulation, regulator_synthesis
from metro_atc.core.atr.blue_line import taipei_blue
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
    reg = make_regulator(method, taipei_blue())
    assert reg.meta["info"]["seed"] == 0 and "atr_train" in reg.meta["info"]["command"]
    x = np.zeros(23)
    x[0] = 180.0
    assert np.all(np.isfinite(reg.decide(x)))


def test_shipped_aoc_beats_lqr_on_the_reference_incident():
    line, w = taipei_blue(), CostWeights()
    p0 = AtrProblem(line, w).p0_np
    sc = incident_scenario(line, 180.0, 4242, w.horizon)
    cost = {}
    for m in ("none", "lqr", "aoc"):
        traj = simulate(line, make_regulator(m, line, w), sc["x0"], sc["w"], w.horizon)
        cost[m] = kpis(traj, line, w, p0)["cost"]
    assert cost["aoc"] < cost["lqr"] < cost["none"]
