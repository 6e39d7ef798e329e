"""Continuous local search of a Ke 2010 tour on the exact simulator (MMAS + local search).

Not in Ke 2010.  The paper's speed codes are 5 km/h apart and its sections of equal length;
the best tour on that lattice can miss the optimum by several per cent.  TTOBench downhill
3 906 -> 6 272 m at 1.10 x flat-out: the optimum is full traction to 47.4 km/h at 88 m, then
coasting (the descent does the rest).  A section in accelerate mode brakes to hold its code
once it is reached (the code is a ceiling), so cutting traction at 88 m needs a section
boundary there; on 47 m sections the nearest tours hold the speed to the section end and
reach 1.2 % to 9 % above the optimum.  Local search on the best tour is the standard
companion of MMAS (Stuetzle & Hoos, "MAX-MIN ant system and local search", Ke 2010 ref.
[8]); this one works on the *continuous* speed commands and *section boundaries* and on the
*exact* simulation (:class:`metro_atc.core.ato.tour_kernel.TourSimulator`, no table
interpolation).  Neighbourhood of a tour:

- per section: its command shifted by ``+-span x {1/4, 1/2, 1}``, its mode changed, its
  (mode, command) copied from the neighbour before or after it;
- per section boundary: moved by 1, 2, 4 or 8 sub-steps (2 m each) either way;
- the acceleration phase (while ``span`` is large): sections 0..i accelerate with one
  command (the highest accelerate command of the first half, shifted, or any lattice code),
  the same with coasting from section i + 1 to the stop, and "sections 0..i accelerate,
  section i + 1 coasts without ceiling" with the switch moved by up to 12 sub-steps;
- every move is simulated exactly from the first section it changes (the prefix is the
  current tour's, or for the acceleration-phase moves an "accelerate everywhere at c"
  tour's) and stops where it rejoins the current tour bit for bit (the rest is then the
  current tour's, :func:`metro_atc.core.ato.tour_kernel.simulate_kernel`).  The
  running-time bound is usually active, so an energy-saving move costs time: besides the
  feasible single moves, the pairs of moves on disjoint sections whose summed time change
  fits the slack and whose summed energy change is the lowest (additive prediction) are
  simulated exactly;
- the best exactly simulated candidate meeting the bound replaces the tour (commands that
  do not act are then set to equivalent canonical values, :func:`canonical`); ``span``
  halves when nothing improves; stops below ``min_span_mps`` or after ``max_rounds``;
- the acceleration-phase moves (most of the cost) are in a round only while they win, in
  the first round, or when the other moves found nothing (then with every lattice code).
- the same acceleration-phase move at the same tour is not simulated again (memo), and
  moves that run the same (:func:`same_runs`) are simulated once.

Deterministic; never returns a tour worse than its input (or slower than the bound when the
input met it).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from metro_atc.core.ato.envelope import MODE_ACCEL, MODE_COAST
from metro_atc.core.ato.tour_kernel import TourSimulator

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


@dataclass
class PolishedTour:
    """Polished tour: modes, commands [m/s], section starts [sub-steps] (N_s,) each.

    energy_j / time_s: exact simulation [J] / [s]; evaluations: tours simulated; rounds:
    search rounds.
    """

    modes: IntArray
    speeds_mps: FloatArray
    bounds: IntArray
    energy_j: float
    time_s: float
    evaluations: int
    rounds: int


_OFFS = np.array([-1.0, -0.5, -0.25, 0.25, 0.5, 1.0])  # command shifts [x span], first rows


def _moves(modes: IntArray, speeds: FloatArray, bounds: IntArray, span: float,
           v_lo: float, v_hi: float, codes: FloatArray, n_steps: int,
           structural: bool = True, lattice: bool = True
           ) -> tuple[IntArray, FloatArray, IntArray, IntArray, NDArray[np.bool_]]:
    """Candidate tours (modes, speeds, bounds), the first section each one changes, structural.

    structural: include the acceleration-phase moves (the costly part of the neighbourhood);
    the last output flags them; lattice: their commands include every lattice code.
    """
    n_s = modes.size
    offs = _OFFS * span
    out_m: list[IntArray] = []
    out_v: list[FloatArray] = []
    out_b: list[IntArray] = []
    out_f: list[IntArray] = []
    out_s: list[NDArray[np.bool_]] = []

    def add(sec: IntArray, m: IntArray, v: FloatArray, b: "IntArray | None" = None,
            f: "IntArray | None" = None) -> None:
        out_m.append(m.astype(np.int64))
        out_v.append(v)
        out_b.append(np.repeat(bounds[None, :], sec.size, axis=0) if b is None else b)
        out_f.append(sec.astype(np.int64) if f is None else f)
        out_s.append(np.full(sec.size, f is not None and not np.any(f)))

    def base(n: int) -> tuple[IntArray, FloatArray]:
        return np.repeat(modes[None, :], n, axis=0), np.repeat(speeds[None, :], n, axis=0)

    sec = np.repeat(np.arange(n_s), offs.size)
    m, v = base(sec.size)
    v[np.arange(sec.size), sec] = np.clip(speeds[sec] + np.tile(offs, n_s), v_lo, v_hi)
    add(sec, m, v)
    # mode changes at the current command
    sec = np.repeat(np.arange(n_s), 2)
    m, v = base(sec.size)
    m[np.arange(sec.size), sec] = (modes[sec] + np.tile([1, 2], n_s)) % 3
    add(sec, m, v)
    # copy the neighbour's (mode, command) into section i (merges two sections' settings)
    for d in (-1, 1):
        sec = np.arange(max(0, -d), n_s - max(0, d))
        m, v = base(sec.size)
        m[np.arange(sec.size), sec] = modes[sec + d]
        v[np.arange(sec.size), sec] = speeds[sec + d]
        add(sec, m, v)
    # acceleration phase: sections 0..i accelerate with one command (the highest command of
    # the accelerating sections in the first half, shifted, or a lattice code)
    acc = np.nonzero(modes[: max(1, n_s // 2)] == MODE_ACCEL)[0]
    if acc.size and structural:
        v_acc = float(np.max(speeds[acc]))
        cmds = np.unique(np.clip(np.concatenate(([v_acc], v_acc + offs,
                                                 codes if lattice else [])), v_lo, v_hi))
        ends = np.arange(max(1, n_s // 2))
        sec, vv = (a.ravel() for a in np.meshgrid(ends, cmds, indexing="ij"))
        upto = np.arange(n_s)[None, :] <= sec[:, None]
        add(sec, np.where(upto, MODE_ACCEL, modes[None, :]),
            np.where(upto, vv[:, None], speeds[None, :]), f=np.zeros(sec.size, np.int64))
        # ... and coasting without ceiling from section i + 1 to the stop (the classic
        # accelerate -- coast structure, a restart away from staircase local optima)
        add(sec, np.where(upto, MODE_ACCEL, MODE_COAST),
            np.where(upto, vv[:, None], v_hi), f=np.zeros(sec.size, np.int64))
        # ... then coasting without ceiling in section i + 1, the switch (the start of
        # section i + 1) anywhere near its boundary
        shifts = np.array([-12, -6, -3, -1, 1, 3, 6, 12])
        ends = np.arange(max(1, min(n_s - 1, n_s // 2)))
        sec, vv, sh = (a.ravel() for a in np.meshgrid(ends, [v_acc, v_hi], shifts,
                                                      indexing="ij"))
        nb = bounds[sec + 1] + sh
        lo = bounds[sec] + 1
        hi = np.where(sec + 2 < n_s, bounds[np.minimum(sec + 2, n_s - 1)], n_steps) - 1
        keep = (nb >= lo) & (nb <= hi)
        sec, vv, nb = sec[keep], vv[keep], nb[keep]
        upto = np.arange(n_s)[None, :] <= sec[:, None]
        nxt = np.arange(n_s)[None, :] == sec[:, None] + 1
        b = np.repeat(bounds[None, :], sec.size, axis=0)
        b[np.arange(sec.size), sec + 1] = nb
        add(sec, np.where(upto, MODE_ACCEL, np.where(nxt, MODE_COAST, modes[None, :])),
            np.where(upto, vv[:, None], np.where(nxt, v_hi, speeds[None, :])), b,
            np.zeros(sec.size, np.int64))
    # section boundaries moved by a few sub-steps (the switching points off the partition)
    if n_s > 1:
        shifts = np.array([-8, -4, -2, -1, 1, 2, 4, 8])
        sec = np.repeat(np.arange(1, n_s), shifts.size)
        nb = bounds[sec] + np.tile(shifts, n_s - 1)
        lo = bounds[sec - 1] + 1
        hi = np.where(sec + 1 < n_s, bounds[np.minimum(sec + 1, n_s - 1)], n_steps) - 1
        keep = (nb >= lo) & (nb <= hi)
        sec, nb = sec[keep], nb[keep]
        b = np.repeat(bounds[None, :], sec.size, axis=0)
        b[np.arange(sec.size), sec] = nb
        m, v = base(sec.size)
        add(sec, m, v, b, sec - 1)
    return (np.concatenate(out_m), np.concatenate(out_v), np.concatenate(out_b),
            np.concatenate(out_f), np.concatenate(out_s))


def shares_section(changed: NDArray[np.bool_]) -> NDArray[np.bool_]:
    """(K, K): moves i and j change a common section; ``changed`` (K, N_s) per move.

    Equal to ``changed @ changed.T > 0`` in floats, but on 64-bit words (bit per section)
    instead of a BLAS product: the multi-threaded BLAS of a small product kept the second
    core spinning, about 0.3 s of CPU per MMAS run.
    """
    k, n = changed.shape
    pad = np.zeros((k, -n % 64), dtype=bool)
    words = np.packbits(np.concatenate((changed, pad), axis=1), axis=1).view(np.uint64)
    out = np.zeros((k, k), dtype=bool)
    for w in words.T:
        out |= (w[:, None] & w[None, :]) != 0
    return out


def row_keys(cm: IntArray, cv: FloatArray, cb: IntArray) -> list[bytes]:
    """One bytes key per candidate row (modes, commands' bits, section starts)."""
    key = np.concatenate((np.asarray(cm, np.int64),
                          np.ascontiguousarray(cv, dtype=np.float64).view(np.int64),
                          np.asarray(cb, np.int64)), axis=1)
    raw = np.ascontiguousarray(key).tobytes()
    w = key.shape[1] * 8
    return [raw[i * w:(i + 1) * w] for i in range(key.shape[0])]


def same_runs(cm: IntArray, cv: FloatArray, cb: IntArray, first: IntArray,
              start: tuple[FloatArray, FloatArray, FloatArray]) -> tuple[IntArray, IntArray]:
    """Candidates that run identically: (representatives, index of each one's representative).

    A candidate's simulation from section ``first`` depends only on its state there
    (``start``: e, t, energy) and on its modes, commands and section starts from that section
    on (:func:`metro_atc.core.ato.tour_kernel.simulate_kernel`); candidates equal in all of
    these, bit for bit, get the same figures.  ``cm[rep][inv]`` etc. give back every row.
    """
    k, n_s = cm.shape
    tail = np.arange(n_s)[None, :] >= first[:, None]
    key = np.concatenate((first[:, None].astype(np.int64),
                          np.stack([np.ascontiguousarray(x, dtype=np.float64).view(np.int64)
                                    for x in start], axis=1),
                          np.where(tail, cm, -1),
                          np.where(tail, np.ascontiguousarray(cv).view(np.int64), -1),
                          np.where(tail, cb, -1)), axis=1)
    raw = np.ascontiguousarray(key).tobytes()
    w = key.shape[1] * 8
    seen: dict[bytes, int] = {}
    inv = np.empty(k, dtype=np.int64)
    rep: list[int] = []
    for i in range(k):
        j = seen.setdefault(raw[i * w:(i + 1) * w], len(rep))
        if j == len(rep):
            rep.append(i)
        inv[i] = j
    return np.asarray(rep, dtype=np.int64), inv


def canonical(sim: TourSimulator, modes: IntArray, speeds: FloatArray, bounds: IntArray,
              hist: FloatArray) -> FloatArray:
    """Equivalent commands: accelerate sections never reaching theirs get their top speed.

    An accelerate section whose command is above the speed it reaches drives full traction
    whatever the command; with the command at the reached speed, the shifts of the search
    move the traction end.  Coast sections whose command never caps get the top command.
    """
    v = np.sqrt(2.0 * np.maximum(hist[0], 0.0))
    ends = np.append(bounds[1:], sim.n_steps)
    top = np.maximum.reduceat(v[1:], bounds)
    out = speeds.copy()
    acc = (modes == MODE_ACCEL) & (speeds > top + 1e-9)
    out[acc] = top[acc]
    coast = (modes == MODE_COAST) & (speeds > top + 1e-6)
    out[coast] = float(np.max(sim.codes_mps))
    _ = ends
    return out


def _canonical_checked(sim: TourSimulator, modes: IntArray, speeds: FloatArray,
                       bounds: IntArray, hist: FloatArray) -> tuple[FloatArray, FloatArray]:
    """:func:`canonical` if it leaves the exact energy and time unchanged, else the input."""
    v2 = canonical(sim, modes, speeds, bounds, hist)
    if np.array_equal(v2, speeds):
        return speeds, hist
    h2 = sim.history(modes, v2, bounds)
    same = abs(h2[2, -1] - hist[2, -1]) <= 1e-9 * max(1.0, abs(hist[2, -1])) and \
        abs(h2[1, -1] - hist[1, -1]) <= 1e-9 * max(1.0, abs(hist[1, -1]))
    return (v2, h2) if same else (speeds, hist)


def _starts(sim: TourSimulator, cm: IntArray, cv: FloatArray, cb: IntArray,
            tour: tuple[IntArray, FloatArray, IntArray], hist: FloatArray
            ) -> tuple[IntArray, tuple[FloatArray, FloatArray, FloatArray]]:
    """First section to simulate and the state there, for candidate tours (K, N_s).

    Each candidate starts after the longest prefix it shares (modes, commands, section
    starts) with the current tour ``tour`` (history ``hist``) or with one of the
    "accelerate everywhere at command c" tours (c: the candidates' first command; their
    histories are simulated once here), the acceleration-phase moves' common prefixes.
    The state at a candidate's own section start comes from that reference's history,
    which is the same trajectory up to there (a moved bound i changes section i - 1).
    """
    tm, tv, tb = tour
    n_k, n_s = cm.shape
    rows = np.arange(n_k)

    def shared(same: NDArray[np.bool_]) -> IntArray:
        """First section to simulate given per-section equality (K, N_s) of all fields."""
        lead = np.where(same.all(axis=1), n_s, np.argmin(same, axis=1))
        s = np.minimum(lead, n_s - 1)
        # the bound of section s may differ: the reference is then past it at b[k, s]
        back = (s > 0) & (cb[rows, s] > tb[np.minimum(s, n_s - 1)])
        return np.where(back, s - 1, s)

    eq_b = cb == tb[None, :]
    f_base = shared((cm == tm[None, :]) & (cv == tv[None, :]) & eq_b)
    j = cb[rows, f_base]
    e, t, en = hist[0, j].copy(), hist[1, j].copy(), hist[2, j].copy()
    first = f_base
    acc = (cm[:, 0] == MODE_ACCEL) & (n_s > 1)
    if np.any(acc):
        c_k = cv[:, 0]
        f_acc = shared((cm == MODE_ACCEL) & (cv == c_k[:, None]) & eq_b)
        use = acc & (f_acc > f_base + 1)
        if np.any(use):
            cmds, inv = np.unique(c_k[use], return_inverse=True)
            mod = np.full(n_s, MODE_ACCEL, dtype=np.int64)
            idx = np.nonzero(use)[0]
            jj = cb[idx, f_acc[idx]]
            for q, c in enumerate(cmds):
                h = sim.history(mod, np.full(n_s, c), tb)
                sel = inv == q
                e[idx[sel]] = h[0, jj[sel]]
                t[idx[sel]] = h[1, jj[sel]]
                en[idx[sel]] = h[2, jj[sel]]
            first = np.where(use, f_acc, f_base)
    return first.astype(np.int64), (e, t, en)


def polish_tour(sim: TourSimulator, modes: IntArray, speeds_mps: FloatArray, t_max: float,
                span_mps: float = 5.0 / 3.6, min_span_mps: float = 0.05 / 3.6,
                max_rounds: int = 40, n_pairs: int = 24, n_keep: int = 100,
                bounds: "IntArray | None" = None, prune: bool = True) -> PolishedTour:
    """Continuous exact local search of one tour under the running-time bound ``t_max`` [s].

    prune: stop simulating an acceleration-phase move as soon as it cannot end within
    ``t_max`` (its time so far plus a lower bound of the time to the stop,
    :meth:`TourSimulator.time_lower_bound`): it cannot win alone and is not offered to
    the pairs.  Not pruned on energy: the faster but dearer of these moves are the
    partners of the pairs that trade time (TTOBench downhill x1.20 stayed +2.7 % above the
    optimum without them).
    """
    cur_m = np.asarray(modes, dtype=np.int64).copy()
    cur_v = np.asarray(speeds_mps, dtype=float).copy()
    cur_b = (sim.equal_bounds() if bounds is None else np.asarray(bounds, np.int64)).copy()
    v_lo, v_hi = 1.0, float(np.max(sim.codes_mps))
    hist = sim.history(cur_m, cur_v, cur_b)
    cur_e, cur_t = float(hist[2, -1]), float(hist[1, -1])
    evals = 1
    cur_v, hist = _canonical_checked(sim, cur_m, cur_v, cur_b, hist)
    span = span_mps
    rounds = 0
    structural = True
    stuck = False  # the cheap moves found nothing at the current tour and span
    last_struct = True  # the last accepted move was an acceleration-phase move
    # figures of the last round at the current tour: t, en, stalled, reusable rows, span
    prev: "tuple[FloatArray, FloatArray, NDArray[np.bool_], NDArray[np.bool_], float] | None" \
        = None
    # acceleration-phase moves simulated at the current tour: key -> (t, en, stalled)
    memo: dict[bytes, tuple[float, float, bool]] = {}
    for rounds in range(1, max_rounds + 1):
        use_struct = structural and (last_struct or stuck)
        cm, cv, cb, first, is_st = _moves(cur_m, cur_v, cur_b, span, v_lo, v_hi,
                                          sim.codes_mps, sim.n_steps, use_struct,
                                          lattice=rounds == 1 or stuck)
        # a round after a failed one (same tour): the moves not depending on the span (all
        # but the command shifts, the first rows, and the acceleration-phase moves), and at
        # the same span the shifts too, are that round's (same order): not simulated again
        n_shift = _OFFS.size * cur_m.size

        def reusable(st: NDArray[np.bool_], same_span: bool) -> NDArray[np.bool_]:
            r = ~st
            if not same_span:
                r[:n_shift] = False
            return r

        mine = np.zeros(is_st.size, bool)
        if prev is not None:
            mine = reusable(is_st, prev[4] == span)
            theirs = prev[3] & reusable(np.zeros(prev[3].size, bool), prev[4] == span)
            if int(np.sum(mine)) != int(np.sum(theirs)):
                mine[:] = False
        reuse = bool(np.any(mine)) and prev is not None
        sel = np.nonzero(~mine)[0]
        f_run, start = _starts(sim, cm[sel], cv[sel], cb[sel], (cur_m, cur_v, cur_b), hist)
        t, en = np.full(is_st.size, np.nan), np.full(is_st.size, np.nan)
        stl = np.zeros(is_st.size, bool)
        if reuse and prev is not None:
            t[mine], en[mine], stl[mine] = (x[theirs] for x in prev[:3])
        # the cheap moves in full, the acceleration-phase moves pruned on time (``prune``)
        for part in (~is_st[sel], is_st[sel]):
            if not np.any(part):
                continue
            q = sel[part]
            t_cut = np.inf
            keys: list[bytes] = []
            todo = np.ones(q.size, bool)
            if prune and bool(np.all(is_st[q])):
                t_cut = t_max + 1e-9
                # the same move at the same tour in an earlier round: its figures
                keys = row_keys(cm[q], cv[q], cb[q])
                for n, key in enumerate(keys):
                    got = memo.get(key)
                    if got is not None:
                        t[q[n]], en[q[n]], stl[q[n]] = got
                        todo[n] = False
            qq, pq = q[todo], np.nonzero(part)[0][todo]
            if qq.size:
                # acceleration-phase moves with the same state at the same first section
                # and the same sections from there on run the same: simulated once (e.g.
                # commands above every speed they reach; ~30 % of them)
                rep, inv = (same_runs(cm[qq], cv[qq], cb[qq], f_run[pq],
                                      (start[0][pq], start[1][pq], start[2][pq]))
                            if keys else (np.arange(qq.size), np.arange(qq.size)))
                r_q, r_p = qq[rep], pq[rep]
                t_r, en_r, _, st_r, _ = sim.run(
                    cm[r_q], cv[r_q], cb[r_q], f_run[r_p], hist, tour=(cur_m, cur_v, cur_b),
                    start=(start[0][r_p], start[1][r_p], start[2][r_p]), t_cut=t_cut)
                t[qq], en[qq], stl[qq] = t_r[inv], en_r[inv], st_r[inv]
            evals += qq.size
            for n in (np.nonzero(todo)[0].tolist() if keys else []):
                row = int(q[n])
                memo[keys[n]] = (float(t[row]), float(en[row]), bool(stl[row]))
        prev = (t, en, stl, ~is_st, span)
        en = np.where(stl | ~np.isfinite(t), np.inf, en)
        d_e = en - cur_e
        d_t = t - cur_t
        slack = t_max - cur_t
        ok = np.isfinite(en) & (t <= t_max + 1e-9)
        best_k = int(np.argmin(np.where(ok, en, np.inf))) if np.any(ok) else -1
        best_e = float(en[best_k]) if best_k >= 0 else np.inf
        best_tour = (cm[best_k], cv[best_k], cb[best_k]) if best_k >= 0 else None
        win_struct = bool(is_st[best_k]) if best_k >= 0 else False
        # pairs of moves on different sections: additive prediction, then exact check
        fin = np.isfinite(d_e) & np.isfinite(d_t) & (np.abs(d_t) < 1e3)
        idx = np.nonzero(fin)[0]
        if idx.size > 2 * n_keep:  # the most energy-saving and the most time-saving moves
            idx = np.union1d(idx[np.argsort(d_e[idx], kind="stable")[:n_keep]],
                             idx[np.argsort(d_t[idx], kind="stable")[:n_keep]])
        if idx.size > 1 and n_pairs > 0:
            bch = cb[idx] != cur_b[None, :]
            bch_prev = np.concatenate((bch[:, 1:], np.zeros((idx.size, 1), bool)), axis=1)
            changed = (cm[idx] != cur_m[None, :]) | (cv[idx] != cur_v[None, :]) | bch \
                | bch_prev
            pe = d_e[idx][:, None] + d_e[idx][None, :]
            pt = d_t[idx][:, None] + d_t[idx][None, :]
            overlap = shares_section(changed)
            bad = overlap | (pt > slack) | (pe >= -1e-9 * max(cur_e, 1.0))
            bad |= np.tril(np.ones_like(bad), 0)
            score = np.where(bad, np.inf, pe)
            sf = score.ravel()
            flat = np.flatnonzero(np.isfinite(sf))
            if flat.size > n_pairs:  # the n_pairs lowest predictions, in (score, index) order
                flat = flat[np.argpartition(sf[flat], n_pairs - 1)[:n_pairs]]
            flat = flat[np.lexsort((flat, sf[flat]))]
            if flat.size:
                a, b = np.unravel_index(flat, score.shape)
                ia, ib = idx[a], idx[b]
                pm = np.where(changed[a], cm[ia], cm[ib])
                pv = np.where(changed[a], cv[ia], cv[ib])
                pb = np.where(bch[a], cb[ia], cb[ib])
                pf = np.minimum(first[ia], first[ib])
                t2, en2, _, st2, _ = sim.run(pm, pv, pb, pf, hist,
                                             tour=(cur_m, cur_v, cur_b),
                                             t_cut=t_max + 1e-9, e_cut=best_e)
                evals += t2.size
                ok2 = ~st2 & np.isfinite(t2) & (t2 <= t_max + 1e-9)
                if np.any(ok2):
                    k2 = int(np.argmin(np.where(ok2, en2, np.inf)))
                    if en2[k2] < best_e:
                        best_e = float(en2[k2])
                        best_tour = (pm[k2], pv[k2], pb[k2])
                        win_struct = False
        cur_score = cur_e if cur_t <= t_max + 1e-9 else np.inf
        if best_tour is not None and best_e < cur_score - 1e-7 * max(cur_e, 1.0):
            cur_m, cur_v, cur_b = (x.copy() for x in best_tour)
            hist = sim.history(cur_m, cur_v, cur_b)
            cur_e, cur_t = float(hist[2, -1]), float(hist[1, -1])
            evals += 1
            cur_v, hist = _canonical_checked(sim, cur_m, cur_v, cur_b, hist)
            stuck = False
            last_struct = win_struct
            prev = None
            memo.clear()
        elif structural and not use_struct:
            stuck = True  # next round: the whole neighbourhood at the same span
        else:
            stuck = False
            span *= 0.5
            # the structure is settled below a quarter of the initial span: refine with the
            # cheap moves (the acceleration-phase moves are most of the cost)
            structural = span > 0.2 * span_mps
            if span < min_span_mps:
                break
    return PolishedTour(cur_m, cur_v, cur_b, cur_e, cur_t, evals, rounds)
