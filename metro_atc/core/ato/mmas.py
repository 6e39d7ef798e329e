"""MAX-MIN ant system for the energy-efficient driving strategy (Ke 2010, Sec. 2, 4).

Problem (Ke 2010, eq. 6-7): choose for each of the ``N_s`` sections an operation mode
M = {accelerate, cruise, coast} and a speed code v_i in V to minimise the energy
``E = sum_i E_i(v_i, g_i)`` subject to the average-speed constraint
``L / (sum_i t_i + t_dwell) >= V_av,spec``, i.e. a running-time bound
``sum_i t_i <= T = L / V_av,spec - t_dwell``.  Section energies and times come from the
pre-work tables (:mod:`metro_atc.core.ato.sections`).

Algorithm (Ke 2010, Sec. 2 and 4.2 items 3-8; Stuetzle & Hoos, refs [8, 9]):

- graph G = (M, V, H, T): pheromone on the mode transition of section m -> m+1
  ``tau[m, mode_m, mode_{m+1}]`` (the paper's ``tau_{mi,(m+1)j}``) and on the speed code of each
  section and mode ``tau_v[m, mode, code]``; all pheromones start at the upper bound;
- an ant chooses mode j with probability ``tau[m, i, j] * eta[m, j]^lambda`` (heuristic eta
  from the section's mean gradient, normalised to [0.1, 1]; the paper normalises to [0, 1]
  -- a zero would forbid a mode, so we floor it at 0.1) and then a code with probability
  ``tau_v`` over the codes allowed in the section.  *Reconstruction:* the paper calls
  lambda (0.5) "the proportional factor of pheromone trails and heuristic information"; we
  use it as the heuristic exponent with pheromone exponent 1;
- evaporation ``tau <- (1 - rho) tau`` then deposits by the iteration-best ant
  ``delta_ib * E_bsf / E_ib`` and the best-so-far ant ``delta_bsf`` (the deposit formula is cut
  in the extraction; this is the reconstruction) and clipping to [tau_min, tau_max];
- re-initialisation of all trails to tau_max after ``reinit_after`` iterations without
  improvement of the best-so-far ant;
- constraint handling: a tour violating the running-time bound ranks behind every feasible
  tour (lexicographic penalty);
- local search (Stuetzle & Hoos [8]: "MAX-MIN ant system and local search"): best-improvement
  single-section moves on every new best-so-far tour (on by default; ``local_search=False``
  gives the plain ant system; ``ls_every_iteration=True`` applies it to every
  iteration-best ant, about 20x slower for little gain on the TTOBench metro line);
- continuous local search on the exact simulation (not in the seed,
  :mod:`metro_atc.core.ato.mmas_polish`): the speed commands of the best tour leave the
  5 km/h lattice and its section boundaries leave the equal partition (sub-step
  resolution), every candidate simulated exactly by the compiled kernel
  (:mod:`metro_atc.core.ato.tour_kernel`).  Why: a section in accelerate mode holds its code
  once reached (the code is a ceiling), so on a descent the optimal switch to coasting needs
  a section boundary at the switch point; on the seed's lattice and partition MMAS stayed up
  to 6-15 % above the LP optimum on the TTOBench downhill run.

Deviations from Ke 2010: the local searches above; the heuristic floor 0.1; the deposit
formula (reconstruction); the reported energy and time are the exact simulation of the
planned tour, not the table estimate.

One iteration's ants are built and evaluated on the tables in one compiled call
(:func:`metro_atc.core.ato.mmas_kernel.construct_ants`, the only path;
``NUMBA_DISABLE_JIT=1`` runs it as Python).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Optional

import numpy as np
from numpy.typing import NDArray

from metro_atc.core.ato.envelope import MODE_ACCEL, MODE_COAST, MODE_CRUISE
from metro_atc.core.ato.mmas_kernel import construct_ants, table_prefix
from metro_atc.core.ato.mmas_polish import polish_tour
from metro_atc.core.ato.sections import SectionTables
from metro_atc.core.ato.tour_kernel import TourSimulator, table_kernel

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

_PENALTY_J = 1e15


@dataclass(frozen=True)
class MmasParams:
    """MMAS parameters (Ke 2010, Sec. 5.1 defaults)."""

    n_ants: int = 50
    n_iterations: int = 100
    tau_min: float = 0.2
    tau_max: float = 2.0
    rho: float = 0.1
    lam: float = 0.5
    reinit_after: int = 19
    delta_ib: float = 0.28
    delta_bsf: float = 0.5
    local_search: bool = True
    ls_max_passes: int = 60
    polish_rounds: int = 10
    continuous_polish: bool = True
    exact_polish_rounds: int = 40
    ls_every_iteration: bool = False
    grade_scale: float = 0.02
    seed: int = 1


@dataclass
class MmasResult:
    """Best tour found and its figures.

    modes: per-section mode ints of the planned tour; codes: lattice code indices of the
    colony's best tour (before the continuous search); code_speeds_mps / section_bounds_m:
    the planned tour's speed commands [m/s] (N_s,) and section bounds [m] (N_s + 1,);
    energy_j / time_s: exact simulation of the planned tour (J, s); table_energy_j /
    table_time_s: online-stage (table) estimate of the colony's best tour;
    feasible: exact time within the bound; history: best-so-far energy per iteration [J];
    n_evaluations: tours evaluated; compute_s: online-stage wall time [s].
    """

    modes: IntArray
    codes: IntArray
    energy_j: float
    time_s: float
    table_energy_j: float
    table_time_s: float
    feasible: bool
    history: FloatArray
    n_evaluations: int
    compute_s: float
    s_grid: FloatArray = field(default_factory=lambda: np.zeros(0))
    v_profile: FloatArray = field(default_factory=lambda: np.zeros(0))
    code_speeds_mps: FloatArray = field(default_factory=lambda: np.zeros(0))
    section_bounds_m: FloatArray = field(default_factory=lambda: np.zeros(0))


def heuristic(tables: SectionTables, grade_scale: float = 0.02) -> FloatArray:
    """Heuristic information eta[section, mode] in [0.1, 1] from the mean gradient.

    Up-grades favour accelerate, down-grades favour coast, cruise is neutral (Ke 2010
    Sec. 4.2 item 3: "created by the average gradient of section m").
    """
    g = np.clip(tables.mean_grade / grade_scale, -1.0, 1.0)
    eta = np.empty((g.size, 3))
    eta[:, MODE_ACCEL] = 0.5 * (1.0 + g)
    eta[:, MODE_CRUISE] = 1.0 - 0.5 * np.abs(g)
    eta[:, MODE_COAST] = 0.5 * (1.0 - g)
    return 0.1 + 0.9 * eta


def evaluate_tours(tables: SectionTables, modes: IntArray, codes: IntArray
                   ) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Table-based (online stage) evaluation of tours (K, N_s): (time [s], energy [J], e_end).

    Compiled (:func:`metro_atc.core.ato.tour_kernel.table_kernel`, the arithmetic of
    :meth:`SectionTables.lookup` section by section).
    """
    m = np.ascontiguousarray(modes, dtype=np.int64)
    c = np.ascontiguousarray(codes, dtype=np.int64)
    n_k = m.shape[0]
    e, t, en = np.zeros(n_k), np.zeros(n_k), np.zeros(n_k)
    table_kernel(tables.packed, tables.h_e, int(tables.e_grid.size), tables.n_codes, m, c,
                 np.zeros(n_k, dtype=np.int64), e, t, en)
    return t, en, e


def _score(t: FloatArray, en: FloatArray, t_max: float) -> FloatArray:
    """Lexicographic score: energy if feasible, else penalty plus the violation."""
    ok = t <= t_max + 1e-9
    return np.where(ok, en, _PENALTY_J * (1.0 + np.minimum(t - t_max, 1e6)))


def _sample(weights: FloatArray, u: FloatArray) -> IntArray:
    """Roulette-wheel choice per row of a (K, n) weight array with uniforms u (K,)."""
    cum = np.cumsum(weights, axis=1)
    r = u * cum[:, -1]
    return np.minimum(np.sum(cum <= r[:, None], axis=1), weights.shape[1] - 1).astype(np.int64)


def _neighbours(tables: SectionTables) -> tuple[IntArray, IntArray, IntArray, IntArray]:
    """All single-section moves (section, mode, code) sorted by section, and slice ends."""
    n_s = tables.n_sections
    sec, mode, code = np.nonzero(np.broadcast_to(tables.code_allowed[:, None, :],
                                                 (n_s, 3, tables.n_codes)))
    ends = np.searchsorted(sec, np.arange(n_s), side="right")
    return sec.astype(np.int64), mode.astype(np.int64), code.astype(np.int64), ends


def tour_prefix(tables: SectionTables, modes: IntArray, codes: IntArray
                ) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Table state (e, time [s], energy [J]) of one tour at each section start (N_s,) each."""
    n_s = modes.size
    e_p, t_p, en_p = np.empty(n_s), np.empty(n_s), np.empty(n_s)
    table_prefix(tables.packed, tables.h_e, int(tables.e_grid.size), tables.n_codes,
                 np.ascontiguousarray(modes, dtype=np.int64),
                 np.ascontiguousarray(codes, dtype=np.int64), e_p, t_p, en_p)
    return e_p, t_p, en_p


def evaluate_changed(tables: SectionTables, modes: IntArray, codes: IntArray,
                     prefix: tuple[FloatArray, FloatArray, FloatArray], cm: IntArray,
                     cc: IntArray) -> tuple[FloatArray, FloatArray]:
    """(time [s], energy [J]) of tours (K, N_s) that are changes of one tour (modes, codes).

    Each starts at its first changed section from the tour's state there (``prefix``,
    :func:`tour_prefix`): the same numbers as :func:`evaluate_tours` from the start (the
    same sums in the same order), fewer look-ups.
    """
    diff = (cm != modes[None, :]) | (cc != codes[None, :])
    first = np.where(diff.any(axis=1), np.argmax(diff, axis=1), modes.size - 1)
    e, t, en = (x[first] for x in prefix)
    table_kernel(tables.packed, tables.h_e, int(tables.e_grid.size), tables.n_codes,
                 np.ascontiguousarray(cm, dtype=np.int64),
                 np.ascontiguousarray(cc, dtype=np.int64), first.astype(np.int64), e, t, en)
    return t, en


def evaluate_neighbours(tables: SectionTables, modes: IntArray, codes: IntArray,
                        moves: tuple[IntArray, IntArray, IntArray, IntArray],
                        prefix: "tuple[FloatArray, FloatArray, FloatArray] | None" = None
                        ) -> tuple[FloatArray, FloatArray]:
    """(time [s], energy [J]) of every single-section move of a tour, vectorised.

    A move changing section i shares the tour's prefix up to i: it starts at section i from
    the tour's state there (compiled, :func:`metro_atc.core.ato.tour_kernel.table_kernel`;
    prefix: :func:`tour_prefix` of the tour, computed when not given).
    """
    sec, mode, code, _ = moves
    # the tour's state at the start of each section (the candidates' common prefix)
    e_p, t_p, en_p = tour_prefix(tables, modes, codes) if prefix is None else prefix
    m1 = np.ascontiguousarray(modes[None, :], dtype=np.int64)
    c1 = np.ascontiguousarray(codes[None, :], dtype=np.int64)
    n_e = int(tables.e_grid.size)
    cm = np.repeat(m1, sec.size, axis=0)
    cc = np.repeat(c1, sec.size, axis=0)
    rows = np.arange(sec.size)
    cm[rows, sec] = mode
    cc[rows, sec] = code
    e, t, en = e_p[sec].copy(), t_p[sec].copy(), en_p[sec].copy()
    table_kernel(tables.packed, tables.h_e, n_e, tables.n_codes, cm, cc, sec.copy(), e, t,
                 en)
    return t, en


def local_search(tables: SectionTables, modes: IntArray, codes: IntArray, t_max: float,
                 max_passes: int = 60, mu: Optional[float] = None, swap_span: int = 8
                 ) -> tuple[IntArray, IntArray, float, int]:
    """Best-improvement local search; returns (modes, codes, score, evals).

    Neighbourhood: every single-section (mode, code) change, every exchange of two sections'
    (mode, code), two consecutive sections set to one (mode, code), "accelerate with code c
    up to section j" (length of the acceleration phase), "coast from section j" (the
    coasting point, highest codes) and "no code ceiling while coasting from section j".

    Objective: the lexicographic constrained score (``mu=None``) or the Lagrangian
    ``E + mu T`` (mu [J/s]).  The returned score is always the lexicographic one.
    """
    moves = _neighbours(tables)
    cur_m = modes.copy()
    cur_c = codes.copy()
    t0, e0, _ = evaluate_tours(tables, cur_m[None, :], cur_c[None, :])
    obj = float(_score(t0, e0, t_max)[0]) if mu is None else float(e0[0] + mu * t0[0])
    evals = 1
    n_s = modes.size
    sw_i, sw_j = np.triu_indices(n_s, k=1)
    near = sw_j - sw_i <= swap_span
    sw_i, sw_j = sw_i[near], sw_j[near]
    sel = moves[0] < n_s - 1
    blk_sec, blk_mode, blk_code = moves[0][sel], moves[1][sel], moves[2][sel]
    blk_len = np.full(blk_sec.size, 2)
    top_code = (tables.n_codes - 1 - np.argmax(tables.code_allowed[:, ::-1], axis=1)
                ).astype(np.int64)
    pf_j, pf_code = (a.ravel() for a in np.meshgrid(np.arange(n_s // 2),
                                                    np.arange(tables.n_codes), indexing="ij"))
    n_single = moves[0].size
    for _ in range(max_passes):
        prefix = tour_prefix(tables, cur_m, cur_c)
        t, en = evaluate_neighbours(tables, cur_m, cur_c, moves, prefix)
        # swap moves: exchange the (mode, code) of two sections (moves an acceleration
        # earlier while the coasting moves later: time-neutral trades single moves miss)
        sw_m = np.repeat(cur_m[None, :], sw_i.size, axis=0)
        sw_c = np.repeat(cur_c[None, :], sw_i.size, axis=0)
        rows = np.arange(sw_i.size)
        sw_m[rows, sw_i], sw_m[rows, sw_j] = cur_m[sw_j], cur_m[sw_i]
        sw_c[rows, sw_i], sw_c[rows, sw_j] = cur_c[sw_j], cur_c[sw_i]
        # block moves: two or three consecutive sections set to one (mode, code)
        bl_m = np.repeat(cur_m[None, :], blk_sec.size, axis=0)
        bl_c = np.repeat(cur_c[None, :], blk_sec.size, axis=0)
        rb = np.arange(blk_sec.size)
        for q in range(2):
            on = blk_len > q
            col = np.minimum(blk_sec + q, n_s - 1)
            bl_m[rb[on], col[on]] = blk_mode[on]
            bl_c[rb[on], col[on]] = blk_code[on]
        # prefix moves: accelerate with code c in sections 0..j (the acceleration phase) and
        # suffix moves: coast from section j on (the coasting point)
        pf_m = np.repeat(cur_m[None, :], pf_j.size + n_s, axis=0)
        pf_c = np.repeat(cur_c[None, :], pf_j.size + n_s, axis=0)
        upto = np.arange(n_s)[None, :] <= pf_j[:, None]
        pf_m[:pf_j.size] = np.where(upto, 0, pf_m[:pf_j.size])
        pf_c[:pf_j.size] = np.where(upto, pf_code[:, None], pf_c[:pf_j.size])
        from_j = np.arange(n_s)[None, :] >= np.arange(n_s)[:, None]
        pf_m[pf_j.size:] = np.where(from_j, MODE_COAST, pf_m[pf_j.size:])
        pf_c[pf_j.size:] = np.where(from_j, top_code[None, :], pf_c[pf_j.size:])
        # uncap moves: coasting sections from j on get their highest code (no braking)
        uc_m = np.repeat(cur_m[None, :], n_s, axis=0)
        uc_c = np.where(from_j & (cur_m[None, :] == MODE_COAST), top_code[None, :],
                        np.repeat(cur_c[None, :], n_s, axis=0))
        pf_m = np.concatenate((pf_m, uc_m))
        pf_c = np.concatenate((pf_c, uc_c))
        sw_m = np.concatenate((sw_m, bl_m, pf_m))
        sw_c = np.concatenate((sw_c, bl_c, pf_c))
        t_s, en_s = evaluate_changed(tables, cur_m, cur_c, prefix, sw_m, sw_c)
        t = np.concatenate((t, t_s))
        en = np.concatenate((en, en_s))
        evals += t.size
        sc = _score(t, en, t_max) if mu is None else en + mu * t
        k = int(np.argmin(sc))
        if not sc[k] < obj - 1e-9 * max(1.0, abs(obj)):
            break
        obj = float(sc[k])
        if k < n_single:
            cur_m = cur_m.copy()
            cur_c = cur_c.copy()
            cur_m[moves[0][k]] = moves[1][k]
            cur_c[moves[0][k]] = moves[2][k]
        else:
            cur_m = sw_m[k - n_single].copy()
            cur_c = sw_c[k - n_single].copy()
    t1, e1, _ = evaluate_tours(tables, cur_m[None, :], cur_c[None, :])
    return cur_m, cur_c, float(_score(t1, e1, t_max)[0]), evals


def lagrangian_polish(tables: SectionTables, modes: IntArray, codes: IntArray, t_max: float,
                      rounds: int = 10, max_passes: int = 40
                      ) -> tuple[IntArray, IntArray, float, int]:
    """Local search on ``E + mu T`` with a multiplier search keeping ``T <= t_max``.

    Single moves on the constrained score cannot trade time between sections once the
    running-time bound is active; with the multiplier they can.  mu is bracketed
    geometrically (start: mean power E/T of the tour); the best feasible tour is returned.
    """
    t0, e0, _ = evaluate_tours(tables, modes[None, :], codes[None, :])
    best = (modes.copy(), codes.copy(), float(_score(t0, e0, t_max)[0]))
    evals = 1
    mu = max(float(e0[0] / max(t0[0], 1.0)), 1.0)
    lo, hi = 0.0, np.inf
    cur_m, cur_c = modes.copy(), codes.copy()
    for _ in range(rounds):
        m, c, _, n_ev = local_search(tables, cur_m, cur_c, t_max, max_passes, mu=mu)
        evals += n_ev
        t, en, _ = evaluate_tours(tables, m[None, :], c[None, :])
        sc = float(_score(t, en, t_max)[0])
        if sc < best[2]:
            best = (m, c, sc)
        if t[0] <= t_max + 1e-9:
            hi = mu
            cur_m, cur_c = m, c
        else:
            lo = mu
        mu = np.sqrt(lo * hi) if (lo > 0 and np.isfinite(hi)) else (mu * 4.0 if lo > 0
                                                                    else mu / 4.0)
        if np.isfinite(hi) and lo > 0 and hi / lo < 1.02:
            break
    return best[0], best[1], best[2], evals


def solve_mmas(tables: SectionTables, t_max_s: float,
               params: Optional[MmasParams] = None) -> MmasResult:
    """Online optimisation stage (Ke 2010, Fig. 2): MMAS over the pre-work tables.

    t_max_s: running-time bound [s] from the average-speed constraint (Ke 2010, eq. 7).
    Deterministic for a given ``params.seed``.
    """
    p = params if params is not None else MmasParams()
    t_start = time.perf_counter()
    rng = np.random.default_rng(p.seed)
    n_s, n_c, n_k = tables.n_sections, tables.n_codes, p.n_ants
    eta_l = heuristic(tables, p.grade_scale) ** p.lam
    allowed = tables.code_allowed.astype(float)
    tau_m = np.full((n_s, 3, 3), p.tau_max)
    tau_c = np.full((n_s, 3, n_c), p.tau_max)
    best_m = np.zeros(n_s, dtype=np.int64)
    best_c = np.zeros(n_s, dtype=np.int64)
    best_score = np.inf
    unimproved = 0
    history = np.empty(p.n_iterations)
    evals = 0
    sec_idx = np.arange(n_s)
    n_e = tables.e_grid.size
    packed = tables.packed
    inv_he = 1.0 / tables.h_e
    for it in range(p.n_iterations):
        u = rng.random((n_s, 2, n_k))
        # cumulative choice weights for the whole iteration (pheromone fixed within it)
        cum_m = np.cumsum(tau_m * eta_l[:, None, :], axis=2)
        cum_c = np.cumsum(tau_c * allowed[:, None, :], axis=2)
        modes = np.empty((n_k, n_s), dtype=np.int64)
        codes = np.empty((n_k, n_s), dtype=np.int64)
        t = np.empty(n_k)
        en = np.empty(n_k)
        construct_ants(cum_m, cum_c, u, packed, inv_he, n_e, modes, codes, t, en)
        evals += n_k
        sc = _score(t, en, t_max_s)
        k_ib = int(np.argmin(sc))
        ib_m, ib_c, ib_score = modes[k_ib], codes[k_ib], float(sc[k_ib])
        improved = ib_score < best_score - 1e-6
        if p.local_search and (improved or p.ls_every_iteration):
            ib_m, ib_c, ib_score, n_ev = local_search(tables, ib_m, ib_c, t_max_s,
                                                      p.ls_max_passes)
            evals += n_ev
        if ib_score < best_score - 1e-6:
            best_m, best_c, best_score = ib_m.copy(), ib_c.copy(), ib_score
            unimproved = 0
        else:
            unimproved += 1
        history[it] = best_score
        # pheromone update: evaporation, iteration-best and best-so-far deposits, bounds
        tau_m *= 1.0 - p.rho
        tau_c *= 1.0 - p.rho
        d_ib = p.delta_ib * min(1.0, best_score / max(ib_score, 1e-9))
        for mm, cc, d in ((ib_m, ib_c, d_ib), (best_m, best_c, p.delta_bsf)):
            pm = np.concatenate(([0], mm[:-1]))
            tau_m[sec_idx, pm, mm] += d
            tau_c[sec_idx, mm, cc] += d
        np.clip(tau_m, p.tau_min, p.tau_max, out=tau_m)
        np.clip(tau_c, p.tau_min, p.tau_max, out=tau_c)
        if unimproved >= p.reinit_after:
            tau_m.fill(p.tau_max)
            tau_c.fill(p.tau_max)
            unimproved = 0
    if p.local_search and p.polish_rounds > 0 and np.isfinite(best_score):
        best_m, best_c, best_score, n_ev = lagrangian_polish(tables, best_m, best_c, t_max_s,
                                                             p.polish_rounds, p.ls_max_passes)
        evals += n_ev
    sim = TourSimulator(tables)
    codes_mps = tables.codes_mps
    tt, te, _ = evaluate_tours(tables, best_m[None, :], best_c[None, :])
    t_ex, e_ex, _, stalled, _ = sim.run(best_m[None, :], codes_mps[best_c][None, :])
    # repair: the interpolated tables can underestimate the exact time slightly; tighten
    # the bound by the observed error and search again from the best tour
    for _ in range(3):
        if not (np.isfinite(best_score) and t_ex[0] > t_max_s + 1e-6 and p.local_search):
            break
        t_eff = t_max_s - (t_ex[0] - tt[0]) - 0.05
        best_m, best_c, best_score, n_ev = lagrangian_polish(tables, best_m, best_c, t_eff,
                                                             p.polish_rounds, p.ls_max_passes)
        evals += n_ev
        tt, te, _ = evaluate_tours(tables, best_m[None, :], best_c[None, :])
        t_ex, e_ex, _, stalled, _ = sim.run(best_m[None, :], codes_mps[best_c][None, :])
    speeds = codes_mps[best_c].astype(float)
    bounds_sub = sim.equal_bounds()
    if p.continuous_polish and p.local_search and np.isfinite(best_score):
        # continuous local search on the exact simulation (mmas_polish; not in the seed)
        pt = polish_tour(sim, best_m, speeds, t_max_s, max_rounds=p.exact_polish_rounds)
        evals += pt.evaluations
        if pt.energy_j < float(e_ex[0]) or t_ex[0] > t_max_s + 1e-6:
            best_m, speeds, bounds_sub = pt.modes, pt.speeds_mps, pt.bounds
    hist = sim.history(best_m, speeds, bounds_sub)
    s_grid = sim.s_grid()
    t_fin, e_fin = float(hist[1, -1]), float(hist[2, -1])
    compute = time.perf_counter() - t_start
    return MmasResult(modes=best_m, codes=best_c, energy_j=e_fin, time_s=t_fin,
                      table_energy_j=float(te[0]), table_time_s=float(tt[0]),
                      feasible=bool(t_fin <= t_max_s + 1e-6),
                      history=history, n_evaluations=evals, compute_s=compute,
                      s_grid=s_grid, v_profile=np.sqrt(2.0 * np.maximum(hist[0], 0.0)),
                      code_speeds_mps=speeds,
                      section_bounds_m=np.append(s_grid[bounds_sub], tables.run.length_m))


__all__ = ["MmasParams", "MmasResult", "solve_mmas", "evaluate_tours", "evaluate_changed",
           "tour_prefix", "local_search",
           "heuristic", "MODE_ACCEL", "MODE_CRUISE", "MODE_COAST"]
