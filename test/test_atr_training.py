"""AOC/DHP training: optimum of a linear-quadratic case, determinism, weights round trip."""

import numpy as np
import pytest
import torch

from metro_atc.core.atr.blue_line import small_line
from metro_atc.core.atr.cost import CostWeights
from metro_atc.core.atr.problems import AtrProblem, LinearProblem, finite_horizon_lqr
from metro_atc.core.atr.regulators import load_weights, make_regulator, save_weights
from metro_atc.core.atr.traffic import linear_model
from metro_atc.core.atr.training import Agent, TrainConfig, rollout, train

torch.set_num_threads(1)


def _linear_case():
    a, b = linear_model(np.array([0.05, 0.1, 0.08]))
    horizon = 10
    prob = LinearProblem(a, b, 1.0, 0.1, horizon, p_final=np.eye(3))
    _, p = finite_horizon_lqr(a, b, 1.0, 0.1, horizon, np.eye(3))
    return prob, p[0]


@pytest.mark.parametrize("method", ["aoc", "dhp"])
def test_adp_reaches_the_riccati_optimum_when_model_is_exact(method):
    """With truth = model both critics are unbiased: cost within 2 % of the LQ optimum."""
    prob, p0 = _linear_case()
    cfg = TrainConfig(epochs=300, batch=64, hidden=16, lr_critic=3e-3, lr_actor=3e-3,
                      seed=0, lr_final_fraction=0.1)
    res = train(method, prob, cfg)
    ep = prob.sample(400, np.random.default_rng(123))
    xs, us = rollout(res.agent(prob), ep)
    cost = (0.5 * (xs[:-1] ** 2).sum(-1).sum(0) + 0.05 * (us ** 2).sum(-1).sum(0)
            + 0.5 * (xs[-1] ** 2).sum(-1))
    x0 = ep.x0.numpy()
    optimum = 0.5 * np.einsum("bi,ij,bj->b", x0, p0, x0)
    assert np.all(cost >= optimum - 1e-9)          # nothing beats the Riccati solution
    assert cost.mean() <= 1.02 * optimum.mean()
    # an untrained policy is far from it (the test can fail)
    xs0, us0 = rollout(Agent.create(method, prob, 16, 0), ep)
    assert (0.5 * (xs0 ** 2).sum()) / len(x0) > 1.2 * optimum.mean()


def test_training_is_deterministic_for_a_seed():
    prob = AtrProblem(small_line(4), CostWeights(horizon=6))
    cfg = TrainConfig(epochs=3, batch=4, hidden=8, seed=5)
    r1 = train("aoc", prob, cfg)
    r2 = train("aoc", prob, cfg)
    r3 = train("aoc", prob, TrainConfig(epochs=3, batch=4, hidden=8, seed=6))
    assert torch.equal(r1.actor.theta, r2.actor.theta)
    assert torch.equal(r1.critic.theta, r2.critic.theta)
    assert r1.history == r2.history
    assert not torch.equal(r1.actor.theta, r3.actor.theta)


@pytest.mark.parametrize("method", ["aoc", "dhp"])
def test_weights_round_trip(tmp_path, method):
    line = small_line(4)
    w = CostWeights(horizon=6)
    prob = AtrProblem(line, w)
    res = train(method, prob, TrainConfig(epochs=2, batch=4, hidden=8, seed=1))
    f = tmp_path / f"{method}.pt"
    save_weights(f, res.agent(prob), line, w, {"seed": 1})
    reg = make_regulator(method, line, weights_path=f)
    x = np.array([120.0, 3.0, -4.0, 0.0])
    ep = prob.sample(1, np.random.default_rng(0))
    direct = res.agent(prob).act(
        torch.from_numpy(x[None] / w.x_scale_s), prob.extras(ep, 0))
    np.testing.assert_allclose(reg.decide(x, 0), direct.numpy()[0] * w.x_scale_s)
    assert reg.name == method and reg.meta["info"]["seed"] == 1
    other = "dhp" if method == "aoc" else "aoc"
    with pytest.raises(ValueError, match="holds a"):
        make_regulator(other, line, weights_path=f)
    with pytest.raises(ValueError, match="stations"):
        load_weights(f, small_line(5))
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"not a torch file")
    with pytest.raises(ValueError):
        load_weights(bad, line)
    with pytest.raises(FileNotFoundError):
        load_weights(tmp_path / "missing.pt", line)
