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
scales; ours are documented defaults of :class:`FuzzyParams`.  The law exists once, compiled
(:mod:`metro_atc.core.ato.tracker_laws`: the memberships, the rules, both forms): the
on-board ATO's per-train step (``control_kernel_step``) calls it with the gains of
:class:`FuzzyParams`, and :class:`FuzzyController` calls it for each train of a vector
(:mod:`metro_atc.core.ato.tracking`).  ``RULE_MATRIX`` (Table 1 as values) is
:data:`metro_atc.core.ato.tracker_laws.RULE_MATRIX`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np
from numpy.typing import ArrayLike, NDArray

from metro_atc.core.ato.tracker_laws import (RULE_MATRIX, flat, flc_many, fuzzy_steps,
                                             memberships, tracker_states)

FloatArray = NDArray[np.float64]
__all__ = ["RULE_MATRIX", "FuzzyController", "FuzzyParams", "d_memberships",
           "e_memberships", "flc_output"]


def e_memberships(e_n: ArrayLike) -> FloatArray:
    """Membership degrees of normalised e in (PB, P, Z, N, NB); shape (..., 5).

    The compiled :func:`metro_atc.core.ato.tracker_laws.e_sets` of each element.
    """
    return memberships(e_n, True)


def d_memberships(d_n: ArrayLike) -> FloatArray:
    """Membership degrees of normalised d in (P, Z, N); shape (..., 3).

    The compiled :func:`metro_atc.core.ato.tracker_laws.d_sets` of each element.
    """
    return memberships(d_n, False)


def flc_output(e_n: ArrayLike, d_n: ArrayLike) -> FloatArray:
    """Crisp output in [-1, 1] of the 15-rule controller for normalised inputs.

    The compiled :func:`metro_atc.core.ato.tracker_laws.flc` of each (e, d) pair.
    """
    shape, (e, d) = flat(e_n, d_n)
    out = np.zeros(e.size)
    flc_many(e, d, out)
    return out.reshape(shape)


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

        ``u_ff``: the feedforward part of that effort (the state keeps the feedback part;
        :func:`metro_atc.core.ato.tracker_laws.tracker_state`).
        """
        shape, (uf, ff) = flat(u, u_ff)
        out = np.zeros(uf.size)
        tracker_states(False, uf, ff, ff, 0.0, 0.0, out)
        self._u = out.reshape(shape)

    def step(self, r_mps: ArrayLike, v_mps: ArrayLike, dt_s: float = 0.1,
             u_ff: ArrayLike = 0.0) -> FloatArray:
        """Return the normalised effort u in [-1, 1] for desired r and actual v [m/s].

        :func:`metro_atc.core.ato.tracker_laws.fuzzy_law` per train.  ``dt_s`` is unused
        by the fuzzy law (d_k is a per-step difference, Li n.d., eq. 3) and kept for the
        common tracker interface; ``u_ff`` is an optional feedforward effort added to the
        absolute form / to the increments' base (0: pure Li n.d.).
        """
        has_e = self._e_prev is not None
        e_prev = self._e_prev if self._e_prev is not None else 0.0
        shape, (r, v, ff, tu, ep) = flat(r_mps, v_mps, u_ff, self._u, e_prev)
        u = np.zeros(r.size)
        p = self.p
        e_scale, d_scale, gain = np.array([p.e_scale_mps, p.d_scale_mps, p.gain], dtype=float)
        fuzzy_steps(r, v, ff, tu, ep, has_e, e_scale, d_scale, gain, bool(p.incremental), u)
        self._u, self._e_prev = tu.reshape(shape), ep.reshape(shape)
        return u.reshape(shape)
