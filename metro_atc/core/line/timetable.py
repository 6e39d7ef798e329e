"""Timetable and passenger flow: multi-period (TSK) dwell and departure schedule.

Seed 000 eq. 7-10: the day is split into L periods (crisp memberships, eq. 8), each with a
scheduled headway H_n and an hourly passenger flow p_{j,n} per station; the passenger part
of the dwell is ``c_j = t_b p_{j,n} H_n`` and the timetable follows eq. 10,
``T(k+1) = A_n T(k) + B_n D`` which, for the undisturbed schedule, reduces to
departure = arrival + S_{j,n}, arrival at j+1 = departure at j + R_j.

Here passengers keep arriving while the doors are open, so with boarding time t_b [s/pax]
and flow p [pax/s] the boarding dwell solves ``d = d0 + t_a A + t_b (W + p d)``, i.e.
``d = (d0 + t_a A + t_b W) / (1 - t_b p)`` unless the train capacity saturates (then
``d = d0 + t_a A + t_b room``) -- the saturation nonlinearity of Lin 2010a, Exp. 2.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]


class PassengerFlow:
    """Piecewise-constant (per period) boarding demand per station [pax/s]."""

    def __init__(self, starts_s: list[float], rates_pph: FloatArray) -> None:
        """``starts_s[n]`` begins period n; ``rates_pph[n, j]`` demand at station j [pax/h]."""
        self.starts = np.asarray(starts_s, dtype=float)
        self.rates = np.asarray(rates_pph, dtype=float) / 3600.0  # [pax/s]
        # cumulative arrivals at each period start, per station
        dur = np.diff(self.starts)
        cum = np.zeros_like(self.rates)
        if len(dur):
            cum[1:] = np.cumsum(self.rates[:-1] * dur[:, None], axis=0)
        self.cum = cum

    def period(self, t: float) -> int:
        """Index n of the period containing time t (first period before its start)."""
        return max(0, int(np.searchsorted(self.starts, t, side="right")) - 1)

    def rate(self, j: int, t: float) -> float:
        """Boarding demand at station j at time t [pax/s]."""
        return float(self.rates[self.period(t), j])

    def cumulative(self, j: int, t: float) -> float:
        """Passengers arrived at station j from the first period start until t [pax]."""
        n = self.period(t)
        return float(self.cum[n, j] + self.rates[n, j] * max(t - self.starts[n], 0.0))

    def arrivals(self, j: int, t0: float, t1: float) -> float:
        """Passengers arriving at station j during [t0, t1] [pax]."""
        if t1 <= t0:
            return 0.0
        return self.cumulative(j, t1) - self.cumulative(j, t0)


def required_dwell(waiting: float, rate: float, alight: float, room: float, t_b: float,
                   t_a: float, overhead: float, min_dwell: float) -> tuple[float, float]:
    """Dwell [s] and boardings [pax] (Lin 2010a c_j = t_b p H with in-dwell arrivals + capacity).

    ``waiting`` persons on the platform at arrival, demand ``rate`` [pax/s], ``alight``
    persons leaving, ``room`` free places after alighting.
    """
    base = overhead + t_a * alight
    denom = 1.0 - t_b * rate
    d = (base + t_b * waiting) / denom if denom > 0.05 else math.inf
    board = waiting + rate * d
    if board > room:
        board = max(room, 0.0)
        d = base + t_b * board
    d = max(d, min_dwell)
    return d, board


def dispatch_times(first_s: float, count: int, flow: PassengerFlow,
                   headways_s: list[float]) -> FloatArray:
    """Departure instants at the first station: T(k+1) = T(k) + H_n(T(k)) (Lin 2010a, eq. 6)."""
    t = np.empty(count)
    t[0] = first_s
    for k in range(1, count):
        t[k] = t[k - 1] + headways_s[flow.period(t[k - 1])]
    return t


def nominal_dwells(flow: PassengerFlow, headways_s: list[float], alight_frac: FloatArray,
                   capacity: float, initial_load: float, t_b: float, t_a: float,
                   overhead: float, min_dwell: float) -> tuple[FloatArray, FloatArray]:
    """Scheduled dwell S[n, j] [s] and nominal departing load [n, j] per period and station.

    Undisturbed operation: waiting = p_{j,n} H_n at arrival (Lin 2010a, eq. 7-9), the load
    propagates along the line; the terminus alights everyone.
    """
    n_per, n_st = flow.rates.shape
    dwell = np.zeros((n_per, n_st))
    load_out = np.zeros((n_per, n_st))
    for n in range(n_per):
        load = initial_load
        for j in range(n_st):
            frac = 1.0 if j == n_st - 1 else float(alight_frac[j])
            alight = load * frac
            load -= alight
            rate = 0.0 if j == n_st - 1 else float(flow.rates[n, j])
            d, board = required_dwell(rate * headways_s[n], rate, alight, capacity - load,
                                      t_b, t_a, overhead, min_dwell)
            load += board
            dwell[n, j] = d
            load_out[n, j] = load
    return dwell, load_out


def schedule(dispatch_s: FloatArray, dwell: FloatArray, running_s: FloatArray,
             flow: PassengerFlow) -> tuple[FloatArray, FloatArray]:
    """Timetable (Lin 2010a, eq. 10, crisp period memberships): arrival and departure [k, j].

    Station 0 "arrival" is the platform entry ``dispatch - S_0``; the terminal departure is
    the end of alighting (then the train turns back).
    """
    n_tr = dispatch_s.size
    n_st = running_s.size + 1
    arr = np.zeros((n_tr, n_st))
    dep = np.zeros((n_tr, n_st))
    for k in range(n_tr):
        dep[k, 0] = dispatch_s[k]
        arr[k, 0] = dispatch_s[k] - dwell[flow.period(dispatch_s[k]), 0]
        for j in range(1, n_st):
            arr[k, j] = dep[k, j - 1] + running_s[j - 1]
            dep[k, j] = arr[k, j] + dwell[flow.period(arr[k, j]), j]
    return arr, dep
