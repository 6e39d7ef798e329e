"""The speed trackers' laws, once: compiled scalar functions for every caller.

The on-board ATO's compiled step (:mod:`metro_atc.core.ato.control_kernel_step`) and the
vectorised tracker classes (:class:`metro_atc.core.ato.fuzzy.FuzzyController`,
:class:`metro_atc.core.ato.pi.PIController`, stepping many trains through the loops
:func:`fuzzy_steps`, :func:`pi_steps`, :func:`tracker_states`) call the same functions:

- :func:`flc`: the 15-rule fuzzy controller of Li n.d. (Sec. 2.3, Table 1): memberships of
  the normalised error e (:func:`e_sets`) and its difference d (:func:`d_sets`) from the
  triangles (eq. 1, :func:`triangle`) and shoulders (eq. 2, :func:`rise`, :func:`fall`),
  product firing strengths, weighted average of the rule singletons;
- :func:`fuzzy_inputs`: e_k and d_k = e_k - e_{k-1} (eq. 3) on their universes;
- :func:`fuzzy_law`: the incremental (fuzzy PI, with anti-windup) and the absolute form;
- :func:`pi_law`: the PI tracker with conditional integration;
- :func:`tracker_state`: the state that gives an applied effort (``set_output``).

Table 1 is :data:`RULES` (the description: :mod:`metro_atc.core.ato.fuzzy`).
``NUMBA_DISABLE_JIT=1`` runs this same source as Python.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from metro_atc.core.ato.control_kernel import clip1, pmax
from metro_atc.core.ato.step_kernel import jit

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
"""Li n.d., Table 1: RULES[d index][e index] -> output set."""
RULE_MATRIX = np.array([[OUT_VALUE[o] for o in row] for row in RULES])
"""Table 1 as output values, shape (3 d-sets, 5 e-sets)."""
R0, R1, R2, R3, R4, R5, R6, R7, R8, R9, R10, R11, R12, R13, R14 = \
    (float(x) for x in RULE_MATRIX.ravel())


@jit
def clip01(m):  # type: ignore[no-untyped-def]
    """A membership degree clipped to [0, 1] (NaN stays NaN)."""
    return 0.0 if m < 0.0 else (1.0 if m > 1.0 else m)


@jit
def triangle(x, a, b, c):  # type: ignore[no-untyped-def]
    """Isosceles triangular membership of x, feet a and c, peak b (Li n.d., eq. 1)."""
    up, dn = (x - a) / (b - a), (c - x) / (c - b)
    return clip01(up if up <= dn else dn)


@jit
def rise(x, a, b):  # type: ignore[no-untyped-def]
    """Right shoulder: 0 up to a, 1 from b on (Li n.d., eq. 2 with an infinite top)."""
    return clip01((x - a) / (b - a))


@jit
def fall(x, c, d):  # type: ignore[no-untyped-def]
    """Left shoulder: 1 up to c, 0 from d on (Li n.d., eq. 2 with an infinite top)."""
    return clip01((d - x) / (d - c))


@jit
def e_sets(e_n):  # type: ignore[no-untyped-def]
    """Memberships of the normalised error in (PB, P, Z, N, NB)."""
    return (rise(e_n, 0.5, 1.0), triangle(e_n, 0.0, 0.5, 1.0), triangle(e_n, -0.5, 0.0, 0.5),
            triangle(e_n, -1.0, -0.5, 0.0), fall(e_n, -1.0, -0.5))


@jit
def d_sets(d_n):  # type: ignore[no-untyped-def]
    """Memberships of the normalised error difference in (P, Z, N)."""
    return rise(d_n, 0.0, 1.0), triangle(d_n, -1.0, 0.0, 1.0), fall(d_n, -1.0, 0.0)


@jit
def flc(e_n, d_n):  # type: ignore[no-untyped-def]
    """Crisp output in [-1, 1] of the 15-rule controller (Li n.d., Table 1) for one pair.

    The memberships of e (:func:`e_sets`) and d (:func:`d_sets`), the 15 product firing
    strengths and the weighted average of the rule singletons, summed in numpy's pairwise
    order for 15 contiguous doubles (8 in pairs, then the rest one by one).
    """
    e0, e1, e2, e3, e4 = e_sets(e_n)
    d0, d1, d2 = d_sets(d_n)
    w0, w1, w2, w3, w4 = d0 * e0, d0 * e1, d0 * e2, d0 * e3, d0 * e4
    w5, w6, w7, w8, w9 = d1 * e0, d1 * e1, d1 * e2, d1 * e3, d1 * e4
    w10, w11, w12, w13, w14 = d2 * e0, d2 * e1, d2 * e2, d2 * e3, d2 * e4
    den = ((w0 + w1) + (w2 + w3)) + ((w4 + w5) + (w6 + w7))
    den = den + w8 + w9 + w10 + w11 + w12 + w13 + w14
    num = ((w0 * R0 + w1 * R1) + (w2 * R2 + w3 * R3)) \
        + ((w4 * R4 + w5 * R5) + (w6 * R6 + w7 * R7))
    num = num + w8 * R8 + w9 * R9 + w10 * R10 + w11 * R11 + w12 * R12 \
        + w13 * R13 + w14 * R14
    return num / (den if den >= 1e-12 else 1e-12)


@jit
def fuzzy_inputs(e, has_e, e_prev, e_scale, d_scale):  # type: ignore[no-untyped-def]
    """(e_n, d_n): the speed error e [m/s] and its difference to the last step's e_prev.

    Li n.d., eq. 3 (the derivative as a first difference, 0 on the first step: ``has_e``
    false), divided by the universe scales e_scale [m/s] and d_scale [m/s per step].
    """
    d = 0.0 if not has_e else e - e_prev
    return e / e_scale, d / d_scale


@jit
def fuzzy_law(tu, e_n, d_n, u_ff, gain, incremental):  # type: ignore[no-untyped-def]
    """One fuzzy controller step: (effort u in [-1, 1], new state tu).

    ``incremental``: the output ``gain flc`` is an effort increment (a fuzzy PI; ``tu`` the
    integrated feedback effort, anti-windup: kept so that ``tu + u_ff`` stays in [-1, 1]);
    else the effort itself (the absolute form, Li n.d., Sec. 2.3; ``tu`` the clipped
    effort).  ``u_ff``: the feedforward effort added [-].
    """
    if incremental:
        uu = tu + gain * flc(e_n, d_n)
        lo, hi = -1.0 - u_ff, 1.0 - u_ff
        uu = uu if not uu < lo else lo
        uu = uu if not uu > hi else hi
        return clip1(uu + u_ff, -1.0, 1.0), uu
    out = clip1(gain * flc(e_n, d_n) + u_ff, -1.0, 1.0)
    return out, out


@jit
def pi_law(i, e, dt, u_ff, kp, ki):  # type: ignore[no-untyped-def]
    """One PI step: (effort u in [-1, 1], new integral i [m]).

    ``u = kp e + ki i + u_ff`` with the error e [m/s], the integral i of e over time
    [m] advanced by e dt (dt [s]) unless the output then saturates in the direction of
    the error (conditional integration, anti-windup); kp [1/(m/s)], ki [1/m].
    """
    i_new = i + e * dt
    raw = kp * e + ki * i_new + u_ff
    if not ((raw > 1.0 and e > 0.0) or (raw < -1.0 and e < 0.0)):
        i = i_new
    return clip1(kp * e + ki * i + u_ff, -1.0, 1.0), i


@jit
def tracker_state(pi, u, u_ff, e, kp, ki):  # type: ignore[no-untyped-def]
    """The tracker's state for the applied effort u [-] (its ``set_output``).

    The fuzzy controller keeps the feedback part ``u - u_ff``; the PI controller (``pi``)
    the integral [m] that gives u with its last error e [m/s].
    """
    if pi:
        return (u - u_ff - kp * e) / pmax(ki, 1e-12)
    return u - u_ff


@jit
def fuzzy_steps(r, v, u_ff, tu, e_prev, has_e, e_scale, d_scale, gain, incremental,
                u):  # type: ignore[no-untyped-def]
    """:func:`fuzzy_law` over trains (1-D arrays of one length; tu, e_prev, u written)."""
    for k in range(u.size):
        e = r[k] - v[k]
        e_n, d_n = fuzzy_inputs(e, has_e, e_prev[k], e_scale, d_scale)
        e_prev[k] = e
        u[k], tu[k] = fuzzy_law(tu[k], e_n, d_n, u_ff[k], gain, incremental)


@jit
def pi_steps(r, v, u_ff, i, e_last, dt, kp, ki, u):  # type: ignore[no-untyped-def]
    """:func:`pi_law` over trains (1-D arrays of one length; i, e_last, u written)."""
    for k in range(u.size):
        e = r[k] - v[k]
        e_last[k] = e
        u[k], i[k] = pi_law(i[k], e, dt, u_ff[k], kp, ki)


@jit
def tracker_states(pi, u, u_ff, e, kp, ki, out):  # type: ignore[no-untyped-def]
    """:func:`tracker_state` over trains (1-D arrays of one length; out written)."""
    for k in range(out.size):
        out[k] = tracker_state(pi, u[k], u_ff[k], e[k], kp, ki)


@jit
def flc_many(e_n, d_n, out):  # type: ignore[no-untyped-def]
    """:func:`flc` over 1-D arrays of one length (out written)."""
    for k in range(out.size):
        out[k] = flc(e_n[k], d_n[k])


@jit
def sets_many(x, is_e, out):  # type: ignore[no-untyped-def]
    """:func:`e_sets` (``is_e``) or :func:`d_sets` of each x into the rows of out."""
    for k in range(x.size):
        if is_e:
            out[k, 0], out[k, 1], out[k, 2], out[k, 3], out[k, 4] = e_sets(x[k])
        else:
            out[k, 0], out[k, 1], out[k, 2] = d_sets(x[k])


def flat(*xs: Any) -> tuple[tuple[int, ...], list[FloatArray]]:
    """(common shape, each argument broadcast to it as a contiguous 1-D float copy)."""
    arrs = np.broadcast_arrays(*[np.asarray(x, dtype=float) for x in xs])
    shape = arrs[0].shape if arrs else ()
    return shape, [np.array(a, dtype=float).ravel() for a in arrs]


def memberships(x: ArrayLike, is_e: bool) -> FloatArray:
    """Memberships of normalised e (PB, P, Z, N, NB) or d (P, Z, N); shape (..., 5 or 3)."""
    shape, (xf,) = flat(x)
    out = np.zeros((xf.size, 5 if is_e else 3))
    sets_many(xf, is_e, out)
    return out.reshape(shape + (out.shape[1],))
