"""AOC and DHP critic-actor training (Lin 2010a, sec. 3, eq. 25-49; partly reconstructed).

Notation: critic lambda^(.|alpha), actor u^(.|beta), approximate model f^, stage cost U.

AOC (adaptive optimal control, Lin 2010a, sec. 3.C)
    * critic: lambda^(k+1) = C(x(k)) -- predicts the *step-ahead* costate from the current
      state, so no model is needed to produce it (Lin 2010a: "the critic predicts the
      step-ahead derivative values of the cost function without consulting the traffic
      model"; Sheu 2011 abstract: "the model for predicting the state for critic prediction is
      no longer necessary");
    * actor (eq. 49): u(k) = A(x(k), lambda^(k+1));
    * control deficiency (eq. 33): delta(k) = dU/du + (df^/du)^T lambda^(k+1);
    * policy impact (eq. 34, the garbled extraction ends in "- lambda^(k|alpha)"):
      eps(k) = dU/dx + (df^/dx)^T lambda^(k+1) + (du^/dx)^T delta(k) - lambda^(k), where
      lambda^(k) is the critic's prediction made one step earlier from x(k-1) and x(k) is the
      *measured* (truth) state; du^/dx is the total derivative of the policy, including the
      path through the critic input;
    * critic update (eq. 35-43 are on a missing page; reconstructed as the momentum
      gradient step of 1/2 |eps|^2 with the target held fixed):
      d_alpha <- rho_c d_alpha - mu_c (d lambda^(k)/d alpha)^T eps(k);
    * actor update (eq. 44/48): d_beta <- rho_a d_beta - mu_a (du^/dbeta)^T delta(k);
    * boundary conditions (eq. 28-32): lambda(0) = 0 is prescribed (there is no critic
      output for stage 0 to train), and the last prediction lambda^(K) is trained towards
      the end-point costate dPhi/dx(K) (eq. 32, free final state).

DHP (dual heuristic programming baseline, Lin 2010a, sec. 3/5 and Sheu 2011)
    * critic lambda^(k) = C(x(k)); its step-ahead value is obtained by *consulting the
      model*: lambda^(k+1) = C(f^(x(k), u(k))) (lambda(K) = dPhi/dx at the last stage);
    * delta(k) as above; critic target dU/dx + (df^/dx)^T lambda^(k+1) + (du/dx)^T delta(k)
      evaluated at the measured x(k); same momentum updates.

Both act on the truth system; training is batched (B episodes in parallel, gradients are
batch means), online (one critic and one actor update per stage), seeded and deterministic.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable, Dict, List, Optional, Tuple

import numpy as np
import torch

from metro_atc.core.atr.mlp import MLP
from metro_atc.core.atr.problems import AdpProblem, Episodes

Tensor = torch.Tensor


@dataclass
class TrainConfig:
    """Hyper-parameters of AOC/DHP training (learning rates mu, momentum rho of eq. 44/48)."""

    epochs: int = 100
    batches_per_epoch: int = 1
    batch: int = 200
    hidden: int = 20
    lr_critic: float = 0.01
    lr_actor: float = 0.01
    momentum: float = 0.9
    seed: int = 0
    time_budget_s: Optional[float] = None
    grad_clip: float = 10.0
    critic_jacobian: str = "model"
    lr_final_fraction: float = 1.0
    anchored: bool = False


@dataclass
class TrainResult:
    """Trained networks plus per-epoch history (cost-to-go, critic and actor errors)."""

    method: str
    critic: MLP
    actor: MLP
    history: Dict[str, List[float]] = field(default_factory=dict)
    seconds: float = 0.0
    steps: int = 0
    anchored: bool = False

    def agent(self, problem: AdpProblem) -> "Agent":
        """The trained policy bound to ``problem`` (with the anchoring it was trained with)."""
        return Agent(self.method, problem, self.critic, self.actor, self.anchored)


def squash(y: Tensor, scale: float, lo: Optional[Tensor], hi: Optional[Tensor]
           ) -> Tuple[Tensor, Tensor]:
    """Actor output transform and its slope: u = b tanh(scale y / b), b = hi (y >= 0) or -lo.

    Smooth, monotone, slope ``scale`` at 0 and bounded to [lo, hi]; linear if lo/hi is None.
    """
    if lo is None or hi is None:
        return scale * y, torch.full_like(y, scale)
    b = torch.where(y >= 0, hi.expand_as(y), (-lo).expand_as(y))
    th = torch.tanh(scale * y / b)
    return b * th, scale * (1.0 - th * th)


class Agent:
    """A critic-actor pair with the feature maps of one method ('aoc' or 'dhp')."""

    def __init__(self, method: str, problem: AdpProblem, critic: MLP, actor: MLP,
                 anchored: bool = False) -> None:
        """Bind networks to a problem (feature layout: [x * x_feat, (lam / lam_scale), extras]).

        ``anchored``: the policy is u(x) = A(x, .) - A(0, .), the actor's output relative to
        its output at the timetable (x = 0, same time-to-go; AOC: with the critic's costate
        at x = 0), so that u(0) = 0: a regulator that leaves an undisturbed timetable alone
        and acts on deviations only (a learnt constant offset cannot masquerade as
        regulation).  The squash keeps each term within the command range; the sum is
        clipped by the plant like any command.
        """
        if method not in ("aoc", "dhp"):
            raise ValueError(f"unknown ADP method {method!r}")
        self.method, self.p, self.critic, self.actor = method, problem, critic, actor
        self.anchored = bool(anchored)

    @classmethod
    def create(cls, method: str, problem: AdpProblem, hidden: int, seed: int,
               anchored: bool = False) -> "Agent":
        """Fresh seeded networks for ``method``."""
        p = problem
        n_ci = p.nx + p.n_extra
        n_ai = p.nx + p.n_extra + (p.nx if method == "aoc" else 0)
        critic = MLP(n_ci, hidden, p.nx, seed=seed)
        actor = MLP(n_ai, hidden, p.nu, seed=seed + 1)
        return cls(method, p, critic, actor, anchored)

    # --- forward pieces -------------------------------------------------------------
    def critic_fwd(self, x: Tensor, extra: Tensor) -> Tuple[Tensor, Tuple[Tensor, Tensor]]:
        """Critic output lambda (scaled back) and cache."""
        y, cache = self.critic.forward(torch.cat([x * self.p.x_feat, extra], 1))
        return y * self.p.lam_scale, cache

    def _actor_raw(self, x: Tensor, lam: Optional[Tensor], extra: Tensor
                   ) -> Tuple[Tensor, Tensor, Tuple[Tensor, Tensor]]:
        parts = [x * self.p.x_feat]
        if lam is not None:
            parts.append(lam / self.p.lam_scale)
        parts.append(extra)
        y, cache = self.actor.forward(torch.cat(parts, 1))
        u, dudy = squash(y, self.p.u_scale, self.p.u_lo, self.p.u_hi)
        return u, dudy, cache

    def actor_fwd(self, x: Tensor, lam: Optional[Tensor], extra: Tensor
                  ) -> Tuple[Tensor, Tensor, Tuple[Tensor, Tensor]]:
        """Actor output u, du/dy (output-transform slope) and cache (see ``anchored``)."""
        u, dudy, cache = self._actor_raw(x, lam, extra)
        if self.anchored:  # kept for actor_grad, which follows in the same stage
            self._anchor = self._origin(x, extra)
            u = u - self._anchor[0]
        return u, dudy, cache

    def _origin(self, x: Tensor, extra: Tensor
                ) -> Tuple[Tensor, Tensor, Tuple[Tensor, Tensor]]:
        """Actor output at the timetable x = 0 (the anchor), its slope and cache."""
        x0 = torch.zeros_like(x)
        lam0 = self.critic_fwd(x0, extra)[0].detach() if self.method == "aoc" else None
        return self._actor_raw(x0, lam0, extra)

    def actor_grad(self, cache: Tuple[Tensor, Tensor], dudy: Tensor, delta: Tensor) -> Tensor:
        """(du^/dbeta)^T delta summed over the batch, for the last :meth:`actor_fwd` call."""
        g = self.actor.grad_params(cache, delta * dudy)
        if self.anchored:
            _, dudy0, cache0 = self._anchor
            g = g - self.actor.grad_params(cache0, delta * dudy0)
        return g

    def act(self, x: Tensor, extra: Tensor) -> Tensor:
        """Policy u(k) for state x(k) (AOC: through the critic's lambda^(k+1))."""
        lam = self.critic_fwd(x, extra)[0] if self.method == "aoc" else None
        return self.actor_fwd(x, lam, extra)[0]

    # --- gradient pieces ------------------------------------------------------------
    def policy_vjp_x(self, a_cache: Tuple[Tensor, Tensor], gy: Tensor,
                     c_cache: Optional[Tuple[Tensor, Tensor]]) -> Tensor:
        """(du^/dx)^T g for g = du/dy * delta given as gy (total derivative for AOC)."""
        nx = self.p.nx
        gz = self.actor.vjp_input(a_cache, gy)
        gx = gz[:, :nx] * self.p.x_feat
        if self.method == "aoc" and c_cache is not None:
            # lam = lam_scale * C(z_c); actor input lam / lam_scale -> factors cancel
            gzc = self.critic.vjp_input(c_cache, gz[:, nx:2 * nx])
            gx = gx + gzc[:, :nx] * self.p.x_feat
        return gx

    def state(self) -> Dict[str, object]:
        """Serialisable state of both networks."""
        return {"method": self.method, "critic": self.critic.state(), "actor": self.actor.state(),
                "anchored": self.anchored}


class _Momentum:
    """Momentum update Delta theta_l = rho Delta theta_{l-1} - mu g (Lin 2010a, eq. 44/48)."""

    def __init__(self, net: MLP, lr: float, rho: float, clip: float) -> None:
        self.net, self.lr, self.rho, self.clip = net, lr, rho, clip
        self.delta = torch.zeros_like(net.theta)

    def step(self, grad: Tensor) -> None:
        n = float(torch.linalg.vector_norm(grad))
        if n > self.clip:
            grad = grad * (self.clip / n)
        self.delta.mul_(self.rho).add_(grad, alpha=-self.lr)
        self.net.theta.add_(self.delta)


def plant_closed_loop_vjp(agent: Agent, ep: Episodes, k: int, x: Tensor, lam: Tensor,
                          x_next: Tensor, h: float = 1e-6) -> Tensor:
    """M^T lam with M = dx(k+1)/dx(k) of the *plant* under the current policy.

    Black-box forward differences: the plant (truth simulator, same disturbance sample) is
    stepped from x(k) + h e_i with the policy re-evaluated there; no model is consulted.
    """
    p = agent.p
    b, nx = x.shape
    eye = torch.eye(nx, dtype=x.dtype)
    xp = (x.unsqueeze(0) + h * eye.unsqueeze(1)).reshape(nx * b, nx)
    ep_t = p.tile(ep, nx)
    xn = p.truth_step(ep_t, k, xp, agent.act(xp, p.extras(ep_t, k)))
    cols = (xn.reshape(nx, b, nx) - x_next.unsqueeze(0)) / h      # [i, b, :] = M[b][:, i]
    return torch.einsum("ibj,bj->bi", cols, lam)


def aoc_stage(agent: Agent, ep: Episodes, k: int, x: Tensor, critic_jacobian: str = "model"
              ) -> Dict[str, Tensor]:
    """AOC quantities at stage k for measured state x(k) (no parameter update).

    Returns lam_next (lambda^(k+1)), u, delta (eq. 33), the actor parameter gradient
    g_actor = (du^/dbeta)^T delta (batch mean, eq. 48), x_next (plant step) and lam_target(k),
    the right-hand side of the costate equation (eq. 30/34):

    * critic_jacobian="model" (default): the literal eq. 34 with the model's Jacobians,
      dU/dx + (df^/dx)^T lambda^(k+1) + (du^/dx)^T delta(k);
    * critic_jacobian="plant" (ablation): dU/dx + (du^/dx)^T dU/du + M^T lambda^(k+1) with
      M the plant's closed-loop sensitivity (:func:`plant_closed_loop_vjp`), so that the
      critic does not see the approximate model at all (one reading of the Lin 2010a
      conclusion "its outcomes were not biased by modeling error").
    """
    p = agent.p
    extra = p.extras(ep, k)
    lam1, c_cache = agent.critic_fwd(x, extra)
    u, dudy, a_cache = agent.actor_fwd(x, lam1, extra)
    du = p.du_du(ep, k, x, u)
    delta = du + p.fu_t(x, u, lam1)
    gy = delta * dudy
    b = x.shape[0]
    g_actor = agent.actor_grad(a_cache, dudy, delta) / b
    x_next = p.truth_step(ep, k, x, u)
    if critic_jacobian == "plant":
        lam_t = (p.du_dx(ep, k, x, u) + agent.policy_vjp_x(a_cache, du * dudy, c_cache)
                 + plant_closed_loop_vjp(agent, ep, k, x, lam1, x_next))
    elif critic_jacobian == "model":
        lam_t = (p.du_dx(ep, k, x, u) + p.fx_t(x, u, lam1)
                 + agent.policy_vjp_x(a_cache, gy, c_cache))
    else:
        raise ValueError(f"critic_jacobian must be 'plant' or 'model', got {critic_jacobian!r}")
    return {"lam_next": lam1, "u": u, "delta": delta, "g_actor": g_actor,
            "lam_target": lam_t, "x_next": x_next}


def critic_error_grad(agent: Agent, x_in: Tensor, extra: Tensor, target: Tensor
                      ) -> Tuple[Tensor, Tensor]:
    """Error eps = C(x_in) - target (scaled by 1/lam_scale) and grad of 1/2 mean |eps|^2."""
    lam, cache = agent.critic_fwd(x_in, extra)
    e = (lam - target) / agent.p.lam_scale
    return e, agent.critic.grad_params(cache, e) / x_in.shape[0]


def dhp_stage(agent: Agent, ep: Episodes, k: int, x: Tensor) -> Dict[str, Tensor]:
    """DHP quantities at stage k: u, model-predicted lambda^(k+1), delta, gradients, target."""
    p = agent.p
    extra = p.extras(ep, k)
    u, dudy, a_cache = agent.actor_fwd(x, None, extra)
    x_hat = p.model_step(x, u)
    if k + 1 >= p.horizon:
        lam1 = p.terminal_grad(ep, x_hat)
    else:
        lam1 = agent.critic_fwd(x_hat, p.extras(ep, k + 1))[0]
    delta = p.du_du(ep, k, x, u) + p.fu_t(x, u, lam1)
    gy = delta * dudy
    g_actor = agent.actor_grad(a_cache, dudy, delta) / x.shape[0]
    lam_t = p.du_dx(ep, k, x, u) + p.fx_t(x, u, lam1) + agent.policy_vjp_x(a_cache, gy, None)
    return {"lam_next": lam1, "u": u, "delta": delta, "g_actor": g_actor, "lam_target": lam_t,
            "x_next": p.truth_step(ep, k, x, u)}


def train(method: str, problem: AdpProblem, cfg: TrainConfig,
          agent: Optional[Agent] = None, verbose: bool = False,
          progress: Optional[Callable[[int, int, float, float], None]] = None
          ) -> TrainResult:
    """Train AOC or DHP on ``problem`` (truth system in the loop); deterministic for a seed.

    ``progress(epoch_done, epochs, cost, elapsed_s)`` is called after every epoch.
    """
    torch.manual_seed(cfg.seed)
    rng = np.random.default_rng(cfg.seed)
    ag = agent if agent is not None else Agent.create(method, problem, cfg.hidden, cfg.seed,
                                                      cfg.anchored)
    opt_c = _Momentum(ag.critic, cfg.lr_critic, cfg.momentum, cfg.grad_clip)
    opt_a = _Momentum(ag.actor, cfg.lr_actor, cfg.momentum, cfg.grad_clip)
    hist: Dict[str, List[float]] = {"cost": [], "critic_error": [], "actor_error": []}
    t_start = time.perf_counter()
    steps = 0
    k_total = problem.horizon
    for epoch in range(cfg.epochs):
        decay = cfg.lr_final_fraction ** (epoch / max(cfg.epochs - 1, 1))
        opt_c.lr, opt_a.lr = cfg.lr_critic * decay, cfg.lr_actor * decay
        cost_sum = crit_sum = act_sum = 0.0
        n_c = n_a = 0
        for _ in range(cfg.batches_per_epoch):
            ep = problem.sample(cfg.batch, rng)
            x = ep.x0.clone()
            prev: Optional[Tuple[Tensor, Tensor]] = None   # (x(k-1), extras(k-1)) for AOC
            cost = torch.zeros(x.shape[0], dtype=torch.float64)
            for k in range(k_total):
                if method == "aoc":
                    st = aoc_stage(ag, ep, k, x, cfg.critic_jacobian)
                    if prev is not None:          # k >= 1: lambda(0) = 0 is not trained
                        e, g_c = critic_error_grad(ag, prev[0], prev[1], st["lam_target"])
                        opt_c.step(g_c)
                        crit_sum += float((e * e).mean())
                        n_c += 1
                    prev = (x, problem.extras(ep, k))
                else:
                    st = dhp_stage(ag, ep, k, x)
                    e, g_c = critic_error_grad(ag, x, problem.extras(ep, k), st["lam_target"])
                    opt_c.step(g_c)
                    crit_sum += float((e * e).mean())
                    n_c += 1
                opt_a.step(st["g_actor"])
                act_sum += float((st["delta"] ** 2).mean())
                n_a += 1
                u = st["u"]
                cost = cost + problem.stage_cost(ep, k, x, u)
                x = st["x_next"]
                steps += 1
            if method == "aoc" and prev is not None:   # end-point condition eq. 32
                e, g_c = critic_error_grad(ag, prev[0], prev[1], problem.terminal_grad(ep, x))
                opt_c.step(g_c)
            cost = cost + problem.terminal_cost(ep, x)
            cost_sum += float(cost.mean())
        hist["cost"].append(cost_sum / cfg.batches_per_epoch)
        hist["critic_error"].append(crit_sum / max(n_c, 1) / problem.nx)
        hist["actor_error"].append(act_sum / max(n_a, 1) / problem.nu)
        if verbose:
            print(f"{method} epoch {epoch:3d} cost {hist['cost'][-1]:10.4f} "
                  f"critic {hist['critic_error'][-1]:.3e} actor {hist['actor_error'][-1]:.3e} "
                  f"t={time.perf_counter() - t_start:.1f}s", flush=True)
        if progress is not None:
            progress(epoch + 1, cfg.epochs, hist["cost"][-1], time.perf_counter() - t_start)
        if cfg.time_budget_s is not None and time.perf_counter() - t_start > cfg.time_budget_s:
            break
    return TrainResult(method, ag.critic, ag.actor, hist, time.perf_counter() - t_start, steps,
                       ag.anchored)


def rollout(agent: Agent, ep: Episodes, steps: Optional[int] = None
            ) -> Tuple[np.ndarray, np.ndarray]:
    """Run the trained policy on the truth system; returns states (K+1, B, nx), controls."""
    p = agent.p
    n = p.horizon if steps is None else steps
    x = ep.x0.clone()
    xs, us = [x.numpy().copy()], []
    for k in range(n):
        u = agent.act(x, p.extras(ep, k))
        us.append(u.numpy().copy())
        x = p.truth_step(ep, k, x, u)
        xs.append(x.numpy().copy())
    return np.stack(xs), np.stack(us)


def atr_train_config(seed: int = 0, epochs: int = 1500) -> TrainConfig:
    """Standard AOC/DHP configuration for the line regulation task (Lin 2010a, Exp. 2).

    Both methods use the same settings: 32 parallel episodes x 40 stages per epoch, 64
    hidden tanh units, learning rate 1e-3 decaying geometrically to 1e-4, momentum 0.9
    (eq. 44/48), literal eq. 34 critic target, anchored policy (u(0) = 0, see
    :class:`Agent`).  Without the anchor the actors learnt constant offsets of up to +-22 s
    at the timetable (holding punctual trains at some stations, cutting others) that the
    ATS in the closed loop applied to every train.
    """
    return TrainConfig(epochs=epochs, batch=32, hidden=64, lr_critic=1e-3, lr_actor=1e-3,
                       momentum=0.9, seed=seed, lr_final_fraction=0.1, critic_jacobian="model",
                       anchored=True)
