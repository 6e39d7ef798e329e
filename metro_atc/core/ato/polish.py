"""Continuous polish of a stage-wise control sequence: regime switch positions off the grid.

A DP profile (:mod:`metro_atc.core.ato.dp`) switches between its regimes (maximum or partial
traction, speed holding, coasting; braking where the envelope demands it) only at stage
boundaries (10 m), and its value function is interpolated on a speed grid; both leave the
switching points of the minimum-energy structure (Pontryagin: maximum traction -- hold --
coast -- maximum brake, e.g. Howlett, Pudney & Vu, Automatica 2009; Albrecht et al., Transp.
Res. B 2016) slightly off, which costs up to about 1 % of energy against the independent LP
optimum on descents and before restrictions.

This module keeps the *regime structure* of the sequence (the runs of equal control and
traction level) and optimises its few continuous parameters -- the positions of the
boundaries between runs, in stage units -- under the running-time bound, with every
candidate simulated exactly (the caller's simulator, e.g.
:func:`metro_atc.core.ato.dp.simulate_path`, vectorised over candidates; no table, no
interpolation):

- a boundary at a fractional position splits its stage; the stage is then driven at the
  traction level of the driving side scaled by its share of the stage (a switch from
  maximum traction to coasting 30 % into a stage = traction level 0.3 over the stage), so
  energy and time are continuous in the positions;
- per iteration, one batch gives the central differences (dE/dx_b, dT/dx_b) of every
  boundary (these single moves are candidates too); the step direction is the gradient of E
  projected onto the tangent of constant running time (the multiplier
  ``mu = -(gE . gT) / |gT|^2``, the marginal energy of time) plus a component along gT that
  uses any time left under the bound; a second batch line-searches step sizes along it;
- the cheapest candidate meeting the time within ``TIME_TOL_S`` replaces the current one;
  the difference step halves when nothing improves.

Deterministic; the result is never worse than the input (if it meets the time).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
from numpy.typing import NDArray

from metro_atc.core.ato.envelope import MODE_ACCEL, MODE_COAST, MODE_CRUISE

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
Simulator = Callable[[IntArray, FloatArray], tuple[FloatArray, FloatArray, FloatArray]]
"""Exact simulation of (controls, levels) (n_c, n_st): (e, cumulative J, cumulative s)."""

TIME_TOL_S = 0.01
"""Running time accepted above the bound [s] (the exact simulation decides)."""
STEPS = (0.05, 0.15, 0.4, 1.0, 2.5)
"""Line-search step lengths [stages] of the largest boundary move."""


@dataclass
class Regimes:
    """Runs of equal (control, level): mode and traction level per run, boundaries [stages].

    bounds: position of the boundary between run r and r + 1 (n_runs - 1,), in stage units
    (0 .. n_stages).
    """

    modes: IntArray
    levels: FloatArray
    bounds: FloatArray
    n_stages: int


@dataclass
class PolishResult:
    """Polished sequence: controls / levels per stage, exact energy [J] / time [s], path.

    path: (e [m^2/s^2], cumulative energy [J], cumulative time [s]) at the stages, each of
    shape (1, n_stages + 1); iterations: gradient iterations; improved: cheaper than input.
    """

    controls: IntArray
    levels: FloatArray
    energy_j: float
    time_s: float
    path: tuple[FloatArray, FloatArray, FloatArray]
    iterations: int
    improved: bool


def regimes_of(controls: IntArray, levels: FloatArray, control_modes: tuple[int, ...]
               ) -> Regimes:
    """Split a stage-wise sequence into runs of equal (mode, level).

    controls index control_modes; levels: traction level per stage.
    """
    c = np.asarray(controls, dtype=np.int64)
    lv = np.asarray(levels, dtype=float)
    mode = np.asarray(control_modes, dtype=np.int64)[c]
    lv = np.where(mode == MODE_ACCEL, lv, np.where(mode == MODE_CRUISE, lv, 1.0))
    chg = np.nonzero((mode[1:] != mode[:-1]) | (np.abs(lv[1:] - lv[:-1]) > 1e-12))[0] + 1
    starts = np.concatenate(([0], chg))
    return Regimes(modes=mode[starts], levels=lv[starts], bounds=chg.astype(float),
                   n_stages=int(c.size))


def render(reg: Regimes, bounds: FloatArray, control_modes: tuple[int, ...]
           ) -> tuple[IntArray, FloatArray]:
    """Stage-wise (controls, levels) of candidates with boundaries ``bounds`` (n_c, n_runs - 1).

    A stage shared by several runs is driven in accelerate mode at the sum of the accelerate
    runs' levels x their shares, else in cruise mode likewise, else it coasts.  Controls are
    the first index of each mode in control_modes.
    """
    cm = list(control_modes)
    i_a, i_c, i_o = cm.index(MODE_ACCEL), cm.index(MODE_CRUISE), cm.index(MODE_COAST)
    b = np.atleast_2d(np.asarray(bounds, dtype=float))
    n_c = b.shape[0]
    n_st = reg.n_stages
    lo = np.concatenate((np.zeros((n_c, 1)), b), axis=1)[:, :, None]
    hi = np.concatenate((b, np.full((n_c, 1), float(n_st))), axis=1)[:, :, None]
    k = np.arange(n_st, dtype=float)[None, None, :]
    w = np.clip(np.minimum(hi, k + 1.0) - np.maximum(lo, k), 0.0, 1.0)   # (n_c, R, n_st)
    is_a = (reg.modes == MODE_ACCEL).astype(float)[None, :, None]
    is_c = (reg.modes == MODE_CRUISE).astype(float)[None, :, None]
    lev = reg.levels[None, :, None]
    pa = np.sum(w * is_a, axis=1)
    la = np.sum(w * is_a * lev, axis=1)
    pc = np.sum(w * is_c, axis=1)
    lc = np.sum(w * is_c * lev, axis=1)
    ctrl = np.where(pa > 1e-12, i_a, np.where(pc > 1e-12, i_c, i_o))
    levels = np.where(pa > 1e-12, la, np.where(pc > 1e-12, lc, 1.0))
    return ctrl.astype(np.int64), np.clip(levels, 0.0, 1.0)


def _order(b: FloatArray, n_st: int) -> FloatArray:
    """Clip boundaries into [0, n_st] and keep them ordered (runs may shrink to zero)."""
    return np.maximum.accumulate(np.clip(b, 0.0, float(n_st)), axis=-1)


def _evaluate(simulate: Simulator, reg: Regimes, bounds: FloatArray,
              control_modes: tuple[int, ...]
              ) -> tuple[FloatArray, FloatArray, IntArray, FloatArray]:
    """Exact (energy [J], time [s], controls, levels) of boundary candidates (n_c, n_b)."""
    ctrl, lev = render(reg, bounds, control_modes)
    _, cj, ct = simulate(ctrl, lev)
    en, tm = cj[:, -1], ct[:, -1]
    bad = ~np.isfinite(tm) | ~np.isfinite(en)
    return np.where(bad, np.inf, en), np.where(bad, np.inf, tm), ctrl, lev


def polish_sequence(simulate: Simulator, control_modes: tuple[int, ...], controls: IntArray,
                    levels: FloatArray, target_time_s: float, max_iterations: int = 6,
                    delta: float = 0.5, rel_tol: float = 2e-5) -> PolishResult:
    """Optimise the boundary positions of a sequence's regimes (exact simulation).

    simulate: exact simulator of candidate sequences (e.g. the DP's ``simulate_path`` bound to
    the run and tables); control_modes: mode of each control index.
    max_iterations: gradient iterations (each two batched simulations); delta: initial
    central-difference step [stages]; stops when an iteration gains less than ``rel_tol``
    of the energy and the difference step is below 0.05 stage.
    """
    reg = regimes_of(controls, levels, control_modes)
    n_st = reg.n_stages
    x = reg.bounds.copy()
    c0 = np.asarray(controls, dtype=np.int64)
    l0 = np.asarray(levels, dtype=float)
    _, cj, ct = simulate(c0[None, :], l0[None, :])
    e_cur, t_cur = float(cj[0, -1]), float(ct[0, -1])
    e_in = e_cur
    best_c, best_l = c0, l0
    limit = target_time_s + TIME_TOL_S
    feasible_in = t_cur <= limit
    it = 0
    n_b = x.size
    if n_b == 0:
        return PolishResult(c0, l0, e_cur, t_cur, simulate(c0[None], l0[None]),
                            0, False)
    for it in range(1, max_iterations + 1):
        eye = np.eye(n_b) * delta
        cand = _order(np.concatenate((x[None, :] + eye, x[None, :] - eye)), n_st)
        en, tm, ctl, lev = _evaluate(simulate, reg, cand, control_modes)
        ib = np.arange(n_b)
        step_d = cand[ib, ib] - cand[n_b + ib, ib]
        with np.errstate(invalid="ignore", divide="ignore"):
            g_e = np.where(step_d > 1e-12, (en[:n_b] - en[n_b:]) / step_d, 0.0)
            g_t = np.where(step_d > 1e-12, (tm[:n_b] - tm[n_b:]) / step_d, 0.0)
        g_e = np.where(np.isfinite(g_e), g_e, 0.0)
        g_t = np.where(np.isfinite(g_t), g_t, 0.0)
        gt2 = float(g_t @ g_t)
        cands_x = [cand]
        cands_r = [(en, tm, ctl, lev)]
        if gt2 > 0.0:
            mu = max(-float(g_e @ g_t) / gt2, 0.0)
            d = -(g_e + mu * g_t)
            d_t = g_t * (target_time_s - 0.5 * TIME_TOL_S - t_cur) / gt2
            sc = float(np.max(np.abs(d)))
            d = d / sc if sc > 0.0 else d
            steps = np.asarray(STEPS)
            ls = np.concatenate((x[None, :] + steps[:, None] * d[None, :],
                                 x[None, :] + steps[:, None] * d[None, :] + d_t[None, :],
                                 x[None, :] + d_t[None, :]))
            ls = _order(ls, n_st)
            cands_x.append(ls)
            cands_r.append(_evaluate(simulate, reg, ls, control_modes))
        xs = np.concatenate(cands_x)
        en = np.concatenate([r[0] for r in cands_r])
        tm = np.concatenate([r[1] for r in cands_r])
        ok = tm <= limit
        gain = 0.0
        if np.any(ok):
            i = int(np.argmin(np.where(ok, en, np.inf)))
            if en[i] < e_cur or t_cur > limit:
                gain = e_cur - float(en[i]) if t_cur <= limit else np.inf
                x = xs[i].copy()
                e_cur, t_cur = float(en[i]), float(tm[i])
                j = i
                for r in cands_r:
                    if j < r[0].size:
                        best_c, best_l = r[2][j], r[3][j]
                        break
                    j -= r[0].size
        if gain <= rel_tol * max(e_cur, 1.0):
            delta *= 0.5
            if delta < 0.05:
                break
    path = simulate(best_c[None, :], best_l[None, :])
    e_f, t_f = float(path[1][0, -1]), float(path[2][0, -1])
    improved = e_f < e_in - 1e-9 * max(e_in, 1.0) or (not feasible_in and t_f <= limit)
    return PolishResult(best_c, best_l, e_f, t_f, path, it, improved)
