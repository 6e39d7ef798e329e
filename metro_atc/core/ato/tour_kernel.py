"""Compiled exact simulation of Ke 2010 tours (numba): every sub-step of every tour.

The MAX-MIN ant system (:mod:`metro_atc.core.ato.mmas`) evaluates tours -- a mode and a
speed command per section -- on the interpolated pre-work tables; the reported energy and
time of a tour are its *exact* simulation here (the arithmetic of
:func:`metro_atc.core.ato.step_kernel.strategy_step` sub-step by sub-step, no interpolation).
A numpy simulation cost about 0.5 ms per sub-step whatever the number of tours (numpy call
overhead on small arrays), i.e. 0.6 s for one tour of a 2.4 km run at 2 m sub-steps; this
kernel runs the same arithmetic element by element (same operation order, no fast-math),
about 0.1 us per sub-step and tour, so that the local search of MMAS can use the exact
simulation instead of the tables.  It is the only exact tour simulation
(``NUMBA_DISABLE_JIT=1`` runs it as Python); ``test_ato_mmas.py`` checks it against the
recorded output of the former numpy simulation (``test/data/tours_numpy_ref.npz``: random
tours, every mode, speed command, grade sign, braking) to round-off.

Constants of a run are packed in one record (:data:`TOUR`, :func:`pack_params`).
Cheaper, same numbers: a coasting step re-uses the closed-form position / time of the
previous step's end and the coefficients of the last grade force (:func:`_coast`), the
Newton start skips the arctangent when it is multiplied by zero (Davis b = 0,
:func:`_coast_x`), a coasting step skips the force and trapezoid time it does not use;
candidates may be pruned on a time lower bound to the stop and on energy
(:func:`simulate_kernel`).
Compiled on first use and cached on disk (``cache=True``).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numba import njit
from numpy.typing import NDArray

from metro_atc.core import laws
from metro_atc.core.ato.envelope import MODE_ACCEL, MODE_COAST, MODE_CRUISE, OperatingLimits
from metro_atc.core.ato.sections import SectionTables
from metro_atc.core.ato.step_kernel import TRAIN, TRAIN_FIELDS, pack_train
from metro_atc.core.line.vehicle import TrainParams

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

TOUR = np.dtype(TRAIN.descr + [(f, np.float64) for f in ("brake_decel", "delta", "h")])
"""The kernel's constants by name: :data:`metro_atc.core.ato.step_kernel.TRAIN`'s fields, the
planning deceleration [m/s^2], the traction level [-] and the sub-step [m]."""
_TINY = 1e-12
_ACC = MODE_ACCEL
_CRU = MODE_CRUISE
_COA = MODE_COAST


def pack_params(train: TrainParams, limits: OperatingLimits, delta: float, h: float
                ) -> NDArray[np.void]:
    """Constants of the kernel (a one-element :data:`TOUR` array).

    The train and limits (:func:`metro_atc.core.ato.step_kernel.pack_train`), the planning
    deceleration [m/s^2], the traction level delta [-] and the sub-step h [m].  A record
    array view: numba types it as the plain structured array, and its element keeps the
    attribute access the kernels use when they run as Python (``NUMBA_DISABLE_JIT=1``).
    """
    p = np.zeros(1, dtype=TOUR)
    tr = pack_train(train, limits)
    for name in TRAIN_FIELDS:
        p[name] = tr[name]
    p["brake_decel"] = limits.brake_decel_mps2
    p["delta"] = delta
    p["h"] = h
    return p.view(np.recarray)


@njit(cache=True, error_model="numpy")
def _trac_acc(p: Any, v: float, fg: float) -> float:  # pragma: no cover - compiled
    """:func:`.step_kernel.traction_accel` for one speed [m/s^2] (the laws of :mod:`.laws`)."""
    phi = laws.traction_accel(v, p.a1, p.v1, p.v2, p.a2, p.a3, p.b2, p.b3)
    f = p.delta * (p.mass * phi) - laws.davis_resistance(v, p.davis_a, p.davis_b, p.davis_c) \
        - fg
    a = f / p.meff
    return a if a <= p.accel_max else p.accel_max


@njit(cache=True, error_model="numpy")
def _coast_xt(w: float, d4: float, c2: float, bp: float, a: float
              ) -> tuple[float, float]:  # pragma: no cover - compiled
    """:func:`.step_kernel.coast_x_t` for one element (X [m], T [s]); a = sqrt(|d4|)."""
    if d4 > 0.0:
        t = -math.atan(w / a) / (c2 * a)
        x_log = -0.5 * math.log(w * w + d4) / c2
        return x_log - bp * t, t
    k = a
    r = abs((k + w) / (k - w + _TINY))
    t = math.log(r) / (2.0 * c2 * k) if r > 0.0 else -np.inf / (2.0 * c2 * k)
    x_log = -0.5 * math.log(abs(w * w + d4) + _TINY) / c2
    return x_log - bp * t, t


@njit(cache=True, error_model="numpy")
def _coast_x(w: float, d4: float, c2: float, bp: float, a: float
             ) -> float:  # pragma: no cover - compiled
    """X of :func:`_coast_xt`, bit for bit; without the arctangent when bp = 0 and d4 > 0.

    There T is finite, so ``bp * T`` is a zero and ``x_log - bp * T`` is ``x_log`` (Davis
    b = 0, e.g. the TTOBench trains: every coasting step's Newton start).
    """
    if d4 > 0.0 and bp == 0.0:
        return -0.5 * math.log(w * w + d4) / c2
    return _coast_xt(w, d4, c2, bp, a)[0]


MEMO = np.dtype((np.record, [(f, np.float64) for f in ("fg", "w", "x", "t", "fg_c", "c0", "c1",
                                                       "c2", "bp", "d4", "a")]))
"""The coasting memo (:func:`_coast`): the last end-of-step evaluation (fg, w, X, T), the
coefficients of the last grade force fg_c (c0, c1, c2, bp, d4, a).  A record dtype: its
element keeps attribute access when the kernels run as Python (``NUMBA_DISABLE_JIT=1``)."""


@njit(cache=True, error_model="numpy")
def _new_memo():  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    """An empty coasting memo (every field NaN: nothing equals it)."""
    memo = np.empty(1, dtype=MEMO)[0]
    memo.fg = np.nan
    memo.w = np.nan
    memo.x = np.nan
    memo.t = np.nan
    memo.fg_c = np.nan
    memo.c0 = np.nan
    memo.c1 = np.nan
    memo.c2 = np.nan
    memo.bp = np.nan
    memo.d4 = np.nan
    memo.a = np.nan
    return memo


@njit(cache=True, error_model="numpy")
def _coast(p: Any, e0: float, v0: float, h: float, fg: float, memo: Any
           ) -> tuple[float, float, bool]:  # pragma: no cover - compiled
    """:func:`.step_kernel.coast_step` for one element: (e1, dt [s], stalled).

    e0 >= 0 [m^2/s^2] and v0 = sqrt(2 e0) [m/s] (the caller's).  memo (a :data:`MEMO`
    record), NaN when empty: (fg, w, X, T) of the last closed-form evaluation at the end of a
    step; a step with the same grade force starting at that w (the previous coasting step's
    end, bit for bit) takes its start X, T from there instead of recomputing them; and the
    coefficients c0, c1, c2, bp, d4, sqrt(|d4|) of the last grade force fg (the same
    expressions, so the
    same numbers).
    """
    if memo.fg_c == fg:
        c0 = memo.c0
        c1 = memo.c1
        c2 = memo.c2
        bp = memo.bp
        d4 = memo.d4
        a = memo.a
    else:
        m = p.meff
        c0 = (p.davis_a + fg) / m
        c1 = p.davis_b / m
        c2 = p.davis_c / m
        bp = 0.0
        d4 = 0.0
        a = 0.0
        if c2 > 0.0:
            bp = c1 / (2.0 * c2)
            d4 = c0 / c2 - bp * bp
            if abs(d4) < 1e-9:
                d4 = 1e-9
            a = math.sqrt(d4) if d4 > 0.0 else math.sqrt(-d4)
        memo.fg_c = fg
        memo.c0 = c0
        memo.c1 = c1
        memo.c2 = c2
        memo.bp = bp
        memo.d4 = d4
        memo.a = a
    # RK4 in distance (the Newton start); the first stage's speed is v0
    k1 = -(c0 + c1 * v0 + c2 * v0 * v0)
    ee = e0 + 0.5 * h * k1
    v = math.sqrt(2.0 * max(ee, 0.0))
    k2 = -(c0 + c1 * v + c2 * v * v)
    ee = e0 + 0.5 * h * k2
    v = math.sqrt(2.0 * max(ee, 0.0))
    k3 = -(c0 + c1 * v + c2 * v * v)
    ee = e0 + h * k3
    v = math.sqrt(2.0 * max(ee, 0.0))
    k4 = -(c0 + c1 * v + c2 * v * v)
    e1 = e0 + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
    stalled = (e1 <= 1e-9) and (c0 > 0.0)
    e_guess = max(e1, 0.0)
    if c2 <= 0.0:
        v1 = math.sqrt(2.0 * e_guess)
        dt = 2.0 * h / (v0 + v1 + 1e-300) if v0 + v1 > 0 else np.inf
        return e_guess, (np.inf if stalled else dt), stalled
    w0 = v0 + bp
    if memo.fg == fg and memo.w == w0:
        x0 = memo.x
        t0 = memo.t
    else:
        x0, t0 = _coast_xt(w0, d4, c2, bp, a)
    w = math.sqrt(2.0 * e_guess) + bp
    x = _coast_x(w, d4, c2, bp, a)
    dxdw = -(w - bp) / (c2 * (w * w + d4))
    if (not stalled) and abs(dxdw) > _TINY:
        w = max(w - (x - x0 - h) / dxdw, bp)
    v1 = max(w - bp, 0.0)
    e1 = 0.0 if stalled else 0.5 * v1 * v1
    w1 = math.sqrt(2.0 * e1) + bp
    x1, t1 = _coast_xt(w1, d4, c2, bp, a)
    memo.fg = fg
    memo.w = w1
    memo.x = x1
    memo.t = t1
    dt = t1 - t0
    if not (math.isfinite(dt) and dt > 0.0):
        dt = 2.0 * h / max(v0 + math.sqrt(2.0 * e1), _TINY)
    return e1, (np.inf if stalled else dt), stalled


@njit(cache=True, error_model="numpy")
def _step(p: Any, e: float, fg: float, e_cap: float, mode: int, e_code: float,
          e_hold: float, latch: bool, memo: Any
          ) -> tuple[float, float, float, bool, bool]:  # pragma: no cover - compiled
    """:func:`.step_kernel.strategy_step` for one trajectory: (e1, dt, energy, stalled, latch).

    memo: the coasting step's closed-form memo (:func:`_coast`).
    """
    h = p.h  # pragma: no cover - compiled
    e0 = max(e, 0.0)
    m = mode
    if latch and m == _ACC:
        m = _COA
    v0 = math.sqrt(2.0 * e0)
    dt_c = 0.0
    st_c = False
    if m == _COA:
        e_m, dt_c, st_c = _coast(p, e0, v0, h, fg, memo)
    else:
        e_p = max(e0 + h * _trac_acc(p, v0, fg), 0.0)
        v_m = 0.5 * (v0 + math.sqrt(2.0 * e_p))
        e_t = max(e0 + h * _trac_acc(p, v_m, fg), 0.0)
        e_m = e_t if m == _ACC else min(e_t, e_hold)
    is_coast = m == _COA
    e_code_cap = max(e_code, e0 - p.brake_decel * h)
    cap = min(e_code_cap, e_cap)
    e1 = max(min(e_m, cap), 0.0)
    clamped = e_m > cap
    energy = 0.0
    if is_coast and not clamped:
        dt = dt_c  # (the force and the trapezoid time below are not used)
    else:
        v1 = math.sqrt(2.0 * e1)
        if not is_coast:
            vm = 0.5 * (v0 + v1)
            force = laws.step_force(p.meff, e0, e1, h, vm, p.davis_a, p.davis_b, p.davis_c,
                                    fg)
            energy = max(force, 0.0) * h
        if v0 + v1 > 0.0:
            dt = 2.0 * h / max(v0 + v1, 1e-300)
        else:
            dt = np.inf
    stalled = (is_coast and (not clamped) and st_c) or (e1 <= 0.0 and e_cap > 1e-9)
    if stalled:
        dt = np.inf
    latch_out = latch or (m == _ACC and e1 >= e_code * (1 - 1e-9))
    return e1, dt, energy, stalled, latch_out


@njit(cache=True, error_model="numpy")
def simulate_kernel(params: NDArray[np.void], fg: FloatArray, cap: FloatArray, modes: IntArray,
                    e_codes: FloatArray, bounds: IntArray, first: IntArray,
                    e_out: FloatArray, t_out: FloatArray, en_out: FloatArray,
                    st_out: NDArray[np.bool_], hist: FloatArray,
                    last: IntArray, base: FloatArray, t_cut: float, e_cut: float,
                    t_lb: FloatArray) -> None:  # pragma: no cover - compiled
    """Exact simulation of tours: mode, command e = v^2/2 and first sub-step per section.

    fg, cap: grade force [N] over and envelope e at the end of each sub-step (n,); modes,
    e_codes, bounds: (K, N_s) (a section's hold speed and latch are set at its first
    sub-step).  first (K,): section the simulation
    starts at; e_out, t_out, en_out, st_out hold the state at its start on entry and the
    final state on exit.  hist (K, n + 1) gets the e history when it has n + 1 columns.

    Rejoining a base tour: last (K,) is the last section where tour k differs from the tour
    whose (3, n + 1) history is ``base`` (sections after it are the base's, same bounds).
    A section's run depends only on its entry state e (hold and latch are set from it), so
    when tour k enters a section i > last[k] with the base's e *bit for bit*, the rest of
    the run is the base's: the final time and energy are the base's final figures plus the
    differences at that sub-step (round-off only), and the simulation stops there.  Off when
    ``last[k] < 0``, the base is stalled or a history is recorded.

    Pruning: a tour whose time so far plus ``t_lb`` (a lower bound of the time to the stop
    from that sub-step, (n + 1,), :meth:`TourSimulator.time_lower_bound`; empty: 0) exceeds
    ``t_cut`` [s] (checked every sub-step), or whose energy so far exceeds ``e_cut`` [J]
    (energy never decreases along a run; checked at section starts), is stopped there with
    time and energy +inf (not stalled): its final figures are past those bounds.  Off with
    t_cut = e_cut = inf; never while a history is recorded.
    """
    p = params[0]
    n_k, n_s = modes.shape
    n = fg.shape[0]
    rec = hist.shape[1] == n + 1
    can_join = base.shape[1] == n + 1 and (not rec) and math.isfinite(base[1, n])
    prune = (not rec) and (t_cut < np.inf or e_cut < np.inf)
    use_lb = t_lb.shape[0] == n + 1
    memo = _new_memo()
    for k in range(n_k):
        e = e_out[k]
        t = t_out[k]
        en = en_out[k]
        stalled = st_out[k]
        cut = False
        if rec:
            hist[k, bounds[k, first[k]]] = e
        for i in range(first[k], n_s):
            j0 = bounds[k, i]
            if can_join and 0 <= last[k] < i and (not stalled):
                if e == base[0, j0]:
                    t += base[1, n] - base[1, j0]
                    en += base[2, n] - base[2, j0]
                    e = base[0, n]
                    break
            if prune and (en > e_cut or t + (t_lb[j0] if use_lb else 0.0) > t_cut):
                cut = True
                break
            m = modes[k, i]
            e_code = e_codes[k, i]
            hold = min(e, e_code)
            latch = m == _ACC and e >= e_code
            j_end = bounds[k, i + 1] if i + 1 < n_s else n
            for j in range(bounds[k, i], j_end):
                e, dt, de, st, latch = _step(p, e, fg[j], cap[j], m, e_code, hold, latch, memo)
                if math.isfinite(dt):
                    t += dt
                en += de
                stalled = stalled or st
                if rec:
                    hist[k, j + 1] = e
                elif prune and use_lb and t + t_lb[j + 1] > t_cut:
                    cut = True
                    break
            if cut:
                break
        if cut:
            t = np.inf
            en = np.inf
        t_out[k] = np.inf if stalled else t
        en_out[k] = en
        e_out[k] = e
        st_out[k] = stalled


@njit(cache=True, error_model="numpy")
def history_kernel(params: NDArray[np.void], fg: FloatArray, cap: FloatArray, modes: IntArray,
                   e_codes: FloatArray, bounds: IntArray, out: FloatArray
                   ) -> None:  # pragma: no cover - compiled
    """One tour (N_s,): out (3, n + 1) = e, cumulative time [s], energy [J] per sub-step.

    params: :func:`pack_params`.
    """
    p = params[0]
    n_s = modes.shape[0]
    n = fg.shape[0]
    e = 0.0
    t = 0.0
    en = 0.0
    stalled = False
    memo = _new_memo()
    for i in range(n_s):
        m = modes[i]
        e_code = e_codes[i]
        hold = min(e, e_code)
        latch = m == _ACC and e >= e_code
        j_end = bounds[i + 1] if i + 1 < n_s else n
        for j in range(bounds[i], j_end):
            e, dt, de, st, latch = _step(p, e, fg[j], cap[j], m, e_code, hold, latch, memo)
            if math.isfinite(dt):
                t += dt
            en += de
            stalled = stalled or st
            out[0, j + 1] = e
            out[1, j + 1] = np.inf if stalled else t
            out[2, j + 1] = en


@njit(cache=True, error_model="numpy")
def table_kernel(packed: FloatArray, h_e: float, n_e: int, n_c: int, modes: IntArray,
                 codes: IntArray, first: IntArray, e_out: FloatArray, t_out: FloatArray,
                 en_out: FloatArray) -> None:  # pragma: no cover - compiled
    """Table evaluation of tours (:meth:`sections.SectionTables.lookup`, same arithmetic).

    packed: the tables' (rows, 3) look-up array (e_out, time [s], energy [J]); modes, codes
    (K, N_s); first (K,): section each tour starts at; e_out, t_out, en_out: the state at
    that section on entry, the final state on exit.
    """
    n_k, n_s = modes.shape
    hi = n_e - 1.000001
    for k in range(n_k):
        e = e_out[k]
        t = t_out[k]
        en = en_out[k]
        for i in range(first[k], n_s):
            f = e / h_e
            f = min(max(f, 0.0), hi)
            j0 = int(f)
            w = f - j0
            b = ((i * 3 + modes[k, i]) * n_c + codes[k, i]) * n_e + j0
            e = packed[b, 0] * (1.0 - w) + packed[b + 1, 0] * w
            t += packed[b, 1] * (1.0 - w) + packed[b + 1, 1] * w
            en += packed[b, 2] * (1.0 - w) + packed[b + 1, 2] * w
        e_out[k] = e
        t_out[k] = t
        en_out[k] = en


class TourSimulator:
    """Exact tour simulation of one run (the physics of the pre-work tables, uninterpolated).

    Sections may have any length in whole sub-steps (``bounds``: first sub-step of each
    section, (N_s,), starting with 0); with the pre-work tables' equal sections it reproduces
    the recorded former numpy simulation (``test/data/tours_numpy_ref.npz``, to round-off).
    Built from the run, sub-step, traction level and codes of the pre-work tables.
    """

    def __init__(self, tables: SectionTables) -> None:
        """Precompute the grade forces and envelope of every sub-step."""
        tab = tables
        run = tab.run
        bounds = np.asarray(tab.bounds_s, dtype=np.float64)
        n_s = bounds.size - 1
        seg = run.length_m / n_s
        n_sub = int(round(seg / tab.substep_m))
        h = seg / n_sub
        s_sub = (bounds[:-1, None] + np.arange(n_sub)[None, :] * h).ravel()
        self.fg = np.ascontiguousarray(run.mean_grade_force(s_sub, s_sub + h), dtype=np.float64)
        self.cap = np.ascontiguousarray(run.ceiling_e(s_sub + h), dtype=np.float64)
        self.params = pack_params(run.train, run.limits, float(tab.delta), h)
        self.codes_mps = np.asarray(tab.codes_mps, dtype=np.float64)
        self.n_sections = n_s
        self.n_sub = n_sub
        self.n_steps = n_s * n_sub
        self.length_m = float(run.length_m)
        self.h = h
        self.t_lb = self.time_lower_bound()

    def time_lower_bound(self) -> FloatArray:
        """Lower bound of the running time [s] from each sub-step to the stop (n + 1,).

        The speed at a sub-step end never exceeds the envelope there (``cap``), so a sub-step
        takes at least h / max(envelope speed at its start, at its end); the sum over the
        remaining sub-steps, less 0.1 % for the round-off of the coasting formula.
        """
        v_cap = np.sqrt(2.0 * np.maximum(self.cap, 0.0))
        v_max = np.maximum(v_cap, np.concatenate((v_cap[:1], v_cap[:-1])))
        dt_min = self.h / np.maximum(v_max, 1e-3)
        return np.append(np.cumsum(dt_min[::-1])[::-1], 0.0) * (1.0 - 1e-3)

    def equal_bounds(self) -> IntArray:
        """First sub-step of each of the tables' equal sections (N_s,)."""
        return np.arange(self.n_sections, dtype=np.int64) * self.n_sub

    def run(self, modes: IntArray, speeds_mps: FloatArray, bounds: "IntArray | None" = None,
            first: "IntArray | None" = None, base: "FloatArray | None" = None,
            record: bool = False,
            tour: "tuple[IntArray, FloatArray, IntArray] | None" = None,
            start: "tuple[FloatArray, FloatArray, FloatArray] | None" = None,
            t_cut: float = np.inf, e_cut: float = np.inf,
            ) -> tuple[FloatArray, FloatArray, FloatArray, NDArray[np.bool_], FloatArray]:
        """(time [s], energy [J], e_end, stalled, e history or empty) of tours (K, N_s).

        speeds_mps: speed command [m/s] of each section (continuous, not only the codes);
        bounds: first sub-step of each section (default: the tables' equal sections);
        first / base: the section each tour starts at (K,) and the (3, n + 1) history of a
        tour it shares the sections before with (:meth:`history`); tour: that base tour
        (modes, speeds [m/s], bounds), to stop a candidate once it rejoins it (see
        :func:`simulate_kernel`; e_end is then the base's); start: the state (e, t [s],
        energy [J]) of each tour at the start of section ``first`` (K,) each, given by the
        caller (e.g. from another tour sharing that prefix) instead of read from ``base``;
        t_cut [s] / e_cut [J]: tours that cannot end within them are stopped early with time
        and energy +inf (pruning, see :func:`simulate_kernel`; never with ``record``).
        """
        m = np.ascontiguousarray(np.atleast_2d(modes), dtype=np.int64)
        sp = np.broadcast_to(np.asarray(speeds_mps, dtype=np.float64), m.shape)
        ec = np.ascontiguousarray(0.5 * sp * sp)
        b = np.ascontiguousarray(np.broadcast_to(
            self.equal_bounds() if bounds is None else np.asarray(bounds, dtype=np.int64),
            m.shape))
        n_k = m.shape[0]
        if first is None or base is None:
            f = np.zeros(n_k, dtype=np.int64)
            e, t, en = np.zeros(n_k), np.zeros(n_k), np.zeros(n_k)
        else:
            f = np.ascontiguousarray(first, dtype=np.int64)
            j0 = b[np.arange(n_k), f]
            e, t, en = (np.array(base[i, j0], dtype=np.float64) for i in range(3))
        st = ~np.isfinite(t)
        hist = np.zeros((n_k, self.n_steps + 1) if record else (1, 0))
        last = np.full(n_k, -1, dtype=np.int64)
        ref = np.zeros((3, 0))
        if base is not None and tour is not None and not record:
            tm, tv, tb = tour
            tv = np.asarray(tv, np.float64)
            diff = (m != np.asarray(tm, np.int64)[None, :]) | (ec != (0.5 * tv * tv)[None, :]) \
                | (b != np.asarray(tb, np.int64)[None, :])
            any_d = diff.any(axis=1)
            last = np.where(any_d, m.shape[1] - 1 - np.argmax(diff[:, ::-1], axis=1), 0)
            ref = np.ascontiguousarray(base, dtype=np.float64)
            # start at the first section that differs (a moved bound i changes section i - 1)
            sec_d = diff.copy()
            sec_d[:, :-1] |= diff[:, 1:] & (b != np.asarray(tb, np.int64)[None, :])[:, 1:]
            f_d = np.where(any_d, np.argmax(sec_d, axis=1), m.shape[1] - 1)
            if start is not None and first is not None:
                e, t, en = (np.array(x, dtype=np.float64) for x in start)
                f = np.ascontiguousarray(first, dtype=np.int64)
                st = ~np.isfinite(t)
            elif first is not None:
                f1 = np.maximum(f, f_d)
                j1 = b[np.arange(n_k), f1]
                e, t, en = (np.array(base[i, j1], dtype=np.float64) for i in range(3))
                f = np.ascontiguousarray(f1, dtype=np.int64)
                st = ~np.isfinite(t)
        simulate_kernel(self.params, self.fg, self.cap, m, ec, b, f, e, t, en, st, hist,
                        last, ref, float(t_cut), float(e_cut), self.t_lb)
        return t, en, e, st, hist

    def history(self, modes: IntArray, speeds_mps: FloatArray, bounds: IntArray
                ) -> FloatArray:
        """(3, n + 1): e [m^2/s^2], cumulative time [s], energy [J] of one tour per sub-step."""
        m = np.ascontiguousarray(modes, dtype=np.int64).ravel()
        sp = np.asarray(speeds_mps, dtype=np.float64).ravel()
        out = np.zeros((3, self.n_steps + 1))
        history_kernel(self.params, self.fg, self.cap, m, np.ascontiguousarray(0.5 * sp * sp),
                       np.ascontiguousarray(bounds, dtype=np.int64).ravel(), out)
        return out

    def s_grid(self) -> FloatArray:
        """Positions [m] of the sub-step grid (n + 1,)."""
        return np.linspace(0.0, self.length_m, self.n_steps + 1)


def warm_up() -> None:
    """Compile (or load from the disk cache) the kernels once: 1-3 s on the first call."""
    p = np.ones(1, dtype=TOUR)
    fg = np.zeros(2)
    cap = np.full(2, 100.0)
    m = np.zeros((1, 1), dtype=np.int64)
    ec = np.full((1, 1), 50.0)
    b = np.zeros((1, 1), dtype=np.int64)
    z = np.zeros(1)
    simulate_kernel(p, fg, cap, m, ec, b, np.zeros(1, dtype=np.int64), z.copy(), z.copy(),
                    z.copy(), np.zeros(1, dtype=bool), np.zeros((1, 0)),
                    np.full(1, -1, dtype=np.int64), np.zeros((3, 0)), np.inf, np.inf, np.zeros(3))
    history_kernel(p, fg, cap, m[0], ec[0], b[0], np.zeros((3, 3)))
    table_kernel(np.zeros((4, 3)), 1.0, 2, 1, m, b, np.zeros(1, dtype=np.int64), z.copy(),
                 z.copy(), z.copy())
