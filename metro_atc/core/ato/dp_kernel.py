"""Compiled (numba) exact stage simulation of the DP: the strategy step element by element.

The DP's exact simulations (:func:`metro_atc.core.ato.dp.simulate_path` and the single-stage
simulations of its blend and rollout) advance a few dozen candidate sequences over a few
hundred stages; in numpy every sub-step is one call over a short array, so the interpreter
overhead dominates (about 1 ms per sub-step, 85 % of the DP's time before this module).
These loops advance one trajectory at a time with
:func:`metro_atc.core.ato.step_kernel.strategy_step_one` (the planners' one step,
:func:`metro_atc.core.ato.step_kernel.strategy_step`, speed code at infinity, shared with the
ECTP/ACTP kernel and the DP's tables).  These loops are the DP's only path
(``NUMBA_DISABLE_JIT=1`` runs them as Python); ``test/test_ato_dp.py`` checks them against
the recorded output of the former numpy path (``test/data/dp_numpy_ref.npz``).

Train constants are packed in a record (:func:`pack_train`).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from metro_atc.core.ato.step_kernel import jit as _njit
from metro_atc.core.ato.step_kernel import pack_train, strategy_step_one

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


@_njit
def simulate_batch(p, modes, levels, fg_sub, cap_sub, h):  # type: ignore[no-untyped-def]
    """Exact simulation of sequences (n_c, n_st) from standstill (twin of ``simulate_path``).

    modes / levels: MODE_* and traction level per candidate and stage; fg_sub / cap_sub:
    grade force [N] and envelope [m^2/s^2] per stage and sub-step; h: sub-step [m].  Returns
    e at the stages, cumulative energy [J] and time [s], each (n_c, n_st + 1).
    """
    tr = p[0]
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
                e, dt, de, _ = strategy_step_one(tr, e, h, fg_sub[k, q], cap_sub[k, q],
                                                 modes[c, k], hold, levels[c, k])
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
    tr = p[0]
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
            e, dt, de, _ = strategy_step_one(tr, e, h, fg_sub[k, q], cap_sub[k, q], modes[i],
                                             e0[i], levels[i])
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


__all__ = ["backward", "forward", "pack_train",
           "simulate_batch", "simulate_stages"]
