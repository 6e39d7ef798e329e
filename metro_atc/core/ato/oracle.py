"""Independent minimum-energy optimum of one run: linear programming in E = v^2/2.

This is the **test oracle and bench reference** of the ATO planners (DP, MMAS, coasting
strategies), written separately from them: it shares only the problem definition (train
parameters, grades, the speed envelope of :class:`~metro_atc.core.ato.envelope.RunModel`)
and none of the planners' simulation code.  It is not an ATO planner (it is too slow for the
node and has no mode structure).

Formulation (kinetic energy per unit mass E = v^2/2 on a distance grid s_0 < ... < s_N;
e.g. Wang & Goverde, Transp. Res. B 2016; Scheepmaker et al., EJOR 2017).  Variables: E_k at
the nodes, traction force F_k >= 0 [N], braking force B_k >= 0 [N] and running time t_k [s]
on every interval of length h_k:

- Newton's law on the interval (constant acceleration, i.e. E linear in s):
  ``M_eff (E_{k+1} - E_k) / h_k = F_k - B_k - R(E_mid) - Fg_k`` with
  ``E_mid = (E_k + E_{k+1}) / 2``, the Davis resistance ``R = A + B v + C v^2``
  (C v^2 = 2 C E is linear; the concave B v term is replaced by its tangent at the
  current iterate, an over-estimate) and the exact mean grade force Fg_k of the interval;
- traction limits at E_mid: ``F_k <= m a_1`` and the convex constant-voltage /
  constant-power branches ``m a_2 / (v + b_2)``, ``m a_3 / (v + b_3)^2`` (ACTP n.d., eq. 3-5)
  by their tangents at the current iterate (under-estimates, i.e. conservative);
- net acceleration ``(E_{k+1} - E_k) / h_k <= a_max``; braking force ``B_k <= M_eff b``;
- the envelope ``E_k <= e_ceiling(s_k)`` (limits for the whole train length, braking curves,
  programmed station stopping), ``E_0 = E_N = 0``;
- running time: ``t_k >= 2 h_k / (v_k + v_{k+1})`` (exact for constant acceleration), a
  convex function of (E_k, E_{k+1}) imposed by supporting hyperplanes (Kelley cutting
  planes, added where the current solution violates it) and ``sum t_k <= T``.

Objective: minimum traction energy at the wheel ``sum F_k h_k`` (no credit for braking, as
the planners).  Solved with scipy's HiGHS (``scipy.optimize.linprog``); the tangents and cuts
are updated until the energy changes by less than ``tol_rel`` and the running-time deficit is
below ``tol_time_s`` (sequential linear programming: at the fixed point every linearisation
is exact).  The grid convergence is shown by :func:`grid_convergence`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy import sparse
from scipy.optimize import linprog

from metro_atc.core.ato.envelope import RunModel
from metro_atc.core.laws import on_array, traction_accel_array

FloatArray = NDArray[np.float64]

_E_FLOOR = 0.005
"""Smallest E [m^2/s^2] (v = 0.1 m/s) at which tangents are taken on interior nodes."""


@dataclass
class OracleResult:
    """Optimum of one run on one grid.

    s_grid [m], v_profile [m/s] (nodes), force_n [N] (net traction - braking per interval),
    traction_n / brake_n [N] per interval; energy_j: traction energy at the wheel [J];
    brake_energy_j: braking work [J]; time_s: running time [s] (exact formula on the profile);
    iterations: LP solves; compute_s: wall time [s]; status: ``optimal``, ``infeasible`` or
    ``max_iterations``.
    """

    s_grid: FloatArray
    v_profile: FloatArray
    traction_n: FloatArray
    brake_n: FloatArray
    energy_j: float
    brake_energy_j: float
    time_s: float
    iterations: int
    compute_s: float
    status: str

    @property
    def feasible(self) -> bool:
        """The LP found a profile meeting the running time."""
        return self.status != "infeasible"


def interval_time(e_a: FloatArray, e_b: FloatArray, h: FloatArray) -> FloatArray:
    """Time [s] over intervals of length h [m] at constant acceleration from E_a to E_b."""
    s = np.sqrt(2.0 * np.maximum(e_a, 0.0)) + np.sqrt(2.0 * np.maximum(e_b, 0.0))
    with np.errstate(divide="ignore"):
        return np.where(s > 0.0, 2.0 * h / np.maximum(s, 1e-300), np.inf)


def _time_cut(e_a: FloatArray, e_b: FloatArray, h: FloatArray, fix_a: FloatArray,
              fix_b: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Supporting hyperplane t >= c0 + ca E_a + cb E_b of the convex interval time.

    Nodes fixed at E = 0 (start/stop) get a zero coefficient (their value never changes);
    other nodes are floored at :data:`_E_FLOOR` so the gradient stays finite.
    """
    a = np.where(fix_a, 0.0, np.maximum(e_a, _E_FLOOR))
    b = np.where(fix_b, 0.0, np.maximum(e_b, _E_FLOOR))
    va, vb = np.sqrt(2.0 * a), np.sqrt(2.0 * b)
    s = va + vb
    g = 2.0 * h / s
    with np.errstate(divide="ignore", invalid="ignore"):
        ca = np.where(fix_a, 0.0, -2.0 * h / (s * s) / np.where(va > 0, va, 1.0))
        cb = np.where(fix_b, 0.0, -2.0 * h / (s * s) / np.where(vb > 0, vb, 1.0))
    return g - ca * a - cb * b, ca, cb


def traction_limit_tangents(run: RunModel, e_star: FloatArray
                            ) -> list[tuple[FloatArray, FloatArray]]:
    """Tangents (value0 [N], slope [N/(m^2/s^2)]) of the traction-force branches at E*.

    The limit is ``m min(a_1, a_2/(v + b_2), a_3/(v + b_3)^2)`` (ACTP n.d., eq. 3-5; the
    branches meet at v_1 and v_2); each branch is convex in E, so its tangent at E* is a
    conservative linear bound ``F <= value0 + slope (E - E*)``.
    """
    p = run.train
    m = p.mass_kg
    es = np.maximum(e_star, _E_FLOOR)
    v = np.sqrt(2.0 * es)
    vmax = float(np.sqrt(2.0 * np.max(run.e_ceiling))) + 1.0
    out: list[tuple[FloatArray, FloatArray]] = []
    a1, _, _, a2, a3, b2, b3 = p.traction_law
    # each branch at every speed: the law with its region stretched over all speeds (the
    # constant-voltage region from v_1 = -inf to v_2 = inf, the constant-power one from
    # v_2 = -inf)
    if p.v1_mps < vmax:
        f2 = m * on_array(traction_accel_array, v, a1, -np.inf, np.inf, a2, a3, b2, b3)
        out.append((f2, -f2 / (v + p.b2_mps) / v))  # dF/dE = dF/dv / v
    if p.v2_mps < vmax:
        f3 = m * on_array(traction_accel_array, v, a1, -np.inf, -np.inf, a2, a3, b2, b3)
        out.append((f3, -2.0 * f3 / (v + p.b3_mps) / v))
    return out


def solve_oracle(run: RunModel, target_time_s: float, ds_m: float = 2.0,
                 tol_rel: float = 1e-6, tol_time_s: float = 1e-3,
                 max_iterations: int = 60) -> OracleResult:
    """Minimum traction energy [J] for running time <= target_time_s [s] on a ds_m grid.

    Raises ValueError on a non-positive grid step or running time.
    """
    if not (ds_m > 0.0 and np.isfinite(ds_m)):
        raise ValueError(f"grid step must be > 0, got {ds_m!r}")
    if not (target_time_s > 0.0 and np.isfinite(target_time_s)):
        raise ValueError(f"running time must be > 0, got {target_time_s!r}")
    t_start = time.perf_counter()
    p = run.train
    lim = run.limits
    n = max(2, int(np.ceil(run.length_m / ds_m)))
    s = np.linspace(0.0, run.length_m, n + 1)
    h = np.diff(s)
    cap = np.maximum(run.ceiling_e(s), 0.0)
    cap[0] = cap[-1] = 0.0
    fg = run.mean_grade_force(s[:-1], s[1:])
    m_eff = p.effective_mass_kg
    # variable layout: E (n+1) | F (n) | B (n) | t (n)
    i_e, i_f, i_b, i_t = 0, n + 1, 2 * n + 1, 3 * n + 1
    n_var = 4 * n + 1
    k = np.arange(n)
    fix_a = k == 0
    fix_b = k == n - 1
    cost = np.zeros(n_var)
    cost[i_f:i_f + n] = h
    bounds = np.zeros((n_var, 2))
    bounds[:i_f, 1] = cap
    bounds[i_f:i_b, 1] = p.mass_kg * p.a1_mps2
    bounds[i_b:i_t, 1] = m_eff * lim.brake_decel_mps2
    bounds[i_t:, 1] = np.inf
    # initial linearisation point and cuts: a ladder of speeds under the envelope
    e_mid_cap = 0.5 * (cap[:-1] + cap[1:])
    e_star = 0.5 * np.maximum(e_mid_cap, _E_FLOOR)
    cut_rows: list[tuple[FloatArray, FloatArray, FloatArray]] = []
    for frac in (0.05, 0.2, 0.45, 0.7, 1.0):
        ea = frac * np.maximum(cap[:-1], _E_FLOOR)
        eb = frac * np.maximum(cap[1:], _E_FLOOR)
        cut_rows.append(_time_cut(ea, eb, h, fix_a, fix_b))
    # static rows: acceleration cap, sum of times
    acc = sparse.csr_matrix((np.concatenate([-np.ones(n), np.ones(n)]),
                             (np.concatenate([k, k]), np.concatenate([i_e + k, i_e + k + 1]))),
                            shape=(n, n_var))
    acc_rhs = lim.accel_max_mps2 * h
    tsum = sparse.csr_matrix((np.ones(n), (np.zeros(n, dtype=int), i_t + k)), shape=(1, n_var))
    energy_prev = np.inf
    status = "max_iterations"
    x = None
    it = 0
    for it in range(1, max_iterations + 1):
        v_star = np.sqrt(2.0 * np.maximum(e_star, _E_FLOOR))
        # dynamics: M/h (E1 - E0) - F + B + (B_d / (2 v*) + C) (E0 + E1) = -Fg - A - B_d v*/2
        cr = 0.5 * p.davis_b_n_per_mps / v_star + p.davis_c_n_per_mps2
        rows = np.concatenate([k, k, k, k])
        cols = np.concatenate([i_e + k, i_e + k + 1, i_f + k, i_b + k])
        vals = np.concatenate([-m_eff / h + cr, m_eff / h + cr, -np.ones(n), np.ones(n)])
        a_eq = sparse.csr_matrix((vals, (rows, cols)), shape=(n, n_var))
        b_eq = -fg - p.davis_a_n - 0.5 * p.davis_b_n_per_mps * v_star
        ub_blocks = [acc, tsum]
        ub_rhs = [acc_rhs, np.array([target_time_s])]
        # traction branches: F - slope (E0 + E1)/2 <= value0 - slope E*
        for f0, slope in traction_limit_tangents(run, e_star):
            vals = np.concatenate([np.ones(n), -0.5 * slope, -0.5 * slope])
            cols = np.concatenate([i_f + k, i_e + k, i_e + k + 1])
            ub_blocks.append(sparse.csr_matrix((vals, (np.concatenate([k, k, k]), cols)),
                                               shape=(n, n_var)))
            ub_rhs.append(f0 - slope * np.maximum(e_star, _E_FLOOR))
        # time cuts: ca E0 + cb E1 - t <= -c0
        for c0, ca, cb in cut_rows:
            vals = np.concatenate([ca, cb, -np.ones(n)])
            cols = np.concatenate([i_e + k, i_e + k + 1, i_t + k])
            ub_blocks.append(sparse.csr_matrix((vals, (np.concatenate([k, k, k]), cols)),
                                               shape=(n, n_var)))
            ub_rhs.append(-c0)
        res = linprog(cost, A_ub=sparse.vstack(ub_blocks, format="csr"),
                      b_ub=np.concatenate(ub_rhs), A_eq=a_eq, b_eq=b_eq,
                      bounds=bounds, method="highs")
        if res.status != 0 or res.x is None:
            status = "infeasible"
            break
        x = res.x
        e = np.clip(x[:i_f], 0.0, cap)
        t_true = interval_time(e[:-1], e[1:], h)
        deficit = float(np.sum(t_true)) - target_time_s
        energy = float(res.fun)
        e_new = 0.5 * (e[:-1] + e[1:])
        moved = float(np.max(np.abs(e_new - e_star))) if it > 1 else np.inf
        e_star = e_new
        violated = t_true - x[i_t:] > 1e-9
        if np.any(violated):
            c0, ca, cb = _time_cut(e[:-1], e[1:], h, fix_a, fix_b)
            keep = violated.astype(float)
            # non-violated intervals get a redundant copy of their previous cut
            prev = cut_rows[-1]
            cut_rows.append((np.where(violated, c0, prev[0]), ca * keep + prev[1] * (1 - keep),
                             cb * keep + prev[2] * (1 - keep)))
        if (abs(energy - energy_prev) <= tol_rel * max(abs(energy), 1.0)
                and deficit <= tol_time_s and moved < 1e-3):
            status = "optimal"
            break
        energy_prev = energy
    elapsed = time.perf_counter() - t_start
    if x is None or status == "infeasible":
        return OracleResult(s, np.zeros(n + 1), np.zeros(n), np.zeros(n), np.inf, 0.0, np.inf,
                            it, elapsed, "infeasible")
    e = np.clip(x[:i_f], 0.0, cap)
    f_tr = x[i_f:i_b]
    f_br = x[i_b:i_t]
    return OracleResult(s_grid=s, v_profile=np.sqrt(2.0 * e), traction_n=f_tr, brake_n=f_br,
                        energy_j=float(np.sum(f_tr * h)), brake_energy_j=float(np.sum(f_br * h)),
                        time_s=float(np.sum(interval_time(e[:-1], e[1:], h))),
                        iterations=it, compute_s=elapsed, status=status)


def grid_convergence(run: RunModel, target_time_s: float,
                     steps_m: tuple[float, ...] = (8.0, 4.0, 2.0, 1.0)
                     ) -> list[tuple[float, float]]:
    """(grid step [m], optimal energy [J]) on successively refined grids."""
    return [(ds, solve_oracle(run, target_time_s, ds).energy_j) for ds in steps_m]
