"""PI speed tracker with anti-windup, pluggable in place of the fuzzy controller.

``u = kp e + ki * integral(e dt)`` with e = r - v [m/s], output clipped to [-1, 1]
(normalised effort, :func:`metro_atc.core.line.vehicle.effort_force`); the integrator is
frozen while the output saturates in the direction of the error (conditional integration).
The law exists once, compiled (:func:`metro_atc.core.ato.tracker_laws.pi_law`): the
on-board ATO's per-train step (``control_kernel_step``) calls it with the gains of
:class:`PIParams`, and :class:`PIController` calls it for each train of a vector
(:mod:`metro_atc.core.ato.tracking`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np
from numpy.typing import ArrayLike, NDArray

from metro_atc.core.ato.tracker_laws import flat, pi_steps, tracker_states

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
        self._e: FloatArray = np.zeros_like(np.asarray(u0, dtype=float))
        self.set_output(u0)

    def set_output(self, u: ArrayLike, u_ff: ArrayLike = 0.0) -> None:
        """Back-calculate the integrator so that the last output equals the applied u.

        ``u_ff``: the feedforward part of u [-]
        (:func:`metro_atc.core.ato.tracker_laws.tracker_state`).
        """
        shape, (uf, ff, e) = flat(u, u_ff, self._e)
        out = np.zeros(uf.size)
        kp, ki = np.array([self.p.kp, self.p.ki], dtype=float)
        tracker_states(True, uf, ff, e, kp, ki, out)
        self._i: FloatArray = out.reshape(shape)

    def step(self, r_mps: ArrayLike, v_mps: ArrayLike, dt_s: float = 0.1,
             u_ff: ArrayLike = 0.0) -> FloatArray:
        """Return u in [-1, 1] for desired r and actual v [m/s] after a step dt_s [s].

        :func:`metro_atc.core.ato.tracker_laws.pi_law` per train.
        """
        shape, (r, v, ff, i) = flat(r_mps, v_mps, u_ff, self._i)
        e = np.zeros(r.size)
        u = np.zeros(r.size)
        dt, kp, ki = np.array([dt_s, self.p.kp, self.p.ki], dtype=float)
        pi_steps(r, v, ff, i, e, dt, kp, ki, u)
        self._i, self._e = i.reshape(shape), e.reshape(shape)
        return u.reshape(shape)
