"""Metro traffic dynamics for automatic train regulation (Lin 2010a, eq. 1-6), ROS-free.

Indexing (0-based, stations i = 0..N-1).  Seed 000 defines the state as the *staggered*
vector of departure instants t(k) = [t_1^{k-1}, t_2^{k-2}, ..., t_N^{k-N}]^T, so entry i
here is the departure instant [s] of train (k-1-i) at station i.  One step k -> k+1 moves
every train one station down the line and dispatches train k at the first station.

Reconstruction (Lin 2010a, eq. 1-5 are partly on a missing page; eq. 9 is garbled)
------------------------------------------------------------------------------
The departure of train m at station i is (Lin 2010a, Fig. 1)

    t_i^m = t_{i-1}^m + R_{i-1} + S_i + t_b p_i^m + u_i^m + w_i^m,

with p_i^m = q_i (t_i^m - t_i^{m-1}) the passengers arriving at rate q_i [pax/s] since the
previous train left (they all board).  With c_i = t_b q_i this is implicit in t_i^m;
solving it gives eq. 5 in the form used here:

    t(k+1) = A t(k) + B (u(k) + w(k) + D(k)),
    A_ii = -c_i / (1 - c_i),  A_{i,i-1} = 1 / (1 - c_i),  B = diag(1 / (1 - c_i)),
    D(k)_0 = z_k + S_0 (train k reaches station 0 at its dispatch instant z_k),
    D(k)_i = R_{i-1} + S_i  (i >= 1),

which matches the structure of A_n, B_n in eq. 9 (diagonal -c/(1-c), sub-diagonal 1/(1-c)).
In steady state every dwell is S_i + c_i H.  The deviation x = t - T from the timetable T
obeys the linear (approximate) model x(k+1) = A x(k) + B (u(k) + w(k)).

Truth variant (what the approximate model lacks)
---------------------------------------------------------
- control saturation: u_i is split into a running-time part (bounded by the minimum and
  maximum running times) and a dwell part (fixed dwell >= its minimum, holding <= hold_max);
- passenger-dependent dwell: boarding time per passenger grows when the gap since the
  previous train exceeds the scheduled one (crowded platform and train): factor
  1 + crowding_gain * min(gap / gap_nom - 1, 1) for gap > gap_nom, and the boarding time is
  capped at ``board_max_s`` (the train fills up; passengers left behind are not carried
  over to the next train);
- knock-on (secondary) delays: a train may not arrive at a platform earlier than
  ``separation_min_s`` after the previous train left it;
- disturbances: exponentially distributed departure delays (Lin 2010a, sec. 2, refs [3, 8]).
With all of these inactive the truth step equals the linear model exactly.
"""

from __future__ import annotations

from typing import Optional, Tuple

import numpy as np

from metro_atc.core.atr.blue_line import LineData


def linear_model(c: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    """Return (A, B) of the linear traffic model for boarding coefficients c (Lin 2010a, eq. 5/9).

    c: (N,) dimensionless c_i = t_b q_i, each in [0, 0.5).  A, B: (N, N).
    """
    c = np.asarray(c, dtype=float)
    if np.any(c < 0.0) or np.any(c >= 0.5):
        raise ValueError("boarding coefficients c_i must lie in [0, 0.5) for a stable model")
    n = c.size
    g = 1.0 / (1.0 - c)
    a = np.diag(-c * g)
    a[np.arange(1, n), np.arange(0, n - 1)] = g[1:]
    return a, np.diag(g)


def schedule_offsets(line: LineData, headway_s: Optional[float] = None,
                     flow_factor: float = 1.0) -> np.ndarray:
    """Steady-state scheduled departure offsets O_i [s] of a train dispatched at 0.

    O_0 = S_0 + c_0 H, O_i = O_{i-1} + R_{i-1} + S_i + c_i H (dwell S_i + c_i H, Lin 2010a, eq. 5).
    """
    h = line.headway_s if headway_s is None else headway_s
    dwell = line.dwell_fixed_s + line.c(flow_factor) * h
    inc = dwell.copy()
    inc[1:] += line.run_s
    return np.cumsum(inc)


def timetable_state(line: LineData, k: int, headway_s: Optional[float] = None,
                    flow_factor: float = 1.0, z0_s: float = 0.0) -> np.ndarray:
    """Staggered scheduled state T(k) [s] for a constant headway: T(k)_i = z0 + (k-1-i) H + O_i."""
    h = line.headway_s if headway_s is None else headway_s
    i = np.arange(line.n_stations)
    return z0_s + (k - 1 - i) * h + schedule_offsets(line, h, flow_factor)


def scheduled_d(line: LineData, z_k: float) -> np.ndarray:
    """Aggregated scheduled values D(k) [s] (Lin 2010a, eq. 6) for dispatch instant z_k."""
    d = line.dwell_fixed_s.astype(float).copy()
    d[0] += z_k
    d[1:] += line.run_s
    return d


def propagate_linear(a: np.ndarray, b: np.ndarray, t0: np.ndarray, drive: np.ndarray
                     ) -> np.ndarray:
    """Iterate t(k+1) = A t(k) + B drive(k) for all k; returns (K+1, N) including t0.

    drive: (K, N) = u(k) + w(k) + D(k) [s].
    """
    out = np.empty((drive.shape[0] + 1, t0.size))
    out[0] = t0
    for k in range(drive.shape[0]):
        out[k + 1] = a @ out[k] + b @ drive[k]
    return out


def unstagger(states: np.ndarray, k0: int = 0) -> dict:
    """Map staggered states t(k0), t(k0+1), ... to {(train, station): time}.

    states: (K, N); entry i of t(k) is train k-1-i at station i.
    """
    out = {}
    for r in range(states.shape[0]):
        k = k0 + r
        for i in range(states.shape[1]):
            out[(k - 1 - i, i)] = float(states[r, i])
    return out


def control_bounds(line: LineData) -> Tuple[np.ndarray, np.ndarray]:
    """Saturation limits [s] of the total adjustment u_i (running time into i + dwell at i)."""
    lo = line.dwell_fixed_min_s - line.dwell_fixed_s
    hi = np.full(line.n_stations, line.hold_max_s, dtype=float)
    lo = lo.astype(float).copy()
    lo[1:] += line.run_min_s - line.run_s
    hi[1:] += line.run_max_s - line.run_s
    return lo, hi


def split_adjustment(line: LineData, u: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    """Split adjustments u (..., N) [s] into saturated (running, dwell) parts.

    The running time of the run into station i takes the adjustment first (within
    [run_min, run_max]); the remainder goes to the dwell (fixed part >= its minimum, holding
    <= hold_max).  Station 0 has no run.  Returns (du_run, du_dwell), both (..., N).
    """
    u = np.asarray(u, dtype=float)
    run_lo = np.zeros(line.n_stations)
    run_hi = np.zeros(line.n_stations)
    run_lo[1:] = line.run_min_s - line.run_s
    run_hi[1:] = line.run_max_s - line.run_s
    du_run = np.clip(u, run_lo, run_hi)
    du_dwell = np.clip(u - du_run, line.dwell_fixed_min_s - line.dwell_fixed_s,
                       line.hold_max_s)
    return du_run, du_dwell


def truth_step(line: LineData, t_k: np.ndarray, u: np.ndarray, z_k: float | np.ndarray,
               w_dep: Optional[np.ndarray] = None, w_run: Optional[np.ndarray] = None,
               headway_s: Optional[float] = None, flow_factor: float = 1.0,
               saturation: bool = True, knock_on: bool = True, crowding: bool = True
               ) -> np.ndarray:
    """One step of the truth traffic dynamics; returns t(k+1) [s], shape like t_k (..., N).

    t_k: staggered departures t(k) [s]; u: adjustments [s]; z_k: dispatch (arrival at
    station 0) instant of train k [s]; w_dep / w_run: departure / running disturbances [s].
    Flags switch off the nonlinearities (then the step equals Lin 2010a, eq. 5).
    """
    return truth_arrivals_departures(line, t_k, u, z_k, w_dep, w_run, headway_s,
                                     flow_factor, saturation, knock_on, crowding)[1]


def truth_arrivals_departures(line: LineData, t_k: np.ndarray, u: np.ndarray,
                              z_k: float | np.ndarray, w_dep: Optional[np.ndarray] = None,
                              w_run: Optional[np.ndarray] = None,
                              headway_s: Optional[float] = None, flow_factor: float = 1.0,
                              saturation: bool = True, knock_on: bool = True,
                              crowding: bool = True) -> Tuple[np.ndarray, np.ndarray]:
    """:func:`truth_step` with the arrivals: (arrival instants, t(k+1)) [s], both like t_k.

    Entry i of the arrivals is the arrival of the same train as t(k+1)_i at station i
    (z_k at station 0); the turnback link of a terminus needs the arrival there.
    """
    t_k = np.asarray(t_k, dtype=float)
    u = np.broadcast_to(np.asarray(u, dtype=float), t_k.shape)
    c = line.c(flow_factor)
    h_sched = line.headway_s if headway_s is None else headway_s
    if saturation:
        du_run, du_dwell = split_adjustment(line, u)
    else:
        du_run = np.zeros_like(u)
        du_dwell = u.copy()
        du_run[..., 1:] = u[..., 1:]
        du_dwell[..., 1:] = 0.0
    arr = np.empty_like(t_k)
    arr[..., 0] = z_k
    arr[..., 1:] = t_k[..., :-1] + line.run_s + du_run[..., 1:]
    if w_run is not None:
        arr = arr + w_run
    if knock_on:
        arr = np.maximum(arr, t_k + line.separation_min_s)
    hold = line.dwell_fixed_s + du_dwell
    if w_dep is not None:
        hold = hold + w_dep          # a departure delay lengthens the dwell; passengers board
    gap = arr - t_k + hold
    board = c * gap / (1.0 - c)
    if crowding:
        gap_nom = (1.0 - c) * h_sched
        excess = np.clip(gap / gap_nom - 1.0, 0.0, 1.0)
        board = np.minimum(board * (1.0 + line.crowding_gain * excess), line.board_max_s)
    return arr, arr + hold + board


def truth_step_dev(line: LineData, x_k: np.ndarray, u: np.ndarray,
                   w_dep: Optional[np.ndarray] = None, saturation: bool = True,
                   knock_on: bool = True, crowding: bool = True) -> np.ndarray:
    """Truth step in deviations from the steady peak timetable: x(k+1) = t(k+1) - T(k+1) [s].

    The steady timetable is shift-invariant (T(k+1) = T(k) + H), so the step is evaluated at
    k = 0 with the dispatch of train 0 at z = 0.
    """
    t0 = timetable_state(line, 0)
    t1 = timetable_state(line, 1)
    return truth_step(line, t0 + np.asarray(x_k, dtype=float), u, 0.0, w_dep=w_dep,
                      saturation=saturation, knock_on=knock_on, crowding=crowding) - t1


def exponential_disturbance(rng: np.random.Generator, mean_s: float, shape: Tuple[int, ...]
                            ) -> np.ndarray:
    """Exponentially distributed departure delays w >= 0 [s] (Lin 2010a, sec. 2)."""
    if mean_s <= 0.0:
        return np.zeros(shape)
    return rng.exponential(mean_s, size=shape)
