"""Dynamic-programming reference optimum: minimum traction energy for a given running time.

Grid: distance stages ``s_k = k ds`` x speed states ``e_j = j h_e`` (kinetic energy per unit
mass e = v^2/2).  Controls per stage (the switching structure of the minimum-energy train
control problem: maximum traction, speed holding, coasting, braking):

- ``accelerate`` at traction level 1.0 and 0.5 (ACTP n.d., eq. 3-5, net accel <= a_max),
- ``cruise`` (hold the stage entry speed),
- ``coast`` (closed-form coasting, ACTP n.d., eq. 7-8),

each simulated exactly over the stage by :func:`metro_atc.core.ato.step_kernel.strategy_step`
(the same physics and the same envelope -- limits incl. train length, braking curves,
programmed stopping -- as every planner; braking happens where the envelope demands it).
The landing speed of a control is off-grid, so the value function of the next stage is
interpolated linearly in e (standard DP on a continuous state, e.g. Bertsekas, *Dynamic
Programming and Optimal Control*, Vol. 1, Ch. 6).

Running-time constraint by Lagrangian relaxation: for a multiplier mu [J/s] the backward
recursion minimises ``E + mu T``; ``T(mu)`` is non-increasing.  The multiplier is searched
in rounds of ``MU_BATCH`` values on a log grid, each round one backward and one forward pass
batched over the multipliers (compiled loops over multipliers x states x controls), until the
bracket [slowest feasible, fastest infeasible] is narrower than ``MU_LOG_TOL`` in log(mu).

Closing the duality gap.  ``T(mu)`` jumps (a stage more or less of traction changes the
running time by up to a second on descents), so the best Lagrangian profile can leave time
unused and cost several per cent more than the constrained optimum (seen against the
independent LP optimum, :mod:`metro_atc.core.ato.oracle`).  The two profiles bracketing the
target are therefore spliced (the slower policy up to stage k, the faster one after it;
every k at once in one vectorised forward pass, the cheapest meeting the time), and inside
the switching stage the traction level of its accelerate / cruise control is swept over
``BLEND_LEVELS`` values (vectorised) so that the running time meets the target; the faster
policy continues from the exact state.  The candidate control sequences (Lagrangian best,
splice, blend, and the slower bracket end) are finally simulated exactly together (no grid
error in the reported energy / time) and the cheapest meeting the time within 0.05 s wins.

Rollout polish.  Switching only at stage boundaries (10 m) with a value function
interpolated on a 1 m^2/s^2 grid leaves the end of an acceleration phase up to a few km/h off
(Ke 2010, case 2: the train then reaches a 50 km/h restriction below the limit and holds a
lower speed for longer, +0.95 % against the LP optimum; refining the grids alone does not
converge: ds 5 m / de 0.25 gives +0.44 %, ds 2.5 m +0.69 %).  The winner is improved by
rollout (:func:`_rollout`): near every change of control, the stage is re-simulated exactly at
a continuous traction level and the DP policies of the bracketing multipliers re-plan the rest
of the run; the cheapest candidate meeting the time replaces the winner (``ROLLOUT_ROUNDS``
rounds, each checked by exact simulation).

Continuous polish.  The rollout still switches inside one stage at a time and re-plans on the
tables, so switching points stay a few metres off (Ke 2010, case 2 +0.55 %, a generated line
+1.06 % against the LP optimum).  Finally the regime structure of the winner (runs of equal
control and level) is kept and the positions of its boundaries are optimised continuously
under the running-time bound by a projected-gradient search with exact simulation
(:func:`metro_atc.core.ato.polish.polish_sequence`, ``POLISH_ITERATIONS``), from the rollout's
winner and from the candidate before the rollout (their structures can differ).

Speed.  The exact simulations (whole sequences and single stages) and the table backward /
forward passes run on compiled loops (:mod:`metro_atc.core.ato.dp_kernel`, numba; one path,
``NUMBA_DISABLE_JIT=1`` runs the same source as Python for debugging).  The former numpy
twins of these loops are gone; their recorded output (``test/data/dp_numpy_ref.npz``) is the
reference the compiled path is tested against.  In numpy each sub-step of a simulation was
one interpreted call over a few dozen candidates, which made the polish 85 % of a 3-10 s
solve; compiled, a solve takes about 0.1 s of CPU.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Optional

import numpy as np
from numpy.typing import ArrayLike, NDArray

from metro_atc.core.ato import dp_kernel
from metro_atc.core.ato.envelope import MODE_ACCEL, MODE_COAST, MODE_CRUISE, RunModel
from metro_atc.core.ato.polish import polish_sequence
from metro_atc.core.ato.step_kernel import pack_train, run_substeps

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

CONTROL_MODES = (MODE_ACCEL, MODE_ACCEL, MODE_CRUISE, MODE_COAST)
"""Mode of each DP control."""
CONTROL_LEVELS = (1.0, 0.5, 1.0, 1.0)
"""Traction level of each DP control (cruise uses full traction when needed)."""
MU_MAX = 1e9
"""Largest multiplier [J/s] (the flat-out end of the energy-time front)."""
MU_BATCH = 12
"""Multipliers per round of the multiplier search."""
MU_ROUNDS = 4
"""Most rounds of the multiplier search."""
MU_LOG_TOL = 0.02
"""Bracket width in log(mu) at which the multiplier search stops."""
BLEND_LEVELS = 32
"""Traction levels tried in the switching stage of the spliced profile."""
ROLLOUT_LEVELS = 8
"""Traction levels per mode tried at every stage by the rollout polish."""
ROLLOUT_ROUNDS = 4
"""Rollout improvements of the chosen control sequence."""
ROLLOUT_SPAN = 3
"""Stages either side of a control change of the base tried by the rollout."""
POLISH_ITERATIONS = 8
"""Gradient iterations of the continuous switch-position polish (0: off)."""


@dataclass
class DPTables:
    """Stage transitions for every grid state and control.

    e_next [m^2/s^2], energy_j [J], time_s [s]: shape (n_stages, n_states, n_controls);
    idx0/w: linear-interpolation index and weight of e_next on the state grid
    (:func:`state_weights`); top: highest grid state under the envelope per stage boundary;
    fg_sub / cap_sub: grade force [N] and envelope (v^2/2) per stage and sub-step.
    """

    s_grid: FloatArray
    e_grid: FloatArray
    e_next: FloatArray
    energy_j: FloatArray
    time_s: FloatArray
    idx0: IntArray
    w: FloatArray
    top: IntArray
    substeps: int
    fg_sub: FloatArray
    cap_sub: FloatArray

    @property
    def n_stages(self) -> int:
        """Number of distance stages."""
        return int(self.s_grid.size - 1)


@dataclass
class DPResult:
    """DP optimum: exact profile (s [m], v [m/s]), energy [J], time [s], multiplier [J/s].

    controls: control index per stage; hull_energy_j: energy-time hull at the target time
    [J]; feasible: the target time is met within 0.05 s (else the fastest profile is
    returned); compute_s: CPU time [s]; n_passes: rounds of the multiplier search
    (each one vectorised backward and forward pass); levels: traction level per stage.
    """

    s_grid: FloatArray
    v_profile: FloatArray
    controls: IntArray
    energy_j: float
    time_s: float
    mu: float
    hull_energy_j: float
    feasible: bool
    compute_s: float
    n_passes: int
    levels: Optional[FloatArray] = None


def build_dp_tables(run: RunModel, ds_m: float = 10.0, de_m2s2: float = 1.0,
                    substep_m: float = 5.0) -> DPTables:
    """Tabulate every (stage, state, control) transition of the run.

    ds_m: stage length [m] (rounded to tile the run); de_m2s2: state step of e = v^2/2
    [m^2/s^2]; substep_m: integration step inside a stage [m].  Vectorised over all stages
    and states at once, one control at a time (the coasting solution, the costly one, is
    computed once rather than for every control).
    """
    n_st = max(1, int(round(run.length_m / ds_m)))
    s = np.linspace(0.0, run.length_m, n_st + 1)
    ds = run.length_m / n_st
    n_sub = max(1, int(np.ceil(ds / substep_m - 1e-9)))
    cap = run.ceiling_e(s)
    n_states = int(np.ceil(np.max(cap) / de_m2s2)) + 2
    e = np.arange(n_states, dtype=float) * de_m2s2
    n_u = len(CONTROL_MODES)
    h = ds / n_sub
    a_sub = s[:-1, None] + np.arange(n_sub)[None, :] * h
    fg_sub = run.mean_grade_force(a_sub, a_sub + h)
    cap_sub = run.ceiling_e(a_sub + h)
    # states above the envelope start from the envelope (clamped above): this keeps the
    # interpolation between the top feasible state and the next one well defined
    e_start = np.minimum(e[None, :], cap[:-1, None])
    e_next = np.empty((n_st, n_states, n_u))
    en = np.empty_like(e_next)
    tm = np.empty_like(e_next)
    tr = pack_train(run.train, run.limits).view(np.recarray)
    e_flat = np.ascontiguousarray(e_start).reshape(-1)
    no_code = np.full(e_flat.size, np.inf)
    no_latch = np.zeros(e_flat.size, dtype=bool)
    for u, (mode, level) in enumerate(zip(CONTROL_MODES, CONTROL_LEVELS)):
        cur, t_u, j_u, _ = run_substeps(tr, e_flat, h, fg_sub, cap_sub, mode, no_code, e_flat,
                                        float(level), run.limits.brake_decel_mps2, no_latch,
                                        False)
        e_next[..., u] = cur.reshape(e_start.shape)
        en[..., u] = j_u.reshape(e_start.shape)
        tm[..., u] = t_u.reshape(e_start.shape)
    infeasible = ~np.isfinite(tm)
    tm[infeasible] = np.inf
    en[infeasible] = np.inf
    top = np.minimum(np.floor(cap / de_m2s2 + 1e-9).astype(np.int64), n_states - 1)
    idx0, w = _weights(e_next, de_m2s2, n_states)
    return DPTables(s_grid=s, e_grid=e, e_next=e_next, energy_j=en, time_s=tm, idx0=idx0,
                    w=w, top=top, substeps=n_sub, fg_sub=fg_sub, cap_sub=cap_sub)


def _weights(e: FloatArray, de: float, n_states: int) -> tuple[IntArray, FloatArray]:
    """Interpolation index and weight of states e [m^2/s^2] on the uniform state grid."""
    f = np.clip(e / de, 0.0, n_states - 1.000001)
    i = f.astype(np.int64)
    return i, f - i


def state_weights(tab: DPTables, k: int, e: FloatArray) -> tuple[IntArray, FloatArray]:
    """Interpolation index and weight of states e [m^2/s^2] at stage boundary k of the tables."""
    _ = k        # the grid is the same at every stage boundary
    return _weights(np.asarray(e, dtype=float), float(tab.e_grid[1] - tab.e_grid[0]),
                    tab.e_grid.size)


def lerp(a: FloatArray, b: FloatArray, w: FloatArray) -> FloatArray:
    """Linear interpolation (1-w) a + w b that keeps a where w == 0 (a, b may be inf)."""
    with np.errstate(invalid="ignore"):
        out = (1.0 - w) * a + w * b
    return np.where(w <= 0.0, a, out)


def _backward(tab: DPTables, mus: ArrayLike) -> FloatArray:
    """Value functions J_k = min (E + mu T) to go, for every multiplier mu [J/s] at once.

    Returns shape (n_mu, n_stages + 1, n_states) (a scalar mu gives n_mu = 1).  The next
    stage's value is interpolated linearly in e at the landing speed of each control.
    """
    m = np.atleast_1d(np.asarray(mus, dtype=float))
    return dp_kernel.backward(tab.energy_j, tab.time_s,  # type: ignore[no-any-return]
                              tab.idx0, tab.w, tab.top, m)


@dataclass
class _Forward:
    """Table forward passes of a batch of candidates.

    controls (n_c, n_st), energy [J] and time [s] (inf when a candidate fails), e at the
    stages (n_c, n_st + 1).
    """

    controls: IntArray
    energy_j: FloatArray
    time_s: FloatArray
    e_path: FloatArray


def _forward(tab: DPTables, mus: FloatArray, j_all: FloatArray, policy: IntArray,
             e0: Optional[FloatArray] = None, k0: int = 0) -> _Forward:
    """Vectorised forward pass of n_c candidates on the tables.

    Candidate c at stage k follows the policy ``policy[c, k]`` (an index into ``mus`` /
    ``j_all``): the control minimising stage cost + mu T + interpolated J_{k+1}.  The state
    stays exact (off-grid); stage outcomes are interpolated linearly in e between the two
    neighbouring grid states.  Starts at stage k0 from e0 (default: standstill at 0);
    earlier stages keep control 0 and count nothing.
    """
    n_c = policy.shape[0]
    e = np.zeros(n_c) if e0 is None else np.asarray(e0, dtype=float).copy()
    return _Forward(*_forward_kernel(tab, mus, j_all, policy, e,
                                     np.full(n_c, k0, dtype=np.int64)))


def _packed_train(run: RunModel) -> NDArray[np.void]:
    """Train and limit constants of the kernels (:func:`.dp_kernel.pack_train`).

    A record array view: numba types it as the plain structured array, and its element
    keeps the attribute access the kernels use when they run as Python
    (``NUMBA_DISABLE_JIT=1``).
    """
    return dp_kernel.pack_train(run.train, run.limits).view(np.recarray)


def _forward_kernel(tab: DPTables, mus: FloatArray, j_all: FloatArray, policy: IntArray,
                    e0: FloatArray, k0: IntArray
                    ) -> tuple[IntArray, FloatArray, FloatArray, FloatArray]:
    """Compiled forward passes (:func:`.dp_kernel.forward`): controls, E, T, e path."""
    return dp_kernel.forward(  # type: ignore[no-any-return]
        float(tab.e_grid[1] - tab.e_grid[0]), tab.energy_j, tab.time_s, tab.e_next,
        np.asarray(mus, dtype=float), j_all, np.asarray(policy, dtype=np.int64), e0, k0)


def _forward_table(tab: DPTables, mu: float, j_val: FloatArray) -> tuple[IntArray, float, float]:
    """Forward pass of one policy (mu, J (n_stages + 1, n_states)): (controls, E [J], T [s])."""
    fw = _forward(tab, np.array([float(mu)]), j_val[None],
                  np.zeros((1, tab.n_stages), dtype=np.int64))
    return fw.controls[0], float(fw.energy_j[0]), float(fw.time_s[0])


def simulate_path(run: RunModel, tab: DPTables, controls: IntArray,
                  levels: Optional[FloatArray] = None
                  ) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Exact simulation of control sequences (n_c, n_st) from standstill, stage by stage.

    levels: traction levels of the same shape (default: each control's level).  Returns
    e = v^2/2 at the stages [m^2/s^2] and the cumulative traction energy [J] and running time
    [s] at the stages, each of shape (n_c, n_st + 1).
    """
    c2 = np.atleast_2d(np.asarray(controls, dtype=np.int64))
    modes = np.asarray(CONTROL_MODES, dtype=np.int64)[c2]
    lev = (np.asarray(CONTROL_LEVELS, dtype=float)[c2] if levels is None
           else np.atleast_2d(np.asarray(levels, dtype=float)))
    h = run.length_m / c2.shape[1] / tab.substeps
    return dp_kernel.simulate_batch(  # type: ignore[no-any-return]
        _packed_train(run), np.ascontiguousarray(modes),
        np.ascontiguousarray(np.broadcast_to(lev, c2.shape), dtype=float),
        tab.fg_sub, tab.cap_sub, h)


def simulate_controls(run: RunModel, tab: DPTables, controls: IntArray,
                      levels: Optional[FloatArray] = None
                      ) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Exact simulation of control sequences from standstill (vectorised over sequences).

    controls: (n_st,) or (n_c, n_st) control indices; levels: traction levels of the same
    shape (default: each control's level).  Returns (v at the stages [m/s], energy [J], time
    [s]) -- per sequence (leading axis n_c) or, for a single 1-D sequence, one profile and
    two floats.
    """
    single = np.asarray(controls).ndim == 1
    e_path, cum_j, cum_t = simulate_path(run, tab, controls, levels)
    v = np.sqrt(2.0 * e_path)
    if single:
        return v[0], cum_j[0, -1], cum_t[0, -1]
    return v, cum_j[:, -1], cum_t[:, -1]


def _stage_levels(run: RunModel, tab: DPTables, k: int, e: float, mode: int,
                  levels: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Exact simulation of stage k from e with (mode, each traction level): (e_next, J, s)."""
    return _simulate_stages(run, tab, k, np.full(levels.size, float(e)), mode, levels)


def _simulate_stages(run: RunModel, tab: DPTables, k: "int | IntArray", e0: FloatArray,
                     mode: "int | IntArray", levels: FloatArray
                     ) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Exact simulation of stage(s) ``k`` per element: (e_next, energy [J], time [s]).

    From states e0 [m^2/s^2] (held at e0 when cruising), with (mode, traction level) per
    element.
    """
    h = run.length_m / tab.n_stages / tab.substeps
    e = np.array(e0, dtype=float)
    n = e.size
    return dp_kernel.simulate_stages(  # type: ignore[no-any-return]
        _packed_train(run),
        np.broadcast_to(np.asarray(k, dtype=np.int64), (n,)).copy(), e,
        np.broadcast_to(np.asarray(mode, dtype=np.int64), (n,)).copy(),
        np.broadcast_to(np.asarray(levels, dtype=float), (n,)).copy(),
        tab.fg_sub, tab.cap_sub, h)


def _blend(run: RunModel, tab: DPTables, target_time_s: float, mu_fast: float,
           j_fast: FloatArray, ctrl: IntArray, e_path: FloatArray, k: int
           ) -> Optional[tuple[IntArray, FloatArray]]:
    """Continuous switch inside stage k of a spliced profile (controls ``ctrl``).

    Stage k's traction level (accelerate or cruise) is swept over ``BLEND_LEVELS`` values
    in [0, its level] from the table state at stage k (stage simulated exactly, vectorised
    over the levels), the fast policy continuing on the tables; the cheapest candidate whose
    table time meets the target is returned as (controls, levels).  None when stage k
    coasts or no candidate meets the time.
    """
    mode_k = CONTROL_MODES[int(ctrl[k])]
    if mode_k not in (MODE_ACCEL, MODE_CRUISE) or k >= tab.n_stages - 1:
        return None
    lv = np.linspace(0.0, CONTROL_LEVELS[int(ctrl[k])], BLEND_LEVELS + 1)[1:]
    e1, dj, dt = _stage_levels(run, tab, k, float(e_path[k]), mode_k, lv)
    fw = _forward(tab, np.array([mu_fast]), j_fast[None],
                  np.zeros((lv.size, tab.n_stages), dtype=np.int64), e0=e1, k0=k + 1)
    # time and energy of the common prefix cancel in the comparison between candidates
    pre_t = _prefix_table(tab, ctrl, e_path, k)
    ok = np.isfinite(dt) & (pre_t + dt + fw.time_s <= target_time_s + 0.01)
    if not np.any(ok):
        return None
    c = int(np.argmin(np.where(ok, dj + fw.energy_j, np.inf)))
    out = ctrl.copy()
    out[k + 1:] = fw.controls[c, k + 1:]
    levels = np.asarray(CONTROL_LEVELS, dtype=float)[out]
    levels[k] = lv[c]
    return out, levels


def _prefix_table(tab: DPTables, ctrl: IntArray, e_path: FloatArray, k: int) -> float:
    """Table running time [s] of stages 0..k-1 along a forward path (interpolated in e)."""
    i, w = _weights(e_path[:k], float(tab.e_grid[1] - tab.e_grid[0]), tab.e_grid.size)
    st = np.arange(k)
    u = ctrl[:k]
    return float(np.sum(lerp(tab.time_s[st, i, u], tab.time_s[st, i + 1, u], w)))


def _rollout(run: RunModel, tab: DPTables, target_time_s: float,
             policies: list[tuple[float, FloatArray]], ctrl: IntArray, levels: FloatArray,
             path: tuple[FloatArray, FloatArray, FloatArray],
             n_levels: int = ROLLOUT_LEVELS) -> tuple[IntArray, FloatArray, bool]:
    """One rollout improvement of a control sequence (continuous switch in any stage).

    Base: the sequence (ctrl, levels) and its exact simulation ``path`` (e, cumulative
    energy [J] and time [s] at the stages, from :func:`simulate_path`).  Candidates: at
    every stage k within ``ROLLOUT_SPAN`` stages of a change of control of the base, the
    base up to k, then stage k simulated exactly at traction level lambda in ``n_levels``
    values of (0, 1] in accelerate and in cruise mode, or coasting, then the rest of the run
    by the DP policy of each multiplier in ``policies`` ((mu, J) pairs) on the tables --
    vectorised over all stages, levels and policies at once.  The candidate with the least
    energy whose table running time meets the target replaces the base when it is cheaper
    (rollout of the base policies: the switching point inside a stage becomes continuous and
    the rest of the run re-adapts to it; Bertsekas, *Rollout, Policy Iteration, and
    Distributed Reinforcement Learning*, 2020).  Returns (controls, levels, improved).
    """
    n_st = tab.n_stages
    e_b, cj_b, ct_b = path
    lv = np.arange(1, n_levels + 1, dtype=float) / n_levels
    n_l = lv.size
    # per stage: accelerate x levels, cruise x levels, coast
    m_st = np.concatenate((np.full(n_l, MODE_ACCEL), np.full(n_l, MODE_CRUISE), [MODE_COAST]))
    u_st = np.concatenate((np.zeros(n_l, dtype=np.int64), np.full(n_l, 2, dtype=np.int64),
                           [3]))
    l_st = np.concatenate((lv, lv, [1.0]))
    # stages near a change of control of the base (where a switching point lies)
    chg = np.nonzero((ctrl[1:] != ctrl[:-1]) | (levels[1:] != levels[:-1]))[0]
    near = np.zeros(n_st - 1, dtype=bool)
    for d in range(-ROLLOUT_SPAN, ROLLOUT_SPAN + 1):
        near[np.clip(chg + d, 0, n_st - 2)] = True
    k_c = np.repeat(np.nonzero(near)[0], m_st.size)
    n_k = int(np.count_nonzero(near))
    mode_c = np.tile(m_st, n_k)
    u_c = np.tile(u_st, n_k)
    lev_c = np.tile(l_st, n_k)
    e0 = e_b[0, k_c]
    e, dj, dt = _simulate_stages(run, tab, k_c, e0, mode_c, lev_c)
    n_p = len(policies)
    mus = np.array([mu for mu, _ in policies])
    j_all = np.stack([j for _, j in policies])
    k_all = np.tile(k_c, n_p)
    fw = _forward_multi(tab, mus, j_all, np.repeat(np.arange(n_p), k_c.size),
                        np.tile(e, n_p), k_all + 1)
    tot_j = np.tile(cj_b[0, k_c] + dj, n_p) + fw.energy_j
    tot_t = np.tile(ct_b[0, k_c] + dt, n_p) + fw.time_s
    base_j, base_t = float(cj_b[0, -1]), float(ct_b[0, -1])
    ok = np.isfinite(tot_t) & (tot_t <= target_time_s + 0.01)
    if not np.any(ok):
        return ctrl, levels, False
    i = int(np.argmin(np.where(ok, tot_j, np.inf)))
    if not (tot_j[i] < base_j - 1e-6 * max(base_j, 1.0) or base_t > target_time_s + 0.01):
        return ctrl, levels, False
    k = int(k_all[i])
    c_new = fw.controls[i].copy()
    c_new[:k] = ctrl[:k]
    c_new[k] = u_c[i % k_c.size]
    l_new = np.asarray(CONTROL_LEVELS, dtype=float)[c_new]
    l_new[:k] = levels[:k]
    l_new[k] = lev_c[i % k_c.size]
    return c_new, l_new, True


def _forward_multi(tab: DPTables, mus: FloatArray, j_all: FloatArray, pol: IntArray,
                   e0: FloatArray, k0: IntArray) -> _Forward:
    """Forward passes of candidates, each with its own policy and start stage.

    pol: index into mus / j_all per candidate; k0: start stage, e0: state there; energy and
    time count from k0 on (vectorised: a candidate joins the pass at its start stage).
    """
    n_c = pol.size
    e = np.asarray(e0, dtype=float).copy()
    pol_k = np.broadcast_to(np.asarray(pol, dtype=np.int64)[:, None], (n_c, tab.n_stages))
    c_k, e_k, t_k, _ = _forward_kernel(tab, mus, j_all, pol_k, e,
                                       np.asarray(k0, dtype=np.int64))
    return _Forward(c_k, e_k, t_k, np.zeros((0, 0)))


def _search_multiplier(tab: DPTables, target_time_s: float
                       ) -> tuple[list[tuple[float, IntArray, float, float]],
                                  Optional[tuple[float, FloatArray, _Forward]],
                                  Optional[tuple[float, FloatArray, _Forward]], int]:
    """Bracket the multiplier whose table running time meets the target.

    Rounds of ``MU_BATCH`` multipliers on a log grid (one vectorised backward and forward
    pass per round) narrow [1, MU_MAX] around the switch from too slow to fast enough
    (T(mu) is non-increasing).  Returns (all evaluated (mu, controls, E, T)), the slowest
    feasible bracket end (mu, J, forward) and the fastest infeasible one (or None), and the
    number of rounds.
    """
    lo, hi = 0.0, float(np.log(MU_MAX))
    grid = np.linspace(lo, hi, MU_BATCH)
    seen: list[tuple[float, IntArray, float, float]] = []
    fast: Optional[tuple[float, FloatArray, _Forward]] = None
    slow: Optional[tuple[float, FloatArray, _Forward]] = None
    rounds = 0
    while rounds < MU_ROUNDS:
        rounds += 1
        mus = np.exp(grid)
        j_all = _backward(tab, mus)
        fw = _forward(tab, mus, j_all, np.repeat(np.arange(mus.size)[:, None],
                                                 tab.n_stages, axis=1))
        for i in range(mus.size):
            seen.append((float(mus[i]), fw.controls[i], float(fw.energy_j[i]),
                         float(fw.time_s[i])))
        ok = fw.time_s <= target_time_s + 0.01
        if np.any(ok):
            i_f = int(np.min(np.nonzero(ok)[0]))
            fast = (float(mus[i_f]), j_all[i_f], _pick(fw, i_f))
            hi = float(grid[i_f])
            below = np.nonzero(~ok[:i_f])[0]
            if below.size:
                i_s = int(below[-1])
                slow = (float(mus[i_s]), j_all[i_s], _pick(fw, i_s))
                lo = float(grid[i_s])
            elif rounds == 1:
                break                       # even the slowest multiplier meets the time
        elif rounds == 1:
            break                           # the flat-out end misses the time: infeasible
        else:
            lo = float(grid[-1])
            slow = (float(mus[-1]), j_all[-1], _pick(fw, mus.size - 1))
        if fast is None or hi - lo < MU_LOG_TOL or \
                target_time_s - fast[2].time_s[0] < 1e-3:
            break
        grid = np.linspace(lo, hi, MU_BATCH + 2)[1:-1]
    return seen, fast, slow, rounds


def _pick(fw: _Forward, i: int) -> _Forward:
    """Candidate i of a forward batch as a batch of one."""
    return _Forward(fw.controls[i:i + 1], fw.energy_j[i:i + 1], fw.time_s[i:i + 1],
                    fw.e_path[i:i + 1])


def solve_dp(run: RunModel, target_time_s: float, ds_m: float = 10.0, de_m2s2: float = 1.0,
             tables: DPTables | None = None) -> DPResult:
    """Minimum-energy profile with running time <= target_time_s [s] (Lagrangian DP).

    Multiplier search by rounds of vectorised backward / forward passes, splice and
    in-stage blend of the bracketing policies, then the candidate control sequences are
    simulated exactly together and the cheapest meeting the time (within 0.05 s) is
    returned.  ``hull_energy_j`` interpolates the two exact bracketing solutions to the
    target time (the lower convex hull of the energy-time front).  If the target is below
    the fastest profile the fastest profile is returned with ``feasible=False``.
    """
    t0 = time.process_time()
    tab = tables if tables is not None else build_dp_tables(run, ds_m, de_m2s2)
    n_st = tab.n_stages
    seen, fast, slow, rounds = _search_multiplier(tab, target_time_s)
    levels0 = np.asarray(CONTROL_LEVELS, dtype=float)
    if fast is None:                        # infeasible target: the fastest profile
        mu, c_fast, _, _ = max(seen, key=lambda r: r[0])
        v_f, e_f, t_f = simulate_controls(run, tab, c_fast)
        return DPResult(s_grid=tab.s_grid.copy(), v_profile=v_f, controls=c_fast,
                        energy_j=float(e_f), time_s=float(t_f), mu=mu,
                        hull_energy_j=float(e_f), feasible=False,
                        compute_s=time.process_time() - t0, n_passes=rounds)
    cands: list[tuple[IntArray, FloatArray]] = []
    feas = [r for r in seen if r[3] <= target_time_s + 0.01]
    best = min(feas, key=lambda r: r[2])
    cands.append((best[1], levels0[best[1]]))
    mu_best = best[0]
    if slow is not None and target_time_s - float(fast[2].time_s[0]) > 0.02:
        # Lagrangian duality gap: the slower (cheaper) policy up to stage k, the faster one
        # after it -- every switch stage k at once; the cheapest meeting the time
        pol = (np.arange(n_st)[None, :] >= np.arange(n_st)[:, None]).astype(np.int64)
        sp = _forward(tab, np.array([slow[0], fast[0]]), np.stack([slow[1], fast[1]]), pol)
        ok = sp.time_s <= target_time_s + 0.01
        if np.any(ok):
            # ties (the policies agree before the switch) go to the latest switch stage
            k_s = n_st - 1 - int(np.argmin(np.where(ok, sp.energy_j, np.inf)[::-1]))
            cands.append((sp.controls[k_s], levels0[sp.controls[k_s]]))
            # the switch stage itself at a partial traction level (continuous switch)
            bl = _blend(run, tab, target_time_s, fast[0], fast[1], sp.controls[k_s],
                        sp.e_path[k_s], k_s)
            if bl is not None:
                cands.append(bl)
    if slow is not None:
        cands.append((slow[2].controls[0], levels0[slow[2].controls[0]]))
    c_all = np.stack([c for c, _ in cands])
    l_all = np.stack([lv for _, lv in cands])
    e_path, cum_j, cum_t = simulate_path(run, tab, c_all, l_all)
    v_all, e_all, t_all = np.sqrt(2.0 * e_path), cum_j[:, -1], cum_t[:, -1]
    # the exact times decide (the slower bracket end may meet the time after all)
    ok = t_all <= target_time_s + 0.05
    i = int(np.argmin(np.where(ok, e_all, np.inf))) if np.any(ok) else int(np.argmin(t_all))
    c_best, l_best = c_all[i], l_all[i]
    v_best = v_all[i]
    energy, tm = float(e_all[i]), float(t_all[i])
    if np.any(ok):
        pols = [(fast[0], fast[1])] + ([(slow[0], slow[1])] if slow is not None else [])
        path = (e_path[i:i + 1], cum_j[i:i + 1], cum_t[i:i + 1])
        for _ in range(ROLLOUT_ROUNDS):
            c_r, l_r, better = _rollout(run, tab, target_time_s, pols, c_best, l_best, path)
            if not better:
                break
            path = simulate_path(run, tab, c_r[None, :], l_r[None, :])
            e_r, t_r = float(path[1][0, -1]), float(path[2][0, -1])
            if not (t_r <= target_time_s + 0.05 and e_r < energy):
                break
            c_best, l_best, energy, tm = c_r, l_r, e_r, t_r
            v_best = np.sqrt(2.0 * path[0][0])
        # continuous polish of the switch positions, from the rollout's winner and from the
        # candidate before the rollout (their regime structures can differ; either can win)
        starts = [(c_best, l_best)]
        if not (np.array_equal(c_best, c_all[i]) and np.array_equal(l_best, l_all[i])):
            starts.append((c_all[i], l_all[i]))
        for c_s, l_s in starts if POLISH_ITERATIONS > 0 else []:
            pr = polish_sequence(lambda c, lv: simulate_path(run, tab, c, lv), CONTROL_MODES,
                                 c_s, l_s, target_time_s, POLISH_ITERATIONS)
            if pr.time_s <= target_time_s + 0.05 and pr.energy_j < energy:
                c_best, l_best, energy, tm = pr.controls, pr.levels, pr.energy_j, pr.time_s
                v_best = np.sqrt(2.0 * pr.path[0][0])
    hull = energy
    if slow is not None:
        e_i, t_i = float(e_all[-1]), float(t_all[-1])
        if np.isfinite(e_i) and t_i > tm + 1e-9 and tm <= target_time_s <= t_i:
            hull = energy + (e_i - energy) * (target_time_s - tm) / (t_i - tm)
    return DPResult(s_grid=tab.s_grid.copy(), v_profile=v_best, controls=c_best,
                    energy_j=energy, time_s=tm, mu=mu_best, hull_energy_j=float(hull),
                    feasible=bool(tm <= target_time_s + 0.05),
                    compute_s=time.process_time() - t0, n_passes=rounds, levels=l_best)
