"""Optimal-control problems for the AOC/DHP trainers (Lin 2010a, Exp. 1 and Exp. 2).

Each problem exposes, batched in torch (float64), what Lin 2010a, sec. 3 needs: the *truth*
system the agent acts on, the *approximate model* f^ and its Jacobians (used by DHP for the
critic's next state and by both methods in eq. 33-34), the stage cost U and its gradients,
and the terminal (end-point) gradient of eq. 32.  The regulator works on a scaled state.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Dict, Optional

import numpy as np
import torch

from metro_atc.core.atr.blue_line import LineData
from metro_atc.core.atr.cost import CostWeights, terminal_matrix
from metro_atc.core.atr.traffic import (
    control_bounds, exponential_disturbance, linear_model, timetable_state, truth_step)

Tensor = torch.Tensor
_F64 = torch.float64


@dataclass
class Episodes:
    """A batch of training/test episodes: initial states and problem-specific data."""

    x0: Tensor
    data: Dict[str, Any] = field(default_factory=dict)


class AdpProblem:
    """Interface of a discrete-time optimal control problem for AOC/DHP (Lin 2010a, eq. 17-34).

    Attributes: nx, nu (dimensions), horizon K (steps per episode), n_extra (extra
    non-state network inputs), x_feat (state -> feature gain), lam_scale, u_scale
    (output scales of critic/actor) and u_lo / u_hi (admissible command range of the actor
    output, negative / positive, shape (nu,)), or None for an unbounded linear output.
    """

    nx: int
    nu: int
    horizon: int
    n_extra: int
    x_feat: float
    lam_scale: float
    u_scale: float
    u_lo: Optional[Tensor] = None
    u_hi: Optional[Tensor] = None

    def sample(self, batch: int, rng: np.random.Generator) -> Episodes:
        """Draw a batch of episodes."""
        raise NotImplementedError

    def tile(self, ep: Episodes, n: int) -> Episodes:
        """Episodes repeated n times (sample-major blocks: [all of ep] * n)."""
        data: Dict[str, Any] = {}
        for key, v in ep.data.items():
            if isinstance(v, torch.Tensor):
                data[key] = v.repeat(n, *([1] * (v.dim() - 1)))
            else:
                data[key] = np.tile(v, (n,) + (1,) * (v.ndim - 1))
        return Episodes(ep.x0.repeat(n, 1), data)

    def extras(self, ep: Episodes, k: int) -> Tensor:
        """Extra network inputs at stage k (references, time-to-go), shape (B, n_extra)."""
        raise NotImplementedError

    def truth_step(self, ep: Episodes, k: int, x: Tensor, u: Tensor) -> Tensor:
        """x(k+1) of the truth system."""
        raise NotImplementedError

    def model_step(self, x: Tensor, u: Tensor) -> Tensor:
        """x^(k+1) of the approximate model f^."""
        raise NotImplementedError

    def fx_t(self, x: Tensor, u: Tensor, lam: Tensor) -> Tensor:
        """(df^/dx)^T lam per sample."""
        raise NotImplementedError

    def fu_t(self, x: Tensor, u: Tensor, lam: Tensor) -> Tensor:
        """(df^/du)^T lam per sample."""
        raise NotImplementedError

    def stage_cost(self, ep: Episodes, k: int, x: Tensor, u: Tensor) -> Tensor:
        """U(x(k), u(k)) per sample, shape (B,)."""
        raise NotImplementedError

    def du_dx(self, ep: Episodes, k: int, x: Tensor, u: Tensor) -> Tensor:
        """dU/dx per sample."""
        raise NotImplementedError

    def du_du(self, ep: Episodes, k: int, x: Tensor, u: Tensor) -> Tensor:
        """dU/du per sample."""
        raise NotImplementedError

    def terminal_cost(self, ep: Episodes, x: Tensor) -> Tensor:
        """Phi(x(K)) per sample."""
        raise NotImplementedError

    def terminal_grad(self, ep: Episodes, x: Tensor) -> Tensor:
        """dPhi/dx(K): the end-point costate lambda(K) of Lin 2010a, eq. 32."""
        raise NotImplementedError


class NarendraProblem(AdpProblem):
    """Seed 000 Exp. 1: regulator synthesis for the Narendra-Parthasarathy plant.

    Truth (eq. 51): x(k+1) = x(k) / (1 + x(k)^2) + u(k)^3 -- the extraction is garbled; this
    is Example 3 ("Model III") of Narendra & Parthasarathy, IEEE Trans. Neural Networks
    1(1), 1990, whose test input sin(2 pi k/25) + sin(2 pi k/10) is also eq. 53.  Note that
    the origin is not unstable as the seed says: |x/(1+x^2)| < |x|, so the free plant decays
    (slowly near 0, where the linearisation has gain 1).
    Approximate model (eq. 52): x(k+1) = x(k) + u(k).
    Cost (eq. 50): J = 1/2 (x(K) - x*(K))^2 + sum_{k<K} 1/2 (x(k) - x*(k))^2, no control
    term.  Training samples: 100 desired states uniform in [-4, 4], each held ``hold`` steps.
    The actor output is bounded to |u| <= u_bound = 2 (|u^3| <= 8 covers every target).
    Network inputs besides x(k): the desired states x*(k), x*(k+1), x*(k+2).
    """

    def __init__(self, n_targets: int = 100, hold: int = 10, x_range: float = 4.0,
                 u_bound: float = 2.0) -> None:
        """Set up the sample layout (Lin 2010a, Exp. 1: 100 targets x 10 steps = 1000 steps)."""
        self.nx = self.nu = 1
        self.n_targets, self.hold, self.x_range = n_targets, hold, x_range
        self.horizon = n_targets * hold
        self.n_extra = 3
        self.x_feat = 1.0 / x_range
        self.lam_scale = 2.0
        self.u_scale = u_bound
        self.u_lo = torch.full((1,), -u_bound, dtype=_F64)
        self.u_hi = torch.full((1,), u_bound, dtype=_F64)

    def sample(self, batch: int, rng: np.random.Generator) -> Episodes:
        """Draw ``batch`` reference sequences (plus 3 padding steps) and x(0) = 0."""
        tgt = rng.uniform(-self.x_range, self.x_range, size=(batch, self.n_targets))
        ref = np.repeat(tgt, self.hold, axis=1)
        return self.with_reference(np.concatenate([ref, np.repeat(ref[:, -1:], 3, 1)], 1))

    def with_reference(self, ref: np.ndarray) -> Episodes:
        """Episodes for given references (B, K+3) (the last 3 columns only pad the window)."""
        b = ref.shape[0]
        return Episodes(torch.zeros(b, 1, dtype=_F64),
                        {"ref": ref, "ref_t": torch.from_numpy(np.ascontiguousarray(ref))})

    def _ref(self, ep: Episodes, k: int) -> Tensor:
        return ep.data["ref_t"][:, k:k + 1]  # type: ignore[return-value]

    def extras(self, ep: Episodes, k: int) -> Tensor:
        """References x*(k), x*(k+1), x*(k+2), scaled."""
        return ep.data["ref_t"][:, k:k + 3] * self.x_feat  # type: ignore[operator]

    def truth_step(self, ep: Episodes, k: int, x: Tensor, u: Tensor) -> Tensor:
        """Seed 000 eq. 51."""
        return x / (1.0 + x * x) + u ** 3

    def model_step(self, x: Tensor, u: Tensor) -> Tensor:
        """Seed 000 eq. 52."""
        return x + u

    def fx_t(self, x: Tensor, u: Tensor, lam: Tensor) -> Tensor:
        """Model Jacobian: df^/dx = 1."""
        return lam

    def fu_t(self, x: Tensor, u: Tensor, lam: Tensor) -> Tensor:
        """Model Jacobian: df^/du = 1."""
        return lam

    def stage_cost(self, ep: Episodes, k: int, x: Tensor, u: Tensor) -> Tensor:
        """1/2 (x - x*(k))^2 (eq. 50)."""
        e = x - self._ref(ep, k)
        return 0.5 * (e * e).sum(1)

    def du_dx(self, ep: Episodes, k: int, x: Tensor, u: Tensor) -> Tensor:
        """x - x*(k)."""
        return x - self._ref(ep, k)

    def du_du(self, ep: Episodes, k: int, x: Tensor, u: Tensor) -> Tensor:
        """Zero (eq. 50 has no control term)."""
        return torch.zeros_like(u)

    def terminal_cost(self, ep: Episodes, x: Tensor) -> Tensor:
        """1/2 (x(K) - x*(K))^2."""
        return self.stage_cost(ep, self.horizon, x, x)

    def terminal_grad(self, ep: Episodes, x: Tensor) -> Tensor:
        """x(K) - x*(K) (eq. 32)."""
        return x - self._ref(ep, self.horizon)


class LinearModelMixin:
    """Approximate model x^(k+1) = A x + B u (Lin 2010a, eq. 5) and its costate products.

    For problems that keep ``a`` (nx, nx) and ``b`` (nx, nu) as float64 tensors.
    """

    a: Tensor
    b: Tensor

    def model_step(self, x: Tensor, u: Tensor) -> Tensor:
        """Linear model A x + B u."""
        return x @ self.a.T + u @ self.b.T

    def fx_t(self, x: Tensor, u: Tensor, lam: Tensor) -> Tensor:
        """A^T lam."""
        return lam @ self.a

    def fu_t(self, x: Tensor, u: Tensor, lam: Tensor) -> Tensor:
        """B^T lam."""
        return lam @ self.b


class AtrProblem(LinearModelMixin, AdpProblem):
    """Seed 000 Exp. 2: automatic train regulation on a line (state = scaled deviations).

    State x~ = (t - T) / x_s (staggered departure deviations), control u~ = u / x_s.
    Truth: :func:`metro_atc.core.atr.traffic.truth_step` (saturation, crowding, knock-on,
    exponential departure delays).  Approximate model: x~(k+1) = A x~ + B u~ (Lin 2010a
    eq. 5 without any of these).  Cost: :mod:`metro_atc.core.atr.cost`.  Network extra
    input: time-to-go (K - k) / K (finite number of adjustable services).
    Episodes: an initial delay uniform in [delay_lo, delay_hi] s at ``delay_station``
    (station 0 = the first station), plus the exponential disturbances; a share
    ``anywhere_share`` of the episodes instead starts with a delay uniform in
    [0, delay_hi] s at a random station on top of +-``noise_s`` deviations everywhere, so
    that the trained policy is a feedback law for any state the ATS node meets (it decides
    at every station with the time-to-go of a fresh horizon, not only along the wave of an
    incident at the first station).
    The actor output is squashed into the admissible command range [lo_i, hi_i] of each
    station (minimum/maximum running time, minimum dwell, maximum holding: operating rules
    the ATS knows); the approximate model itself has no saturation.
    """

    def __init__(self, line: LineData, weights: CostWeights, delay_lo_s: float = 60.0,
                 delay_hi_s: float = 300.0, delay_station: int = 0,
                 disturbances: bool = True, anywhere_share: float = 0.5,
                 noise_s: float = 10.0) -> None:
        """Build the linear model, the terminal matrix and the steady timetable."""
        self.line, self.w = line, weights
        self.nx = self.nu = line.n_stations
        self.horizon = weights.horizon
        self.n_extra = 1
        self.x_feat = 1.0
        self.a_np, self.b_np = linear_model(line.c())
        self.p0_np = terminal_matrix(self.a_np, weights.q)
        self.a = torch.from_numpy(self.a_np)
        self.b = torch.from_numpy(self.b_np)
        self.p0 = torch.from_numpy(self.p0_np)
        self.lam_scale = 10.0
        self.u_scale = 10.0 / weights.x_scale_s
        lo, hi = control_bounds(line)
        self.u_lo = torch.from_numpy(lo / weights.x_scale_s)
        self.u_hi = torch.from_numpy(hi / weights.x_scale_s)
        self.delay_lo, self.delay_hi, self.delay_station = delay_lo_s, delay_hi_s, delay_station
        self.disturbances = disturbances
        if not 0.0 <= anywhere_share <= 1.0:
            raise ValueError(f"anywhere_share must lie in [0, 1], got {anywhere_share!r}")
        self.anywhere_share, self.noise_s = float(anywhere_share), float(noise_s)
        self.t0 = timetable_state(line, 0)
        self.t1 = timetable_state(line, 1)

    def sample(self, batch: int, rng: np.random.Generator) -> Episodes:
        """Initial delays and disturbance sequences (B, K+extra, N) [s]."""
        x0 = np.zeros((batch, self.nx))
        n_any = int(round(self.anywhere_share * batch))
        n_wave = batch - n_any
        x0[:n_wave, self.delay_station] = rng.uniform(self.delay_lo, self.delay_hi, size=n_wave)
        if n_any:
            st = rng.integers(0, self.nx - 1, size=n_any)
            x0[n_wave + np.arange(n_any), st] = rng.uniform(0.0, self.delay_hi, size=n_any)
            x0[n_wave:] += rng.uniform(-self.noise_s, self.noise_s, size=(n_any, self.nx))
        return self.with_initial(x0, rng)

    def with_initial(self, x0_s: np.ndarray, rng: np.random.Generator,
                     steps: Optional[int] = None) -> Episodes:
        """Episodes for given initial deviations x0 [s], shape (B, N)."""
        n_steps = self.horizon if steps is None else steps
        mean = self.line.disturbance_mean_s if self.disturbances else 0.0
        w = exponential_disturbance(rng, mean, (x0_s.shape[0], n_steps, self.nx))
        return Episodes(torch.from_numpy(x0_s / self.w.x_scale_s), {"w": w})

    def extras(self, ep: Episodes, k: int) -> Tensor:
        """Time-to-go (K - k) / K as a column."""
        b = ep.x0.shape[0]
        return torch.full((b, 1), max(self.horizon - k, 0) / self.horizon, dtype=_F64)

    def truth_step_np(self, ep: Episodes, k: int, x_s: np.ndarray, u_s: np.ndarray
                      ) -> np.ndarray:
        """Truth step on deviations in seconds (numpy), using the episode's disturbance."""
        w = ep.data["w"][:, k, :]
        t_next = truth_step(self.line, self.t0 + x_s, u_s, 0.0, w_dep=w)
        return t_next - self.t1

    def truth_step(self, ep: Episodes, k: int, x: Tensor, u: Tensor) -> Tensor:
        """Truth step on scaled deviations."""
        xs = self.w.x_scale_s
        nxt = self.truth_step_np(ep, k, x.numpy() * xs, u.numpy() * xs)
        return torch.from_numpy(nxt / xs)

    def stage_cost(self, ep: Episodes, k: int, x: Tensor, u: Tensor) -> Tensor:
        """1/2 q |x~|^2 + 1/2 r |u~|^2."""
        return 0.5 * self.w.q * (x * x).sum(1) + 0.5 * self.w.r * (u * u).sum(1)

    def du_dx(self, ep: Episodes, k: int, x: Tensor, u: Tensor) -> Tensor:
        """q x~."""
        return self.w.q * x

    def du_du(self, ep: Episodes, k: int, x: Tensor, u: Tensor) -> Tensor:
        """r u~."""
        return self.w.r * u

    def terminal_cost(self, ep: Episodes, x: Tensor) -> Tensor:
        """1/2 x~^T P_0 x~."""
        return 0.5 * ((x @ self.p0) * x).sum(1)

    def terminal_grad(self, ep: Episodes, x: Tensor) -> Tensor:
        """P_0 x~ (eq. 32)."""
        return x @ self.p0


class LinearProblem(LinearModelMixin, AdpProblem):
    """Finite-horizon linear-quadratic problem whose truth equals the model (sanity case).

    x(k+1) = A x + B u, U = 1/2 q|x|^2 + 1/2 r|u|^2, Phi = 1/2 x^T P_f x; initial states
    uniform in [-x0_range, x0_range]^n.  The optimum is the backward Riccati recursion
    (:func:`finite_horizon_lqr`), which AOC and DHP must approach.
    """

    def __init__(self, a: np.ndarray, b: np.ndarray, q: float, r: float, horizon: int,
                 p_final: Optional[np.ndarray] = None, x0_range: float = 1.0) -> None:
        """Store the matrices (numpy and torch)."""
        self.a_np, self.b_np = np.asarray(a, float), np.asarray(b, float)
        self.nx, self.nu = self.b_np.shape
        self.q, self.r, self.horizon = q, r, horizon
        self.pf_np = (np.zeros((self.nx, self.nx)) if p_final is None
                      else np.asarray(p_final, float))
        self.a, self.b = torch.from_numpy(self.a_np), torch.from_numpy(self.b_np)
        self.pf = torch.from_numpy(self.pf_np)
        self.n_extra = 1
        self.x_feat = 1.0 / x0_range
        self.lam_scale = x0_range
        self.u_scale = x0_range
        self.x0_range = x0_range

    def sample(self, batch: int, rng: np.random.Generator) -> Episodes:
        """Uniform initial states."""
        x0 = rng.uniform(-self.x0_range, self.x0_range, size=(batch, self.nx))
        return Episodes(torch.from_numpy(x0))

    def extras(self, ep: Episodes, k: int) -> Tensor:
        """Time-to-go (K - k) / K."""
        return torch.full((ep.x0.shape[0], 1), max(self.horizon - k, 0) / self.horizon,
                          dtype=_F64)

    def truth_step(self, ep: Episodes, k: int, x: Tensor, u: Tensor) -> Tensor:
        """A x + B u (truth = model)."""
        return self.model_step(x, u)

    def stage_cost(self, ep: Episodes, k: int, x: Tensor, u: Tensor) -> Tensor:
        """1/2 q|x|^2 + 1/2 r|u|^2."""
        return 0.5 * self.q * (x * x).sum(1) + 0.5 * self.r * (u * u).sum(1)

    def du_dx(self, ep: Episodes, k: int, x: Tensor, u: Tensor) -> Tensor:
        """q x."""
        return self.q * x

    def du_du(self, ep: Episodes, k: int, x: Tensor, u: Tensor) -> Tensor:
        """r u."""
        return self.r * u

    def terminal_cost(self, ep: Episodes, x: Tensor) -> Tensor:
        """1/2 x^T P_f x."""
        return 0.5 * ((x @ self.pf) * x).sum(1)

    def terminal_grad(self, ep: Episodes, x: Tensor) -> Tensor:
        """P_f x."""
        return x @ self.pf


def finite_horizon_lqr(a: np.ndarray, b: np.ndarray, q: float, r: float, horizon: int,
                       p_final: np.ndarray) -> tuple:
    """Backward Riccati recursion: gains K_k (u = -K_k x) and cost matrices P_0..P_K."""
    n, m = b.shape
    p = [np.zeros((n, n))] * (horizon + 1)
    gains = [np.zeros((m, n))] * horizon
    p[horizon] = np.asarray(p_final, float)
    for k in range(horizon - 1, -1, -1):
        pk1 = p[k + 1]
        gk = np.linalg.solve(r * np.eye(m) + b.T @ pk1 @ b, b.T @ pk1 @ a)
        gains[k] = gk
        acl = a - b @ gk
        p[k] = q * np.eye(n) + r * gk.T @ gk + acl.T @ pk1 @ acl
    return gains, p
