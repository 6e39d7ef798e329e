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
scales; ours are documented defaults of :class:`FuzzyParams`.  Vectorised over trains.
"""

from __future__ import annotations

import math
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


_RULES_FLAT = tuple(float(x) for x in RULE_MATRIX.ravel())


def flc_output_at(e_n: float, d_n: float) -> float:
    """:func:`flc_output` for one finite (e, d) pair (plain floats, the same IEEE result).

    The per-train tracker runs it once per control step (graph speed): the
    memberships (:func:`triangle` / :func:`trapezoid` of the sets of :func:`e_memberships`
    and :func:`d_memberships`, clipped), the 15 products and the two sums (numpy's pairwise
    order for 15 contiguous doubles: 8 in pairs, then the rest one by one) are written
    out, every operation as numpy does it (``test/test_scalar_math.py`` against numpy).
    """
    # e: PB (ramp), P, Z, N (triangles: min of the two sides, clipped), NB (ramp)
    m = (e_n - 0.5) / 0.5
    e0 = 0.0 if m < 0.0 else (1.0 if m > 1.0 else m)
    up, dn = (e_n - 0.0) / 0.5, (1.0 - e_n) / 0.5
    m = up if up <= dn else dn
    e1 = 0.0 if m < 0.0 else (1.0 if m > 1.0 else m)
    up, dn = (e_n - -0.5) / 0.5, (0.5 - e_n) / 0.5
    m = up if up <= dn else dn
    e2 = 0.0 if m < 0.0 else (1.0 if m > 1.0 else m)
    up, dn = (e_n - -1.0) / 0.5, (0.0 - e_n) / 0.5
    m = up if up <= dn else dn
    e3 = 0.0 if m < 0.0 else (1.0 if m > 1.0 else m)
    m = (-0.5 - e_n) / 0.5
    e4 = 0.0 if m < 0.0 else (1.0 if m > 1.0 else m)
    # d: P (ramp), Z (triangle), N (ramp)
    m = (d_n - 0.0) / 1.0
    d0 = 0.0 if m < 0.0 else (1.0 if m > 1.0 else m)
    up, dn = (d_n - -1.0) / 1.0, (1.0 - d_n) / 1.0
    m = up if up <= dn else dn
    d1 = 0.0 if m < 0.0 else (1.0 if m > 1.0 else m)
    m = (0.0 - d_n) / 1.0
    d2 = 0.0 if m < 0.0 else (1.0 if m > 1.0 else m)
    w0, w1, w2, w3, w4 = d0 * e0, d0 * e1, d0 * e2, d0 * e3, d0 * e4
    w5, w6, w7, w8, w9 = d1 * e0, d1 * e1, d1 * e2, d1 * e3, d1 * e4
    w10, w11, w12, w13, w14 = d2 * e0, d2 * e1, d2 * e2, d2 * e3, d2 * e4
    den = ((w0 + w1) + (w2 + w3)) + ((w4 + w5) + (w6 + w7))
    den = den + w8 + w9 + w10 + w11 + w12 + w13 + w14
    r = _RULES_FLAT
    num = ((w0 * r[0] + w1 * r[1]) + (w2 * r[2] + w3 * r[3])) \
        + ((w4 * r[4] + w5 * r[5]) + (w6 * r[6] + w7 * r[7]))
    num = num + w8 * r[8] + w9 * r[9] + w10 * r[10] + w11 * r[11] + w12 * r[12] \
        + w13 * r[13] + w14 * r[14]
    return num / (den if den >= 1e-12 else 1e-12)


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
        # plain floats while the controller runs one train (the scalar step reads them
        # without numpy; the vector step takes either)
        self._e_prev: "FloatArray | float | None" = None
        self._u: "FloatArray | float" = u0 if type(u0) is float \
            else np.asarray(u0, dtype=float)

    def scalar_state(self) -> Optional[tuple[bool, float, float]]:
        """The state of a one-train incremental controller with plain floats, else None.

        (has a previous error, previous error [m/s], effort state [-]): what the compiled
        ATO step reads.
        """
        e_prev, u = self._e_prev, self._u
        if not self.p.incremental or type(u) is not float \
                or (e_prev is not None and type(e_prev) is not float):
            return None
        return e_prev is not None, (e_prev if e_prev is not None else 0.0), u

    def set_scalar_state(self, has_e: bool, e_prev: float, u: float) -> None:
        """Set the state :meth:`scalar_state` returns (after a compiled step)."""
        self._e_prev = e_prev if has_e else None
        self._u = u

    def set_output(self, u: ArrayLike, u_ff: ArrayLike = 0.0) -> None:
        """Align the effort state with the effort u actually applied (after rate limits).

        ``u_ff``: the feedforward part of that effort (the state keeps the feedback part).
        """
        if type(u) is float and type(u_ff) is float:
            self._u = u - u_ff  # the same double as the numpy difference
        else:
            self._u = np.asarray(u, dtype=float) - np.asarray(u_ff, dtype=float)

    def step(self, r_mps: ArrayLike, v_mps: ArrayLike, dt_s: float = 0.1,
             u_ff: ArrayLike = 0.0) -> FloatArray:
        """Return the normalised effort u in [-1, 1] for desired r and actual v [m/s].

        ``dt_s`` is unused by the fuzzy law (d_k is a per-step difference, Li n.d., eq. 3)
        and kept for the common tracker interface; ``u_ff`` is an optional feedforward
        effort added to the absolute form / to the increments' base (0: pure Li n.d.).
        """
        if type(r_mps) is float and type(v_mps) is float and type(u_ff) is float \
                and self.p.incremental:
            return np.asarray(self._step_at(r_mps, v_mps, u_ff))
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

    def step_float(self, r_mps: float, v_mps: float, dt_s: float = 0.1,
                   u_ff: float = 0.0) -> float:
        """``float(step(...))`` (the same double) without the 0-d array for one train."""
        if type(r_mps) is float and type(v_mps) is float and type(u_ff) is float \
                and self.p.incremental:
            return self._step_at(r_mps, v_mps, u_ff)
        return float(self.step(r_mps, v_mps, dt_s, u_ff))

    def _step_at(self, r: float, v: float, ff: float) -> float:
        """:meth:`step` (incremental form) for one train given plain floats; the same result."""
        u_prev = self._u
        e_prev = self._e_prev
        if (type(u_prev) is not float and np.ndim(u_prev) != 0) \
                or (e_prev is not None and type(e_prev) is not float and np.ndim(e_prev) != 0):
            raise ValueError("fuzzy tracker: scalar step on a vector state")
        e = r - v
        d = 0.0 if e_prev is None else e - float(e_prev)
        self._e_prev = e
        e_n, d_n = e / self.p.e_scale_mps, d / self.p.d_scale_mps
        if not (math.isfinite(e_n) and math.isfinite(d_n) and math.isfinite(ff)):
            y = float(flc_output(e_n, d_n))
        else:
            y = flc_output_at(e_n, d_n)
        u = float(u_prev) + self.p.gain * y
        lo, hi = -1.0 - ff, 1.0 - ff
        u = u if not u < lo else lo
        u = u if not u > hi else hi
        self._u = u
        out = u + ff
        return -1.0 if out < -1.0 else (1.0 if out > 1.0 else out)
