"""Closed-form coasting of the driving strategies (ACTP n.d., eq. 7-8; Ke 2010).

The closed-form coasting speed (its coefficients:
:func:`metro_atc.core.ato.step_kernel.coast_coefficients`).  The distance
step of every driving strategy (accelerate, cruise, coast, speed code, envelope) is the
compiled :func:`metro_atc.core.ato.step_kernel.strategy_step`, the planners' one step.

Reconstruction note (ACTP n.d., eq. 7-8).  The extraction prints eq. 7 as
``v = alpha tan(beta + gamma (C_v - t))``; with the printed constants
``alpha^2 = c0/c2 - c1^2/(4 c2^2)``, ``beta = -c1/(2 c2)``, ``gamma = c2 alpha`` and eq. 8
``C_v = t_c + atan((v_c - beta)/alpha)/gamma`` the consistent solution of the coasting ODE is
``v(t) = beta + alpha tan(gamma (C_v - t))`` (beta is an offset, not a phase).  For steep
down-grades (``alpha^2 < 0``) the tan becomes tanh/coth (both branches:
:func:`metro_atc.core.ato.step_kernel.coast_x_t`).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]


# ----------------------------------------------------------------------------- coasting
def coast_constants(c0: float, c1: float, c2: float) -> tuple[float, float, float]:
    """Constants (alpha [m/s], beta [m/s], gamma [1/s]) of ACTP n.d., eq. 7 (alpha^2 > 0 case)."""
    a2 = c0 / c2 - c1 * c1 / (4.0 * c2 * c2)
    if a2 <= 0.0:
        raise ValueError("tan form of ACTP n.d., eq. 7 needs c0/c2 > c1^2/(4 c2^2)")
    alpha = float(np.sqrt(a2))
    return alpha, -c1 / (2.0 * c2), c2 * alpha


def coast_speed(t: ArrayLike, t_c: float, v_c: float, c0: float, c1: float,
                c2: float) -> FloatArray:
    """Coasting speed v(t) [m/s] starting at v_c [m/s] at time t_c [s] (ACTP n.d., eq. 7-8).

    ``v(t) = beta + alpha tan(gamma (C_v - t))`` with ``C_v`` from eq. 8; valid until the
    speed reaches zero.
    """
    alpha, beta, gamma = coast_constants(c0, c1, c2)
    c_v = t_c + np.arctan((v_c - beta) / alpha) / gamma  # ACTP n.d., eq. 8
    return beta + alpha * np.tan(gamma * (c_v - np.asarray(t, dtype=float)))
