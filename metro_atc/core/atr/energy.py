"""Energy-aware automatic train regulation (Sheu 2011 abstract; ACTP n.d.; Lin 2010a), ROS-free.

What the seed says
------------------
Our extraction of Sheu 2011 holds only the dissertation abstract: "the models for describing
the traffic environment and energy consumption resulting from traffic regulation are
developed ... With the model, the optimal traffic regulation with higher energy efficiency
is attainable with adequate tailoring of a performance index for the optimization", and the
optimised regulator "shows considerable energy savings".  The energy model, the performance
index and the figures are not in the extraction; everything below is our reconstruction
in that spirit, built on the ATR core of Lin 2010a and the ATO core of ACTP n.d..

Energy-running-time curves E_j(R) [J]
-------------------------------------
Regulation acts on the running time R_j [s] of run j (station j -> j+1); the ATO then
plans that run for R_j with an energy-efficient profile (ACTP n.d.: coasting control; our DP
reference is the minimum-energy profile).  So the energy consumption resulting from
regulation is the traction energy of the planned run as a function of its running time.
:func:`build_energy_table` tabulates it per run for a scenario's train and track
(:mod:`metro_atc.core.bridge`) on a grid of running times from the flat-out minimum to the
ATR maximum running time ``LineData.run_max_s``:

- ``source="dp"`` (default): the DP minimum-energy reference of
  :mod:`metro_atc.core.ato.dp` (Lagrangian relaxation E + mu T).  Instead of one bisection on
  mu per running time (:func:`~metro_atc.core.ato.dp.solve_dp`), one vectorised backward
  pass over a log-grid of multipliers followed by one vectorised forward pass on the tables
  yields points (T(mu), E(mu)) of the lower convex hull of the energy-time front (the
  quantity ``solve_dp`` reports as ``hull_energy_j``); the table interpolates the hull
  linearly.  The forward pass on the tables agrees with the exact re-simulation to within
  3e-4 relative, and the table with ``solve_dp`` at the scheduled running time to within
  0.2 % (measured on Blue line runs; the bench prints this check).
- ``source="ectp"``: the ACTP n.d. coasting-control family used by the ATO node's default
  planner ECTP: Level-II (90 %) traction, cruise at the envelope, coast from y_c, brake;
  one vectorised simulation over a grid of coasting points gives (T(y_c), E(y_c)).

Energies are mechanical traction energy at the wheel [J] (braking is not credited, as in
the ATO core); the catenary energy is about this divided by the traction efficiency.
Physics: a longer running time allows more coasting and a lower cruising speed, so E_j(R)
is decreasing and (on the hull) convex in R.

Per run a smooth convex model is fitted to the table (:func:`fit_curve`) over the
regulation domain [R_lo, R_max], R_lo = the last grid point at or below the ATR minimum
running time ``LineData.run_min_s`` (the traffic model never commands a faster run:
:func:`metro_atc.core.atr.traffic.split_adjustment`): ``hyperbolic``
E(R) = a + b / (R - c), b > 0, c < R_lo (decreasing and convex for R > c; the default), or
``quadratic`` E(R) = p0 + p1 R + p2 R^2, p2 >= 0.  Between the planner's flat-out time and
R_lo the hull has a near-vertical knee (the last seconds towards flat-out cost several kWh)
that no three-parameter model follows; the table keeps it, the fit leaves it out.  Value,
first and second derivative are available; the fit error over the fit domain (and over the
whole table, for information) is reported per run.  Running times are clipped to
[R_lo, R_max] before evaluation (a running time above R_max, e.g. a knock-on wait, is
charged the R_max profile's energy: no credit for waiting).

Energy-aware cost (Sheu 2011: "adequate tailoring of a performance index")
------------------------------------------------------------------------
The stage cost of :mod:`metro_atc.core.atr.cost` plus an energy term on the running-time
part du_run of the adjustment u (:func:`metro_atc.core.atr.traffic.split_adjustment`):

    U_E = U(x, u) + w_E sum_j (E_j(R_j + du_run_{j+1}) - E_j(R_j)) / E_s.

Weight choice: E_s is the traction energy of one service at the scheduled running times,
sum_j E_j(R_j) [J] (:attr:`EnergyTable.e_scale_j`), so w_E [-] is the cost, in units of U
(1/2 q for a deviation of x_s = 60 s at one station), of one whole service's traction
energy: w_E = 1 prices a service's traction energy like a 60 s deviation at two stations.
The size of the effect follows from the terminal run alone (upstream stations ignored):
its steady offset is about -w_E g x_s^2 / ((q + r + w_E x_s^2 h / E_s) E_s) [s], with
g ~ -1.2 MJ/s, h ~ 0.1 MJ/s^2 and E_s ~ 222 kWh on the Blue line about 3 s for w_E = 1.
Measured (bench ``python -m metro_atc bench energy-regulation``, undisturbed): w_E = 1
saves 0.7 % of the traction energy per service for 3.6 s of steady terminal lateness,
w_E = 5 saves 2 % for 12 s.  The default w_E = 1 keeps the lateness within the few
seconds a timetable tolerates as punctual; the bench compares several weights.

Energy-aware LQR (affine-quadratic, average-cost optimal)
--------------------------------------------------------
Scaled variables x~ = x / x_s, u~ = u / x_s; linear model x~(k+1) = A x~ + B u~ (Lin 2010a
eq. 5, unconstrained, so du_run_i = u_i for i >= 1 and station 0 has no run).  Second-order
expansion of E_j around the scheduled running time, g_i = E'_{i-1}(R_{i-1}) [J/s] < 0,
h_i = E''_{i-1}(R_{i-1}) [J/s^2] > 0 (i >= 1; g_0 = h_0 = 0):

    U_E ~ 1/2 q |x~|^2 + 1/2 u~^T R_E u~ + f^T u~,
    R_E = r I + diag(w_E x_s^2 h / E_s),   f = w_E x_s g / E_s.

The linear term makes the infinite sum diverge (every stage saves energy), so optimality is
in the average-cost sense: the limit of the K-stage optimal policy as K -> infinity.  Its
relative value function V(x~) = 1/2 x~^T P x~ + p^T x~ (+ const) solves
V(x~) + lambda = min_u~ [U_E(x~, u~) + V(A x~ + B u~)].  Setting the u~-gradient to zero:

    R_E u~ + f + B^T (P (A x~ + B u~) + p) = 0  =>  u~ = -K x~ + v,
    K = G B^T P A,   v = -G (B^T p + f),   G = (R_E + B^T P B)^-1.

Matching the quadratic terms in x~ gives the DARE for P (``solve_discrete_are(A, B, qI,
R_E)``).  Matching the linear terms (envelope theorem: grad V = Q x~ + A^T grad V(next)) at
x~ = 0, where u~ = v: p = A^T (P B v + p).  With A^T P B G = K^T this is
p = A^T p - K^T (B^T p + f), i.e.

    p = -(I - A_cl^T)^-1 K^T f,   A_cl = A - B K   (stable, so I - A_cl^T is invertible),

and the feed-forward offset v follows.  The closed loop settles at
x~_ss = (I - A_cl)^-1 B v, u~_ss = -K x~_ss + v, the minimiser of U_E over the equilibria
x~ = A x~ + B u~ (turnpike property of convex LQ problems; checked by brute force in
``test/test_atr_energy.py``).  For this A an equilibrium is x_i = x_{i-1} + u_i: every
train runs a little longer and keeps a constant lateness X_i = sum_{l<=i} u_l, the trade of
schedule deviation for energy.  Written in X the linear term is
sum_i (f_i - f_{i+1}) X_i + f_{N-1} X_{N-1}: besides lengthening the runs in total, the
steady state moves running time from runs with a small marginal energy rate |E'| to runs
with a large one (the equal-marginal-rate rule for running-time supplements), so single
offsets can be negative, and it asks for a shorter dwell at the first station (u_0 < 0,
energy-free in the model); the truth model saturates that where the minimum dwell is the
scheduled one (``taipei_blue``), and the feedback then settles at a similar lateness.
g < 0 gives f < 0 and a positive total offset (longer runs);
w_E = 0 gives f = 0, p = 0, v = 0 and R_E = r I: the plain LQR of
:mod:`metro_atc.core.atr.regulators`.  The curvature term h adds to r on the running-time
inputs, so the energy-aware LQR also shortens runs less eagerly after a delay (a shorter
run costs convexly more energy).
"""

from __future__ import annotations

import functools
import math
import time
from dataclasses import dataclass, field
from typing import Optional, Sequence

import numpy as np
from numpy.typing import NDArray
from scipy.linalg import solve_discrete_are
from scipy.optimize import minimize_scalar

from metro_atc.core.ato.coasting import LEVEL_II, simulate_switching
from metro_atc.core.ato.dp import DPTables, lerp, build_dp_tables
from metro_atc.core.ato.envelope import RunModel
from metro_atc.core.atr.blue_line import LineData
from metro_atc.core.atr.cost import CostWeights, stage_cost
from metro_atc.core.atr.regulators import Regulator, RegulatorInputs
from metro_atc.core.atr.traffic import linear_model, split_adjustment
from metro_atc.core.line.scenario import Scenario, load_scenario

FloatArray = NDArray[np.float64]

ENERGY_SOURCES = ("dp", "ectp")
"""Planners the energy-running-time table can be built from."""
FIT_MODELS = ("hyperbolic", "quadratic")
"""Smooth convex models fitted to each run's table."""
J_PER_KWH = 3.6e6
"""Joules per kilowatt-hour."""
MU_MAX_J_PER_S = 1e9
"""Largest DP multiplier [J/s] (the DP's flat-out end, as in ``solve_dp``)."""


# ----------------------------------------------------------------------------- fitting
def _model_eval(model: str, coef: FloatArray, r: FloatArray, order: int) -> FloatArray:
    """Evaluate a fitted model (coef (..., 3)) or its derivative of ``order`` at r [s]."""
    c0, c1, c2 = coef[..., 0], coef[..., 1], coef[..., 2]
    if model == "hyperbolic":          # c0 + c1 / (r - c2)
        d = r - c2
        if order == 0:
            return np.asarray(c0 + c1 / d, dtype=float)
        if order == 1:
            return np.asarray(-c1 / d ** 2, dtype=float)
        return np.asarray(2.0 * c1 / d ** 3, dtype=float)
    if order == 0:                      # quadratic c0 + c1 r + c2 r^2
        return np.asarray(c0 + c1 * r + c2 * r * r, dtype=float)
    if order == 1:
        return np.asarray(c1 + 2.0 * c2 * r, dtype=float)
    return np.asarray(2.0 * c2 + 0.0 * r, dtype=float)


def fit_curve(r_s: FloatArray, e_j: FloatArray, model: str = "hyperbolic"
              ) -> tuple[FloatArray, float, float]:
    """Least-squares fit of a convex, decreasing model to one run's table.

    r_s: running times [s] (increasing), e_j: energies [J].  Returns (coef (3,), RMS error
    [J], max absolute error [J]).  ``hyperbolic``: E = a + b / (R - c) with b > 0 and
    c < min(r_s) (a, b linear least squares for each c, c by a bounded scalar search);
    ``quadratic``: E = p0 + p1 R + p2 R^2 with p2 >= 0 (R centred for conditioning).
    """
    r = np.asarray(r_s, dtype=float)
    e = np.asarray(e_j, dtype=float)
    if model not in FIT_MODELS:
        raise ValueError(f"unknown fit model {model!r}; expected one of {FIT_MODELS}")
    if r.size < 3:
        raise ValueError("at least three tabulated points are needed for a fit")
    if model == "hyperbolic":
        span = max(float(r[-1] - r[0]), 1e-6)

        def lsq(c: float) -> tuple[float, float, float]:
            m = np.stack([np.ones_like(r), 1.0 / (r - c)], axis=1)
            sol, *_ = np.linalg.lstsq(m, e, rcond=None)
            b = max(float(sol[1]), 0.0)
            a = float(np.mean(e - b / (r - c)))
            res = e - a - b / (r - c)
            return a, b, float(np.sum(res * res))

        best = minimize_scalar(lambda c: lsq(float(c))[2],
                               bounds=(float(r[0]) - 20.0 * span, float(r[0]) - 1e-3 * span),
                               method="bounded", options={"xatol": 1e-6 * span})
        c = float(best.x)
        a, b, _ = lsq(c)
        coef = np.array([a, b, c])
    else:
        r0 = float(np.mean(r))
        m = np.stack([np.ones_like(r), r - r0, (r - r0) ** 2], axis=1)
        sol, *_ = np.linalg.lstsq(m, e, rcond=None)
        if sol[2] < 0.0:                 # convexity: best line instead
            sol2, *_ = np.linalg.lstsq(m[:, :2], e, rcond=None)
            sol = np.array([sol2[0], sol2[1], 0.0])
        q0, q1, q2 = (float(v) for v in sol)
        coef = np.array([q0 - q1 * r0 + q2 * r0 * r0, q1 - 2.0 * q2 * r0, q2])
    res = e - _model_eval(model, coef, r, 0)
    return coef, float(np.sqrt(np.mean(res * res))), float(np.max(np.abs(res)))


def lower_hull(t: FloatArray, e: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Lower convex, non-increasing hull of points (t [s], e [J]); returns sorted (t, e)."""
    ok = np.isfinite(t) & np.isfinite(e)
    order = np.lexsort((e[ok], t[ok]))
    ts, es = t[ok][order], e[ok][order]
    hull: list[tuple[float, float]] = []
    for p in zip(ts.tolist(), es.tolist()):
        if hull and abs(p[0] - hull[-1][0]) < 1e-9:
            continue                      # same time: the lower energy came first
        if hull and p[1] >= hull[-1][1]:
            continue                      # slower and not cheaper: dominated
        while len(hull) >= 2:
            (t1, e1), (t2, e2) = hull[-2], hull[-1]
            if (e2 - e1) * (p[0] - t1) >= (p[1] - e1) * (t2 - t1):
                hull.pop()                # middle point above the chord
            else:
                break
        hull.append(p)
    arr = np.asarray(hull, dtype=float)
    return arr[:, 0], arr[:, 1]


# ----------------------------------------------------------------------------- DP sweep
def dp_energy_time_points(tab: DPTables, mu: FloatArray | Sequence[float], forward: bool = True
                          ) -> tuple[FloatArray, FloatArray]:
    """Running time [s] and traction energy [J] of the DP optimum for each multiplier mu.

    One backward pass of the Lagrangian DP (minimise E + mu T, mu [J/s]) vectorised over
    the multipliers (same recursion as :mod:`metro_atc.core.ato.dp`); with ``forward`` a
    vectorised forward pass on the tables from standstill follows (same control choice as
    ``solve_dp``'s table forward pass), else the backward value at standstill is used
    (cheaper, ~1 % error; used to bracket the multiplier range).
    """
    m = np.asarray(mu, dtype=float)
    n_m, n_st, n_s = m.size, tab.n_stages, tab.e_grid.size
    j_all = np.zeros((n_st + 1, n_m, n_s)) if forward else np.zeros((0, 0, 0))
    j_next = np.zeros((n_m, n_s))
    t_next = np.zeros((n_m, n_s))
    for k in range(n_st - 1, -1, -1):
        i0, w = tab.idx0[k], tab.w[k]
        q = tab.energy_j[k][None] + m[:, None, None] * tab.time_s[k][None] \
            + lerp(j_next[:, i0], j_next[:, i0 + 1], w)
        u = np.argmin(q, axis=2)[..., None]
        jk = np.take_along_axis(q, u, axis=2)[..., 0]
        top = int(tab.top[k])
        jk[:, top + 1:] = jk[:, top:top + 1]
        if not forward:
            tq = tab.time_s[k][None] + lerp(t_next[:, i0], t_next[:, i0 + 1], w)
            tk = np.take_along_axis(tq, u, axis=2)[..., 0]
            tk[:, top + 1:] = tk[:, top:top + 1]
            t_next = tk
        else:
            j_all[k] = jk
        j_next = jk
    if not forward:
        t0 = t_next[:, 0]
        return t0, j_next[:, 0] - m * t0
    de = float(tab.e_grid[1] - tab.e_grid[0])
    top_f = n_s - 1.000001
    rows = np.arange(n_m)
    e = np.zeros(n_m)
    energy = np.zeros(n_m)
    tm = np.zeros(n_m)
    alive = np.ones(n_m, dtype=bool)
    for k in range(n_st):
        f = np.clip(e / de, 0.0, top_f)
        i = f.astype(np.int64)
        a = (f - i)[:, None]
        en = lerp(tab.energy_j[k, i], tab.energy_j[k, i + 1], a)
        dt = lerp(tab.time_s[k, i], tab.time_s[k, i + 1], a)
        e_n = tab.e_next[k, i] + a * (tab.e_next[k, i + 1] - tab.e_next[k, i])
        g = np.clip(e_n / de, 0.0, top_f)
        i1 = g.astype(np.int64)
        jn = j_all[k + 1]
        q = en + m[:, None] * dt + lerp(jn[rows[:, None], i1], jn[rows[:, None], i1 + 1],
                                        g - i1)
        q = np.where(np.isfinite(dt), q, np.inf)
        u = np.argmin(q, axis=1)
        alive &= np.isfinite(q[rows, u])
        e = e_n[rows, u]
        energy += en[rows, u]
        tm += dt[rows, u]
    return np.where(alive, tm, np.inf), np.where(alive, energy, np.inf)


def _dp_points(run: RunModel, r_hi_s: float, ds_m: float, de_m2s2: float, n_mu: int
               ) -> tuple[FloatArray, FloatArray]:
    """(T, E) points of the DP hull covering [flat-out, >= r_hi_s] for one run."""
    tab = build_dp_tables(run, ds_m, de_m2s2)
    coarse = np.geomspace(1e3, MU_MAX_J_PER_S, 19)
    t_c, _ = dp_energy_time_points(tab, coarse, forward=False)
    slow = np.nonzero(t_c >= 1.03 * r_hi_s)[0]
    mu_lo = float(coarse[slow[-1]]) if slow.size else float(coarse[0])
    return dp_energy_time_points(tab, np.geomspace(mu_lo, MU_MAX_J_PER_S, n_mu))


def _ectp_points(run: RunModel, h_m: float, n_coast: int) -> tuple[FloatArray, FloatArray]:
    """(T, E) points of the ACTP n.d. coasting family (Level-II traction) for one run."""
    yc = np.linspace(0.0, run.length_m + 1.0, n_coast)
    sim = simulate_switching(run, yc, np.full(n_coast, LEVEL_II), h_m)
    return sim.time_s, sim.energy_j


# ----------------------------------------------------------------------------- tables
@dataclass(frozen=True)
class EnergyTable:
    """Energy-running-time curves E_j(R) of every run of a line (Sheu 2011 / ACTP n.d.).

    r_grid_s, e_grid_j: (n_runs, n_grid) tabulated running times [s] and traction energies
    [J] (lower convex hull of the planner's energy-time points); r_fast_s / r_max_s:
    (n_runs,) flat-out and maximum tabulated running times [s]; r_lo_s: (n_runs,) lower end
    of the fit domain [s]; r_sched_s: (n_runs,) scheduled running times [s]; model / coef
    (n_runs, 3): the fitted smooth model; fit_rms_j / fit_max_j: (n_runs,) RMS and maximum
    fit error over the fit domain [J]; table_max_j: (n_runs,) maximum deviation of the model
    from the whole table (incl. the flat-out knee) [J]; build_s / build_cpu_s: wall and
    CPU time of the build [s].
    """

    scenario: str
    source: str
    model: str
    r_grid_s: FloatArray
    e_grid_j: FloatArray
    r_fast_s: FloatArray
    r_max_s: FloatArray
    r_lo_s: FloatArray
    r_sched_s: FloatArray
    coef: FloatArray
    fit_rms_j: FloatArray
    fit_max_j: FloatArray
    table_max_j: FloatArray
    build_s: float = 0.0
    build_cpu_s: float = 0.0
    notes: tuple[str, ...] = field(default_factory=tuple)

    @property
    def n_runs(self) -> int:
        """Number of inter-station runs."""
        return int(self.r_fast_s.size)

    def _clip(self, r_s: FloatArray) -> FloatArray:
        r = np.asarray(r_s, dtype=float)
        if r.shape[-1] != self.n_runs:
            raise ValueError(f"running times have {r.shape[-1]} entries, the table has "
                             f"{self.n_runs} runs")
        return np.clip(r, self.r_lo_s, self.r_max_s)

    def energy_j(self, r_s: FloatArray) -> FloatArray:
        """Traction energy [J] of each run for running times r_s [s], shape (..., n_runs)."""
        return _model_eval(self.model, self.coef, self._clip(r_s), 0)

    def d_energy_j_per_s(self, r_s: FloatArray) -> FloatArray:
        """dE_j/dR [J/s] (< 0) at running times r_s [s], shape (..., n_runs)."""
        return _model_eval(self.model, self.coef, self._clip(r_s), 1)

    def d2_energy_j_per_s2(self, r_s: FloatArray) -> FloatArray:
        """d^2E_j/dR^2 [J/s^2] (>= 0) at running times r_s [s], shape (..., n_runs)."""
        return _model_eval(self.model, self.coef, self._clip(r_s), 2)

    def tabulated_energy_j(self, r_s: FloatArray) -> FloatArray:
        """Table (hull) energy [J], linear interpolation, at running times r_s (n_runs,)."""
        r = np.asarray(r_s, dtype=float).reshape(self.n_runs)
        return np.array([np.interp(r[j], self.r_grid_s[j], self.e_grid_j[j])
                         for j in range(self.n_runs)])

    @property
    def e_sched_j(self) -> FloatArray:
        """Traction energy [J] of each run at its scheduled running time, (n_runs,)."""
        return self.energy_j(self.r_sched_s)

    @property
    def e_scale_j(self) -> float:
        """E_s [J]: traction energy of one service at the scheduled running times."""
        return float(np.sum(self.e_sched_j))

    @property
    def fit_max_rel(self) -> float:
        """Largest fit error relative to the run's scheduled energy [-]."""
        return float(np.max(self.fit_max_j / self.e_sched_j))

    def summary(self) -> dict[str, object]:
        """Build time, fit errors and energies [kWh] as plain types (for reports)."""
        return {
            "scenario": self.scenario, "source": self.source, "model": self.model,
            "n_runs": self.n_runs, "n_grid": int(self.r_grid_s.shape[1]),
            "build_s": self.build_s, "build_cpu_s": self.build_cpu_s,
            "fit_rms_kwh_max": float(np.max(self.fit_rms_j)) / J_PER_KWH,
            "fit_max_abs_kwh": float(np.max(self.fit_max_j)) / J_PER_KWH,
            "fit_max_rel": self.fit_max_rel,
            "fit_rms_rel_mean": float(np.mean(self.fit_rms_j / self.e_sched_j)),
            "table_max_rel_incl_flat_out_knee": float(np.max(self.table_max_j
                                                             / self.e_sched_j)),
            "service_energy_sched_kwh": self.e_scale_j / J_PER_KWH,
            "service_energy_fast_kwh": float(np.sum(self.e_grid_j[:, 0])) / J_PER_KWH,
            "service_energy_rmax_kwh": float(np.sum(self.e_grid_j[:, -1])) / J_PER_KWH,
            "notes": list(self.notes),
        }


def build_energy_table(scn: Scenario, line: Optional[LineData] = None, source: str = "dp",
                       model: str = "hyperbolic", n_grid: int = 31, ds_m: float = 10.0,
                       de_m2s2: float = 1.0, n_mu: int = 40, h_m: float = 4.0,
                       n_coast: int = 96, runs: Optional[Sequence[int]] = None
                       ) -> EnergyTable:
    """Tabulate and fit E_j(R) [J] for the runs of a scenario (Sheu 2011 / ACTP n.d.).

    line: the ATR line of the scenario (default :func:`metro_atc.core.bridge.atr_line_for`);
    it gives the scheduled and maximum running times; a line whose stations are the
    scenario's in reverse order (the down direction,
    :func:`metro_atc.core.service.regulation.direction_line`) is tabulated for runs in that
    direction (run j from its station j to j+1, chainage decreasing).
    source: ``dp`` (minimum-energy reference; grid ``ds_m`` [m] x ``de_m2s2`` [m^2/s^2],
    ``n_mu`` multipliers) or ``ectp`` (ACTP n.d. coasting family at Level II; step ``h_m``
    [m], ``n_coast`` coasting points).
    n_grid: running times per run from the planner's flat-out time to ``run_max_s``; the
    model is fitted from the last grid point at or below ``run_min_s`` on.
    runs: subset of run indices (default all; a subset gives a table of that subset).
    """
    from metro_atc.core.bridge import (ato_limits_for, atr_line_for, timetable_for, track_for,
                                       train_for)

    if source not in ENERGY_SOURCES:
        raise ValueError(f"unknown energy source {source!r}; expected one of {ENERGY_SOURCES}")
    if n_grid < 3:
        raise ValueError("n_grid must be >= 3")
    t0, c0 = time.perf_counter(), time.process_time()
    tt = timetable_for(scn)
    ln = line if line is not None else atr_line_for(scn, tt)
    pos = np.asarray(tt.station_positions_m, dtype=float)
    names = tuple(tt.station_names)
    if tuple(ln.station_names) == names[::-1] and names != names[::-1]:
        pos = pos[::-1].copy()  # the line runs the scenario's stations backwards (down)
    if pos.size - 1 != ln.run_s.size:
        raise ValueError(f"line {ln.name!r} has {ln.run_s.size} runs, scenario "
                         f"{scn.name!r} has {pos.size - 1}")
    train, track = train_for(scn), track_for(scn)
    limits = ato_limits_for(train)
    idx = list(range(ln.run_s.size)) if runs is None else [int(j) for j in runs]
    rg = np.zeros((len(idx), n_grid))
    eg = np.zeros((len(idx), n_grid))
    coef = np.zeros((len(idx), 3))
    rms = np.zeros(len(idx))
    mx = np.zeros(len(idx))
    r_lo = np.zeros(len(idx))
    tmx = np.zeros(len(idx))
    notes: list[str] = []
    for row, j in enumerate(idx):
        run = RunModel(train, track, float(pos[j]), float(pos[j + 1]), limits)
        r_hi = float(ln.run_max_s[j])
        if source == "dp":
            t_pts, e_pts = _dp_points(run, r_hi, ds_m, de_m2s2, n_mu)
        else:
            t_pts, e_pts = _ectp_points(run, h_m, n_coast)
        th, eh = lower_hull(t_pts, e_pts)
        if th[-1] < r_hi:
            notes.append(f"run {j}: slowest planned profile {th[-1]:.1f} s < run_max "
                         f"{r_hi:.1f} s; table ends there")
            r_hi = float(th[-1])
        if th[0] >= r_hi:
            raise ValueError(f"run {j}: flat-out time {th[0]:.1f} s >= maximum running time "
                             f"{r_hi:.1f} s")
        rg[row] = np.linspace(th[0], r_hi, n_grid)
        eg[row] = np.interp(rg[row], th, eh)
        first = max(min(int(np.searchsorted(rg[row], float(ln.run_min_s[j]), side="right")) - 1,
                        n_grid - 3), 0)
        r_lo[row] = rg[row, first]
        coef[row], rms[row], mx[row] = fit_curve(rg[row, first:], eg[row, first:], model)
        tmx[row] = float(np.max(np.abs(eg[row] - _model_eval(model, coef[row], rg[row], 0))))
    return EnergyTable(scenario=scn.name, source=source, model=model, r_grid_s=rg,
                       e_grid_j=eg, r_fast_s=rg[:, 0].copy(), r_max_s=rg[:, -1].copy(),
                       r_lo_s=r_lo, r_sched_s=np.asarray(ln.run_s, dtype=float)[idx],
                       coef=coef, fit_rms_j=rms, fit_max_j=mx, table_max_j=tmx,
                       build_s=time.perf_counter() - t0, build_cpu_s=time.process_time() - c0,
                       notes=tuple(notes))


@functools.lru_cache(maxsize=8)
def energy_table_for(scenario: str, source: str = "dp", model: str = "hyperbolic",
                     n_grid: int = 31) -> EnergyTable:
    """Cached :func:`build_energy_table` for an embedded scenario name or YAML path.

    Computed once per process (a few seconds for the 22 Blue line runs with ``dp``).
    """
    return build_energy_table(load_scenario(scenario), source=source, model=model,
                              n_grid=n_grid)


# ----------------------------------------------------------------------------- cost
def run_adjustment(line: LineData, u_s: FloatArray) -> FloatArray:
    """Running-time part of adjustments u (..., N) [s] per run, shape (..., N-1)."""
    du_run, _ = split_adjustment(line, u_s)
    return du_run[..., 1:]


def energy_term(line: LineData, table: EnergyTable, u_s: FloatArray, w_energy: float,
                e_scale_j: Optional[float] = None) -> FloatArray:
    """w_E sum_j (E_j(R_j + du_run_j) - E_j(R_j)) / E_s for adjustments u [s]; shape (...,).

    du_run from :func:`metro_atc.core.atr.traffic.split_adjustment` (saturated running
    part); E_s defaults to :attr:`EnergyTable.e_scale_j`.
    """
    es = table.e_scale_j if e_scale_j is None else float(e_scale_j)
    r = line.run_s + run_adjustment(line, u_s)
    return np.asarray(w_energy * np.sum(table.energy_j(r) - table.e_sched_j, axis=-1) / es,
                      dtype=float)


def energy_aware_stage_cost(line: LineData, table: EnergyTable, x_s: FloatArray,
                            u_s: FloatArray, weights: CostWeights, w_energy: float,
                            e_scale_j: Optional[float] = None) -> FloatArray:
    """U_E = U(x, u) (:func:`metro_atc.core.atr.cost.stage_cost`) + energy term; (...,)."""
    return stage_cost(x_s, u_s, weights) + energy_term(line, table, u_s, w_energy, e_scale_j)


# ----------------------------------------------------------------------------- affine LQR
@dataclass(frozen=True)
class AffineLqr:
    """Solution of the affine-quadratic (average-cost) LQ problem in scaled units.

    k: gain (u~ = -k x~ + v); v: feed-forward offset; p_mat / p_vec: relative value
    function 1/2 x~^T P x~ + p^T x~; x_ss / u_ss: closed-loop steady state (all scaled).
    """

    k: FloatArray
    v: FloatArray
    p_mat: FloatArray
    p_vec: FloatArray
    x_ss: FloatArray
    u_ss: FloatArray


def affine_lqr(a: FloatArray, b: FloatArray, q_mat: FloatArray, r_mat: FloatArray,
               f: FloatArray) -> AffineLqr:
    """Minimise the average of 1/2 x^T Q x + 1/2 u^T R u + f^T u, x+ = A x + B u.

    Derivation in the module docstring: P from the DARE, p = -(I - A_cl^T)^-1 K^T f,
    v = -(R + B^T P B)^-1 (B^T p + f).
    """
    n = a.shape[0]
    p = solve_discrete_are(a, b, q_mat, r_mat)
    p = 0.5 * (p + p.T)
    g_inv = r_mat + b.T @ p @ b
    k = np.linalg.solve(g_inv, b.T @ p @ a)
    a_cl = a - b @ k
    pv = np.asarray(-np.linalg.solve(np.eye(n) - a_cl.T, k.T @ f), dtype=float)
    v = np.asarray(-np.linalg.solve(g_inv, b.T @ pv + f), dtype=float)
    x_ss = np.asarray(np.linalg.solve(np.eye(n) - a_cl, b @ v), dtype=float)
    return AffineLqr(k=k, v=v, p_mat=p, p_vec=pv, x_ss=x_ss, u_ss=-k @ x_ss + v)


class EnergyLqrRegulator(Regulator):
    """Energy-aware LQR (Sheu 2011 idea on the Lin 2010a linear model): u = -K x + u_ff.

    line: the ATR line; table: its energy-running-time curves (same runs); weights: the
    schedule-deviation cost (q, r, x_s); w_energy: w_E [-]; e_scale_j: E_s [J] (default:
    one service's scheduled traction energy).  Attributes (seconds unless stated): ``k``
    gain [-], ``u_ff_s`` feed-forward offset, ``x_ss_s`` / ``u_ss_s`` closed-loop steady
    state of the linear model, ``g_j_per_s`` / ``h_j_per_s2`` the expansion coefficients
    per station (0 at station 0), ``r_e`` the input weight R_E [-], ``f`` the linear
    term [-].  Saturation is not applied here (as for every regulator).
    """

    name = "elqr"

    def __init__(self, line: LineData, table: EnergyTable,
                 weights: Optional[CostWeights] = None, w_energy: float = 1.0,
                 e_scale_j: Optional[float] = None) -> None:
        """Expand E_j at the scheduled running times and solve the affine LQ problem."""
        super().__init__(line.n_stations)
        if table.n_runs != line.n_stations - 1:
            raise ValueError(f"energy table has {table.n_runs} runs, line {line.name!r} has "
                             f"{line.n_stations - 1}")
        if not (math.isfinite(w_energy) and w_energy >= 0.0):
            raise ValueError(f"w_energy must be finite and >= 0, got {w_energy!r}")
        w = weights if weights is not None else CostWeights()
        es = table.e_scale_j if e_scale_j is None else float(e_scale_j)
        if not (math.isfinite(es) and es > 0.0):
            raise ValueError(f"e_scale_j must be finite and > 0, got {e_scale_j!r}")
        self.weights, self.w_energy, self.e_scale_j = w, float(w_energy), es
        n, xs = line.n_stations, w.x_scale_s
        g = np.zeros(n)
        h = np.zeros(n)
        g[1:] = table.d_energy_j_per_s(line.run_s)
        h[1:] = table.d2_energy_j_per_s2(line.run_s)
        self.g_j_per_s, self.h_j_per_s2 = g, h
        a, b = linear_model(line.c())
        self.r_e = w.r * np.eye(n) + np.diag(self.w_energy * xs * xs * h / es)
        self.f = self.w_energy * xs * g / es
        sol = affine_lqr(a, b, w.q * np.eye(n), self.r_e, self.f)
        self.solution = sol
        self.k = sol.k
        self.u_ff_s = sol.v * xs
        self.x_ss_s = sol.x_ss * xs
        self.u_ss_s = sol.u_ss * xs

    def decide(self, x_s: FloatArray, step: int = 0) -> FloatArray:
        """u = -K x + u_ff [s] (shape of x)."""
        return np.asarray(-(self._check(x_s) @ self.k.T) + self.u_ff_s, dtype=float)


__all__ = ["AffineLqr", "ENERGY_SOURCES", "EnergyLqrRegulator", "EnergyTable", "FIT_MODELS",
           "J_PER_KWH", "affine_lqr", "build_energy_table",
           "dp_energy_time_points", "energy_aware_stage_cost", "energy_table_for",
           "energy_term", "fit_curve", "lower_hull", "run_adjustment"]


def build_elqr(name: str, inputs: RegulatorInputs) -> Regulator:
    """Factory of ``elqr`` (:data:`metro_atc.core.atr.registry.REGULATORS`).

    The energy table is built from ``inputs.scenario`` (a few seconds); ValueError when
    there is none.
    """
    if inputs.scenario is None:
        raise ValueError(f"regulator {name!r} needs the scenario (its energy table)")
    return EnergyLqrRegulator(inputs.line, build_energy_table(inputs.scenario, inputs.line),
                              inputs.cost, inputs.energy_weight)
