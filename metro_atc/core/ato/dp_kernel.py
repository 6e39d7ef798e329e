"""Compiled (numba) exact stage simulation of the DP: :func:`strategy_step` element by element.

The DP's exact simulations (:func:`metro_atc.core.ato.dp.simulate_path` and the single-stage
simulations of its blend and rollout) advance a few dozen candidate sequences over a few
hundred stages; in numpy every sub-step is one call over a short array, so the interpreter
overhead dominates (about 1 ms per sub-step, 85 % of the DP's time before this module).
These loops compute the same operations as
:func:`metro_atc.core.ato.strategy.strategy_step` (traction: midpoint RK2 in distance,
seed 002 eq. 3-5; coasting: RK4 guess and one Newton step on the closed-form distance
potential, seed 002 eq. 7-8; speed code at infinity, envelope cap, trapezoid time) for one
trajectory at a time, in the same operation order; the numpy path stays the reference and
is tested equal to this one (``test/test_ato_dp.py``).

Train constants are packed in a float array (``P_*`` indices, :func:`pack_train`).
"""

from __future__ import annotations

import importlib.util
import math

import numpy as np
from numpy.typing import NDArray

from metro_atc.core.ato.envelope import MODE_COAST, MODE_CRUISE, OperatingLimits
from metro_atc.core.line.vehicle import TrainParams

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

(P_MASS, P_MEFF, P_DA, P_DB, P_DC, P_A1, P_V1, P_V2, P_B2, P_B3, P_A2, P_A3, P_AMAX,
 N_P) = range(14)
_TINY = 1e-12


def numba_available() -> bool:
    """True when numba can be imported (else the DP uses the numpy reference path)."""
    return importlib.util.find_spec("numba") is not None


def pack_train(train: TrainParams, limits: OperatingLimits) -> FloatArray:
    """Train and limit constants of the stage physics as a float array (``P_*`` order)."""
    p = np.empty(N_P)
    p[P_MASS], p[P_MEFF] = train.mass_kg, train.effective_mass_kg
    p[P_DA], p[P_DB], p[P_DC] = train.davis_a_n, train.davis_b_n_per_mps, train.davis_c_n_per_mps2
    p[P_A1], p[P_V1], p[P_V2] = train.a1_mps2, train.v1_mps, train.v2_mps
    p[P_B2], p[P_B3], p[P_A2], p[P_A3] = train.b2_mps, train.b3_mps, train.a2, train.a3
    p[P_AMAX] = limits.accel_max_mps2
    return p


def _njit(fn):  # type: ignore[no-untyped-def]
    """numba.njit(cache, numpy error model) when numba is installed, else the plain function."""
    if not numba_available():
        return fn
    from numba import njit
    return njit(cache=True, error_model="numpy")(fn)


@_njit
def _trac_accel(p, v, fg, delta):  # type: ignore[no-untyped-def]
    """:func:`metro_atc.core.ato.strategy.traction_accel` of one speed [m/s^2]."""
    va = abs(v)
    if va <= p[P_V1]:
        phi = p[P_A1]
    elif va <= p[P_V2]:
        phi = p[P_A2] / (va + p[P_B2] + 1e-12)
    else:
        phi = p[P_A3] / (va + p[P_B3] + 1e-12) ** 2
    f = delta * (p[P_MASS] * phi) - (p[P_DA] + p[P_DB] * v + p[P_DC] * v * v) - fg
    return min(f / p[P_MEFF], p[P_AMAX])


@_njit
def _coast_xt(w, d4, c2, bp):  # type: ignore[no-untyped-def]
    """:func:`metro_atc.core.ato.strategy._coast_x_t` of one value: (X [m], T [s])."""
    if d4 > 0.0:
        a = math.sqrt(d4)
        t = -math.atan(w / a) / (c2 * a)
        return -0.5 * math.log(w * w + d4) / c2 - bp * t, t
    k = math.sqrt(-d4)
    t = math.log(abs((k + w) / (k - w + _TINY))) / (2.0 * c2 * k)
    return -0.5 * math.log(abs(w * w + d4) + _TINY) / c2 - bp * t, t


@_njit
def _coast(p, e, h, fg):  # type: ignore[no-untyped-def]
    """:func:`metro_atc.core.ato.strategy.coast_step` of one state: (e1, dt [s], stalled)."""
    m = p[P_MEFF]
    c0 = (p[P_DA] + fg) / m
    c1 = p[P_DB] / m
    c2 = p[P_DC] / m
    e0 = max(e, 0.0)
    v0 = math.sqrt(2.0 * e0)
    v = math.sqrt(2.0 * max(e0, 0.0))
    k1 = -(c0 + c1 * v + c2 * v * v)
    v = math.sqrt(2.0 * max(e0 + 0.5 * h * k1, 0.0))
    k2 = -(c0 + c1 * v + c2 * v * v)
    v = math.sqrt(2.0 * max(e0 + 0.5 * h * k2, 0.0))
    k3 = -(c0 + c1 * v + c2 * v * v)
    v = math.sqrt(2.0 * max(e0 + h * k3, 0.0))
    k4 = -(c0 + c1 * v + c2 * v * v)
    e_g = e0 + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
    stalled = (e_g <= 1e-9) and (c0 > 0.0)
    e_g = max(e_g, 0.0)
    if c2 <= 0.0:
        v1 = math.sqrt(2.0 * e_g)
        dt = 2.0 * h / (v0 + v1 + 1e-300) if v0 + v1 > 0 else np.inf
        return e_g, (np.inf if stalled else dt), stalled
    bp = c1 / (2.0 * c2)
    d4 = c0 / c2 - bp * bp
    if abs(d4) < 1e-9:
        d4 = 1e-9
    x0, t0 = _coast_xt(v0 + bp, d4, c2, bp)
    w = math.sqrt(2.0 * e_g) + bp
    x, _ = _coast_xt(w, d4, c2, bp)
    dxdw = -(w - bp) / (c2 * (w * w + d4))
    if (not stalled) and abs(dxdw) > _TINY:
        w = max(w - (x - x0 - h) / dxdw, bp)
    v1 = max(w - bp, 0.0)
    e1 = 0.0 if stalled else 0.5 * v1 * v1
    _, t1 = _coast_xt(math.sqrt(2.0 * e1) + bp, d4, c2, bp)
    dt = t1 - t0
    if not (math.isfinite(dt) and dt > 0.0):
        dt = 2.0 * h / max(v0 + math.sqrt(2.0 * e1), _TINY)
    return e1, (np.inf if stalled else dt), stalled


@_njit
def step_one(p, e, h, fg, cap, mode, e_hold, delta):  # type: ignore[no-untyped-def]
    """:func:`metro_atc.core.ato.strategy.strategy_step` of one trajectory (speed code inf).

    Returns (e_next [m^2/s^2], dt [s], traction energy [J]).
    """
    e0 = max(e, 0.0)
    e_m = e0
    dt_c = 0.0
    st_c = False
    if mode == MODE_COAST:
        e_m, dt_c, st_c = _coast(p, e0, h, fg)
    else:
        v0 = math.sqrt(2.0 * e0)
        e_p = max(e0 + h * _trac_accel(p, v0, fg, delta), 0.0)
        v_m = 0.5 * (v0 + math.sqrt(2.0 * e_p))
        e_m = max(e0 + h * _trac_accel(p, v_m, fg, delta), 0.0)
        if mode == MODE_CRUISE:
            e_m = min(e_m, e_hold)
    e1 = max(min(e_m, cap), 0.0)
    clamped = e_m > cap
    v0 = math.sqrt(2.0 * e0)
    v1 = math.sqrt(2.0 * e1)
    vm = 0.5 * (v0 + v1)
    force = p[P_MEFF] * (e1 - e0) / h + p[P_DA] + p[P_DB] * vm + p[P_DC] * vm * vm + fg
    is_coast = mode == MODE_COAST
    energy = 0.0 if is_coast else max(force, 0.0) * h
    if is_coast and not clamped:
        dt = dt_c
    else:
        dt = 2.0 * h / max(v0 + v1, 1e-300) if v0 + v1 > 0.0 else np.inf
    if (is_coast and not clamped and st_c) or (e1 <= 0.0 and cap > 1e-9):
        dt = np.inf
    return e1, dt, energy


@_njit
def simulate_batch(p, modes, levels, fg_sub, cap_sub, h):  # type: ignore[no-untyped-def]
    """Exact simulation of sequences (n_c, n_st) from standstill (twin of ``simulate_path``).

    modes / levels: MODE_* and traction level per candidate and stage; fg_sub / cap_sub:
    grade force [N] and envelope [m^2/s^2] per stage and sub-step; h: sub-step [m].  Returns
    e at the stages, cumulative energy [J] and time [s], each (n_c, n_st + 1).
    """
    n_c, n_st = modes.shape
    n_sub = fg_sub.shape[1]
    e_path = np.zeros((n_c, n_st + 1))
    cum_j = np.zeros((n_c, n_st + 1))
    cum_t = np.zeros((n_c, n_st + 1))
    for c in range(n_c):
        e = 0.0
        energy = 0.0
        tm = 0.0
        for k in range(n_st):
            hold = e
            for q in range(n_sub):
                e, dt, de = step_one(p, e, h, fg_sub[k, q], cap_sub[k, q], modes[c, k],
                                     hold, levels[c, k])
                energy = energy + de
                tm = tm + dt
            e_path[c, k + 1] = e
            cum_j[c, k + 1] = energy
            cum_t[c, k + 1] = tm
    return e_path, cum_j, cum_t


@_njit
def simulate_stages(p, ks, e0, modes, levels, fg_sub, cap_sub, h
                    ):  # type: ignore[no-untyped-def]
    """One stage ``ks[i]`` per element from e0[i] (mode, level): (e_next, J, s) arrays."""
    n = ks.size
    n_sub = fg_sub.shape[1]
    e_out = np.empty(n)
    j_out = np.empty(n)
    t_out = np.empty(n)
    for i in range(n):
        k = ks[i]
        e = e0[i]
        energy = 0.0
        tm = 0.0
        for q in range(n_sub):
            e, dt, de = step_one(p, e, h, fg_sub[k, q], cap_sub[k, q], modes[i], e0[i],
                                 levels[i])
            energy += de
            tm += dt
        e_out[i] = e
        j_out[i] = energy
        t_out[i] = tm
    return e_out, j_out, t_out


@_njit
def _lerp(a, b, w):  # type: ignore[no-untyped-def]
    """:func:`metro_atc.core.ato.dp.lerp` of one value."""
    if w <= 0.0:
        return a
    return (1.0 - w) * a + w * b


@_njit
def backward(energy, time_s, idx0, w, top, mus):  # type: ignore[no-untyped-def]
    """Value functions of every multiplier (twin of ``dp._backward``): (n_mu, n_st + 1, n_e)."""
    n_st, n_e, n_u = energy.shape
    n_mu = mus.size
    j_all = np.zeros((n_mu, n_st + 1, n_e))
    for m in range(n_mu):
        mu = mus[m]
        for k in range(n_st - 1, -1, -1):
            tp = top[k]
            for i in range(min(tp + 1, n_e)):
                best = np.inf
                for u in range(n_u):
                    i0 = idx0[k, i, u]
                    q = energy[k, i, u] + mu * time_s[k, i, u] \
                        + _lerp(j_all[m, k + 1, i0], j_all[m, k + 1, i0 + 1], w[k, i, u])
                    if u == 0 or q < best:
                        best = q
                j_all[m, k, i] = best
            for i in range(tp + 1, n_e):
                j_all[m, k, i] = j_all[m, k, tp]
    return j_all


@_njit
def forward(de, energy, time_s, e_next, mus, j_all, policy, e0, k0
            ):  # type: ignore[no-untyped-def]
    """Table forward passes (twin of ``dp._forward`` / ``dp._forward_multi``).

    Candidate c starts at stage k0[c] from e0[c] and follows policy[c, k] (index into mus /
    j_all).  Returns controls (n_c, n_st), energy [J], time [s] (inf when a candidate
    fails) and e at the stages (n_c, n_st + 1).
    """
    n_st, n_e, n_u = energy.shape
    n_c = e0.size
    top_f = n_e - 1.000001
    ctrl = np.zeros((n_c, n_st), dtype=np.int64)
    path = np.zeros((n_c, n_st + 1))
    en_out = np.zeros(n_c)
    tm_out = np.zeros(n_c)
    q = np.empty(n_u)
    en = np.empty(n_u)
    dt = np.empty(n_u)
    nx = np.empty(n_u)
    for c in range(n_c):
        e = e0[c]
        path[c, k0[c]] = e
        acc_e = 0.0
        acc_t = 0.0
        alive = True
        for k in range(k0[c], n_st):
            f = min(max(e / de, 0.0), top_f)
            i = int(f)
            a = f - i
            p = policy[c, k]
            mu = mus[p]
            for u in range(n_u):
                en[u] = _lerp(energy[k, i, u], energy[k, i + 1, u], a)
                dt[u] = _lerp(time_s[k, i, u], time_s[k, i + 1, u], a)
                nx[u] = e_next[k, i, u] + a * (e_next[k, i + 1, u] - e_next[k, i, u])
                f1 = min(max(nx[u] / de, 0.0), top_f)
                i1 = int(f1)
                w1 = f1 - i1
                qq = en[u] + mu * dt[u] + _lerp(j_all[p, k + 1, i1], j_all[p, k + 1, i1 + 1],
                                                w1)
                q[u] = qq if math.isfinite(dt[u]) else np.inf
            ub = 0
            for u in range(1, n_u):
                if q[u] < q[ub]:
                    ub = u
            alive = alive and math.isfinite(q[ub])
            ctrl[c, k] = ub
            e = nx[ub]
            acc_e += en[ub]
            acc_t += dt[ub]
            path[c, k + 1] = e
        en_out[c] = acc_e if alive else np.inf
        tm_out[c] = acc_t if alive else np.inf
    return ctrl, en_out, tm_out, path


__all__ = ["backward", "forward", "numba_available", "pack_train",
           "simulate_batch", "simulate_stages", "step_one"]
