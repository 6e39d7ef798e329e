r"""Fuzzy logic speed controller (Li n.d., Sec. 2.3, Table 1, eq. 1-3).

Inputs: the speed error ``e_k = r_k - v_k`` [m/s] and its difference ``d_k = e_k - e_{k-1}``
[m/s per control step] (Li n.d., eq. 3, the derivative taken as a first difference).
Fuzzification: e_k with 5 sets {PB, P, Z, N, NB}, d_k with 3 sets {P, Z, N} on normalised
universes; P, Z, N of e_k and Z of d_k are isosceles triangles (eq. 1), the outer sets
trapezoids (eq. 2) -- as stated under Li n.d., Fig. 2.  Rule base: the 3 x 5 = 15 rules of
Li n.d., Table 1::

    d_k \ e_k   PB   P    Z    N    NB
    P           PB   PB   P    Z    N
    Z           PB   P    Z    N    NB
    N           P    Z    N    NB   NB

Inference: product firing strength; defuzzification: weighted average of output singletons
(PB=+1, P=+0.5, Z=0, N=-0.5, NB=-1), i.e. centre of gravity of singletons.  The crisp output
drives the normalised effort u in [-1, 1] (traction for u > 0, service brake for u < 0; see
:func:`metro_atc.core.line.vehicle.effort_force`).  With ``incremental=True`` (default) the
output is an effort *increment* per step (a fuzzy PI controller: zero error needs no
steady-state offset while cruising against resistance); with ``incremental=False`` it is the
effort itself, as in the crane controller of Li n.d., Sec. 2.3.  The seed gives no universe
scales; ours are documented defaults of :class:`FuzzyParams`.  Vectorised over trains
(:mod:`metro_atc.core.ato.tracking`); the on-board ATO's per-train step runs the compiled
controller (``control_kernel.flc`` and the tracker of ``control_kernel_step``) with the
gains of :class:`FuzzyParams`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]

E_SETS = ("PB", "P", "Z", "N", "NB")
"""Linguistic sets of e_k (Table 1 column order)."""
D_SETS = ("P", "Z", "N")
"""Linguistic sets of d_k (Table 1 row order)."""
OUT_VALUE = {"PB": 1.0, "P": 0.5, "Z": 0.0, "N": -0.5, "NB": -1.0}
"""Output singletons of the consequent sets."""
RULES = (
    ("PB", "PB", "P", "Z", "N"),
    ("PB", "P", "Z", "N", "NB"),
    ("P", "Z", "N", "NB", "NB"),
)
"""Seed 004 Table 1: RULES[d index][e index] -> output set."""
RULE_MATRIX = np.array([[OUT_VALUE[o] for o in row] for row in RULES])
"""Table 1 as output values, shape (3 d-sets, 5 e-sets)."""


def triangle(h: ArrayLike, a: float, b: float, c: float) -> FloatArray:
    """Triangular membership (Li n.d., eq. 1)."""
    x = np.asarray(h, dtype=float)
    up = (x - a) / (b - a)
    down = (c - x) / (c - b)
    return np.clip(np.minimum(up, down), 0.0, 1.0)


def trapezoid(h: ArrayLike, a: float, b: float, c: float, d: float) -> FloatArray:
    """Trapezoidal membership (Li n.d., eq. 2); infinite shoulders allowed."""
    x = np.asarray(h, dtype=float)
    up = np.ones_like(x) if not np.isfinite(a) else (x - a) / (b - a)
    down = np.ones_like(x) if not np.isfinite(d) else (d - x) / (d - c)
    return np.clip(np.minimum(up, down), 0.0, 1.0)


def e_memberships(e_n: ArrayLike) -> FloatArray:
    """Membership degrees of normalised e in (PB, P, Z, N, NB); shape (..., 5)."""
    x = np.asarray(e_n, dtype=float)
    inf = np.inf
    return np.stack([trapezoid(x, 0.5, 1.0, inf, inf), triangle(x, 0.0, 0.5, 1.0),
                     triangle(x, -0.5, 0.0, 0.5), triangle(x, -1.0, -0.5, 0.0),
                     trapezoid(x, -inf, -inf, -1.0, -0.5)], axis=-1)


def d_memberships(d_n: ArrayLike) -> FloatArray:
    """Membership degrees of normalised d in (P, Z, N); shape (..., 3)."""
    x = np.asarray(d_n, dtype=float)
    inf = np.inf
    return np.stack([trapezoid(x, 0.0, 1.0, inf, inf), triangle(x, -1.0, 0.0, 1.0),
                     trapezoid(x, -inf, -inf, -1.0, 0.0)], axis=-1)


def flc_output(e_n: ArrayLike, d_n: ArrayLike) -> FloatArray:
    """Crisp output in [-1, 1] of the 15-rule controller for normalised inputs."""
    me = e_memberships(e_n)
    md = d_memberships(d_n)
    w = md[..., :, None] * me[..., None, :]
    num = np.sum(w * RULE_MATRIX, axis=(-2, -1))
    den = np.sum(w, axis=(-2, -1))
    return np.asarray(num / np.maximum(den, 1e-12), dtype=float)


@dataclass(frozen=True)
class FuzzyParams:
    """Universe scales and output gain of the fuzzy controller.

    e_scale_mps: |e_k| at which e is fully PB/NB [m/s]; d_scale_mps: |d_k| at which d is
    fully P/N [m/s per step]; gain: effort change per step at output +-1 (incremental) or
    effort at +-1 (absolute); incremental: PI-type (True) or absolute output.
    """

    e_scale_mps: float = 0.2
    d_scale_mps: float = 0.01
    gain: float = 0.16
    incremental: bool = True


class FuzzyController:
    """Stateful Li n.d. fuzzy speed controller (one or many trains)."""

    name = "fuzzy"

    def __init__(self, params: Optional[FuzzyParams] = None) -> None:
        """Create with default or given scales; state starts at zero effort."""
        self.p = params if params is not None else FuzzyParams()
        self.reset()

    def reset(self, u0: ArrayLike = 0.0) -> None:
        """Forget the previous error and set the effort state."""
        self._e_prev: "FloatArray | None" = None
        self._u: FloatArray = np.asarray(u0, dtype=float)

    def set_output(self, u: ArrayLike, u_ff: ArrayLike = 0.0) -> None:
        """Align the effort state with the effort u actually applied (after rate limits).

        ``u_ff``: the feedforward part of that effort (the state keeps the feedback part).
        """
        self._u = np.asarray(u, dtype=float) - np.asarray(u_ff, dtype=float)

    def step(self, r_mps: ArrayLike, v_mps: ArrayLike, dt_s: float = 0.1,
             u_ff: ArrayLike = 0.0) -> FloatArray:
        """Return the normalised effort u in [-1, 1] for desired r and actual v [m/s].

        ``dt_s`` is unused by the fuzzy law (d_k is a per-step difference, Li n.d., eq. 3)
        and kept for the common tracker interface; ``u_ff`` is an optional feedforward
        effort added to the absolute form / to the increments' base (0: pure Li n.d.).
        """
        e = np.asarray(r_mps, dtype=float) - np.asarray(v_mps, dtype=float)
        d = np.zeros_like(e) if self._e_prev is None else e - self._e_prev
        self._e_prev = e
        y = flc_output(e / self.p.e_scale_mps, d / self.p.d_scale_mps)
        if self.p.incremental:
            ff = np.asarray(u_ff, dtype=float)
            # anti-windup: the state (feedback part) keeps the total effort in [-1, 1]
            self._u = np.clip(self._u + self.p.gain * y, -1.0 - ff, 1.0 - ff)
            out = np.clip(self._u + ff, -1.0, 1.0)
        else:
            out = np.clip(self.p.gain * y + np.asarray(u_ff, dtype=float), -1.0, 1.0)
            self._u = out
        return np.asarray(out, dtype=float)
