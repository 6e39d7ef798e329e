"""AOC/DHP gradient code (Lin 2010a, eq. 30-34, 44-48) against finite differences and autograd."""

import numpy as np
import pytest
import torch

from metro_atc.core.atr.blue_line import small_line
from metro_atc.core.atr.cost import CostWeights
from metro_atc.core.atr.mlp import MLP
from metro_atc.core.atr.problems import AtrProblem, LinearProblem, NarendraProblem
from metro_atc.core.atr.traffic import linear_model
from metro_atc.core.atr.training import (
    Agent, aoc_stage, critic_error_grad, dhp_stage, plant_closed_loop_vjp, squash)

torch.set_num_threads(1)
F64 = torch.float64


def _net(seed=0, skip=True):
    net = MLP(4, 6, 3, seed=seed, skip=skip, out_gain=1.0)
    g = torch.Generator().manual_seed(seed + 7)
    net.theta.copy_(torch.randn(net.theta.shape, generator=g, dtype=F64) * 0.5)
    return net


def _fd(fun, v, eps=1e-6):
    """Central finite-difference gradient of a scalar function of a flat tensor."""
    g = torch.zeros_like(v)
    for i in range(v.numel()):
        old = float(v[i])
        v[i] = old + eps
        fp = fun()
        v[i] = old - eps
        fm = fun()
        v[i] = old
        g[i] = (fp - fm) / (2 * eps)
    return g


@pytest.mark.parametrize("skip", [True, False])
def test_mlp_vjp_and_param_grad_match_fd_and_autograd(skip):
    net = _net(1, skip)
    z = torch.randn(5, 4, generator=torch.Generator().manual_seed(2), dtype=F64)
    gy = torch.randn(5, 3, generator=torch.Generator().manual_seed(3), dtype=F64)
    _, cache = net.forward(z)
    # parameters
    g_ana = net.grad_params(cache, gy)
    g_fd = _fd(lambda: float((net(z) * gy).sum()), net.theta)
    torch.testing.assert_close(g_ana, g_fd, rtol=1e-6, atol=1e-8)
    # inputs, against autograd
    zz = z.clone().requires_grad_(True)
    (net(zz) * gy).sum().backward()
    torch.testing.assert_close(net.vjp_input(cache, gy), zz.grad, rtol=1e-10, atol=1e-12)


def test_squash_slope_matches_fd_and_bounds():
    lo, hi = torch.tensor([-5.0, -11.0], dtype=F64), torch.tensor([60.0, 72.0], dtype=F64)
    y = torch.tensor([[-3.0, 0.7], [0.2, -0.01], [4000.0, -4000.0]], dtype=F64)
    u, s = squash(y, 0.5, lo, hi)
    up, _ = squash(y + 1e-6, 0.5, lo, hi)
    um, _ = squash(y - 1e-6, 0.5, lo, hi)
    torch.testing.assert_close(s, (up - um) / 2e-6, rtol=1e-6, atol=1e-9)
    assert torch.all(u >= lo) and torch.all(u <= hi)
    assert float(u[2, 0]) == pytest.approx(60.0) and float(u[2, 1]) == pytest.approx(-11.0)


def _atr_agent(method, seed=0, anchored=False):
    prob = AtrProblem(small_line(3), CostWeights(horizon=5))
    ag = Agent.create(method, prob, hidden=5, seed=seed, anchored=anchored)
    for net in (ag.critic, ag.actor):
        g = torch.Generator().manual_seed(seed + 11)
        net.theta.copy_(torch.randn(net.theta.shape, generator=g, dtype=F64) * 0.3)
    ep = prob.sample(4, np.random.default_rng(seed))
    x = ep.x0 + torch.randn(4, 3, generator=torch.Generator().manual_seed(5), dtype=F64) * 0.3
    return prob, ag, ep, x


@pytest.mark.parametrize("anchored", [False, True])
@pytest.mark.parametrize("method", ["aoc", "dhp"])
def test_actor_gradient_is_eq48(method, anchored):
    """g_actor = (du/dbeta)^T delta with delta held fixed (eq. 48): FD of mean(delta . u).

    Anchored policies u = A(x) - A(0) differentiate through both terms.
    """
    prob, ag, ep, x = _atr_agent(method, anchored=anchored)
    stage = aoc_stage if method == "aoc" else dhp_stage
    st = stage(ag, ep, 1, x)
    delta = st["delta"].clone()

    def surrogate():
        return float((stage(ag, ep, 1, x)["u"] * delta).sum() / x.shape[0])
    g_fd = _fd(surrogate, ag.actor.theta)
    torch.testing.assert_close(st["g_actor"], g_fd, rtol=1e-5, atol=1e-8)


@pytest.mark.parametrize("method", ["aoc", "dhp"])
def test_control_deficiency_is_eq33(method):
    prob, ag, ep, x = _atr_agent(method)
    st = (aoc_stage if method == "aoc" else dhp_stage)(ag, ep, 1, x)
    expected = prob.w.r * st["u"] + st["lam_next"] @ prob.b   # dU/du + B^T lambda(k+1)
    torch.testing.assert_close(st["delta"], expected)
    if method == "dhp":   # DHP consults the model for the next state
        u = st["u"]
        x_hat = x @ prob.a.T + u @ prob.b.T
        lam = ag.critic_fwd(x_hat, prob.extras(ep, 2))[0]
        torch.testing.assert_close(st["lam_next"], lam)
    else:                 # AOC predicts lambda(k+1) from x(k) only
        torch.testing.assert_close(st["lam_next"], ag.critic_fwd(x, prob.extras(ep, 1))[0])


@pytest.mark.parametrize("method", ["aoc", "dhp"])
def test_costate_target_uses_total_policy_derivative(method):
    """lam_target = dU/dx + A^T lam + (du/dx)^T delta, du/dx by FD of the whole policy."""
    prob, ag, ep, x = _atr_agent(method)
    stage = aoc_stage if method == "aoc" else dhp_stage
    st = stage(ag, ep, 1, x)
    delta, lam = st["delta"], st["lam_next"]
    pol_vjp = torch.zeros_like(x)
    for i in range(3):
        e = torch.zeros_like(x)
        e[:, i] = 1e-6
        up = ag.act(x + e, prob.extras(ep, 1))
        um = ag.act(x - e, prob.extras(ep, 1))
        pol_vjp[:, i] = ((up - um) / 2e-6 * delta).sum(1)
    expected = prob.w.q * x + lam @ prob.a + pol_vjp
    torch.testing.assert_close(st["lam_target"], expected, rtol=1e-6, atol=1e-8)


def test_critic_error_gradient_matches_fd():
    prob, ag, ep, x = _atr_agent("aoc")
    target = torch.randn(4, 3, generator=torch.Generator().manual_seed(9), dtype=F64)
    extra = prob.extras(ep, 0)
    _, g = critic_error_grad(ag, x, extra, target)

    def loss():
        e = (ag.critic_fwd(x, extra)[0] - target) / prob.lam_scale
        return float(0.5 * (e * e).sum() / x.shape[0])
    torch.testing.assert_close(g, _fd(loss, ag.critic.theta), rtol=1e-5, atol=1e-9)


def test_plant_closed_loop_sensitivity_on_linear_plant():
    """M^T lam = A^T lam + (du/dx)^T B^T lam for a linear plant (eq. 30 with the true model)."""
    a, b = linear_model(np.array([0.05, 0.1]))
    prob = LinearProblem(a, b, 1.0, 0.1, 4)
    ag = Agent.create("aoc", prob, hidden=4, seed=3)
    ep = prob.sample(3, np.random.default_rng(1))
    x = ep.x0
    lam = torch.randn(3, 2, generator=torch.Generator().manual_seed(4), dtype=F64)
    u = ag.act(x, prob.extras(ep, 0))
    got = plant_closed_loop_vjp(ag, ep, 0, x, lam, prob.truth_step(ep, 0, x, u))
    blam = lam @ prob.b
    pol = torch.zeros_like(x)
    for i in range(2):
        e = torch.zeros_like(x)
        e[:, i] = 1e-6
        d = (ag.act(x + e, prob.extras(ep, 0)) - ag.act(x - e, prob.extras(ep, 0))) / 2e-6
        pol[:, i] = (d * blam).sum(1)
    torch.testing.assert_close(got, lam @ prob.a + pol, rtol=1e-4, atol=1e-6)


def test_narendra_problem_equations():
    p = NarendraProblem(n_targets=2, hold=2)
    ep = p.with_reference(np.array([[1.0, 1.0, -2.0, -2.0, -2.0, -2.0, -2.0]]))
    x = torch.tensor([[2.0]], dtype=F64)
    u = torch.tensor([[0.5]], dtype=F64)
    assert float(p.truth_step(ep, 0, x, u)) == pytest.approx(2.0 / 5.0 + 0.125)
    assert float(p.model_step(x, u)) == pytest.approx(2.5)
    assert float(p.stage_cost(ep, 2, x, u)) == pytest.approx(0.5 * 16.0)
    assert float(p.terminal_grad(ep, x)) == pytest.approx(4.0)
    torch.testing.assert_close(p.extras(ep, 1), torch.tensor([[0.25, -0.5, -0.5]], dtype=F64))
