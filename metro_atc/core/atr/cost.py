"""Finite-service schedule-deviation cost for ATR (Lin 2010a, eq. 17-22, 45, 32; reconstructed).

Seed 000 eq. 17-22 are on a missing page.  From the surviving text ("finite-degree-of-freedom
infinite-horizon cost function ... measure traffic regularity in terms of schedule
deviation", the recurrence eq. 45 J(k) = U(k) + J(k+1) with J(K) = J*(K), the end-point
condition eq. 32 and the LQR baseline "linear model, quadratic cost") we use:

    J = sum_{k=0}^{K-1} U(x(k), u(k)) + Phi(x(K)),
    U = 1/2 x~^T Q x~ + 1/2 u~^T R u~,      x~ = x / x_s,  u~ = u / x_s,
    Phi = 1/2 x~(K)^T P_0 x~(K),   P_0 = A^T P_0 A + Q   (discrete Lyapunov),

i.e. K adjustable services ("finite degree of freedom"), after which the line runs free
(u = 0) for ever ("infinite horizon"); Phi is the exact free-running tail cost of the linear
model, and eq. 32 gives the costate boundary lambda(K) = P_0 x~(K).

Weights (state which and why): Q = q I with q = 1 — every departure deviation at every
station counts equally (regularity for all passengers); R = r I with r = 0.1 — a small
penalty on running/dwell adjustments (passenger comfort, energy) so that regulation is not
bang-bang, while schedule deviation still dominates; x_s = 60 s makes the cost read in
minutes^2.  The seed gives no numeric weights in the extracted pages.

Energy-aware option (Sheu 2011): our extraction of Sheu 2011 holds only the dissertation
abstract (no energy model), and the energy-running-time curve belongs to the ATO core, so the
energy term is not implemented here.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class CostWeights:
    """Weights of the ATR cost (see module docstring); units: q, r [-], x_scale_s [s]."""

    q: float = 1.0
    r: float = 0.1
    x_scale_s: float = 60.0
    horizon: int = 40

    def __post_init__(self) -> None:
        """Validate the weights."""
        for name in ("q", "r", "x_scale_s"):
            v = getattr(self, name)
            if not np.isfinite(v) or v <= 0.0:
                raise ValueError(f"cost weight {name} must be finite and > 0, got {v!r}")
        if self.horizon < 1:
            raise ValueError(f"horizon must be >= 1 service, got {self.horizon!r}")


def terminal_matrix(a: np.ndarray, q: float) -> np.ndarray:
    """P_0 with P_0 = A^T P_0 A + q I: free-running tail cost of the linear model."""
    from scipy.linalg import solve_discrete_lyapunov  # here: the ATS's start-up skips it
    n = a.shape[0]
    p = solve_discrete_lyapunov(a.T, q * np.eye(n))
    return 0.5 * (p + p.T)


def stage_cost(x_s: np.ndarray, u_s: np.ndarray, w: CostWeights) -> np.ndarray:
    """U(x, u) (Lin 2010a, eq. 17, reconstructed) for deviations x, u [s]; shape (...,)."""
    xt = np.asarray(x_s) / w.x_scale_s
    ut = np.asarray(u_s) / w.x_scale_s
    return 0.5 * w.q * np.sum(xt * xt, axis=-1) + 0.5 * w.r * np.sum(ut * ut, axis=-1)


def terminal_cost(x_s: np.ndarray, p0: np.ndarray, w: CostWeights) -> np.ndarray:
    """Phi(x(K)) = 1/2 x~^T P_0 x~ for deviation x [s]; shape (...,)."""
    xt = np.asarray(x_s) / w.x_scale_s
    return 0.5 * np.einsum("...i,ij,...j->...", xt, p0, xt)
