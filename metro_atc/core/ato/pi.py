"""PI speed tracker with anti-windup, pluggable in place of the fuzzy controller.

``u = kp e + ki * integral(e dt)`` with e = r - v [m/s], output clipped to [-1, 1]
(normalised effort, :func:`metro_atc.core.line.vehicle.effort_force`); the integrator is
frozen while the output saturates in the direction of the error (conditional integration).
Vectorised over trains (:mod:`metro_atc.core.ato.tracking`); the on-board ATO's per-train
step runs the compiled controller (``control_kernel_step``) with the gains of
:class:`PIParams`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class PIParams:
    """Gains: kp [1/(m/s)], ki [1/m] (effort per m/s of error and per metre of integral)."""

    kp: float = 1.5
    ki: float = 0.4


class PIController:
    """Stateful PI tracker with the same interface as the fuzzy controller."""

    name = "pi"

    def __init__(self, params: Optional[PIParams] = None) -> None:
        """Create with default or given gains."""
        self.p = params if params is not None else PIParams()
        self.reset()

    def reset(self, u0: ArrayLike = 0.0) -> None:
        """Reset the integrator so that the first output with zero error is u0."""
        self._i = np.asarray(u0, dtype=float) / max(self.p.ki, 1e-12)
        self._e = np.zeros_like(self._i)

    def set_output(self, u: ArrayLike, u_ff: ArrayLike = 0.0) -> None:
        """Back-calculate the integrator so that the last output equals the applied u.

        ``u_ff``: the feedforward part of u [-].
        """
        self._i = (np.asarray(u, dtype=float) - np.asarray(u_ff, dtype=float)
                   - self.p.kp * self._e) / max(self.p.ki, 1e-12)

    def step(self, r_mps: ArrayLike, v_mps: ArrayLike, dt_s: float = 0.1,
             u_ff: ArrayLike = 0.0) -> FloatArray:
        """Return u in [-1, 1] for desired r and actual v [m/s] after a step dt_s [s]."""
        e = np.asarray(r_mps, dtype=float) - np.asarray(v_mps, dtype=float)
        self._e = e
        i_new = self._i + e * dt_s
        raw = self.p.kp * e + self.p.ki * i_new + np.asarray(u_ff, dtype=float)
        sat_hi = (raw > 1.0) & (e > 0.0)
        sat_lo = (raw < -1.0) & (e < 0.0)
        self._i = np.where(sat_hi | sat_lo, self._i, i_new)
        out = self.p.kp * e + self.p.ki * self._i + np.asarray(u_ff, dtype=float)
        return np.asarray(np.clip(out, -1.0, 1.0), dtype=float)
