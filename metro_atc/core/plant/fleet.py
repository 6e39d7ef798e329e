"""Fleet state: per-train arrays (SI) and the service status of each train.

Status: ``WAIT`` before entering service, ``RUN`` in service, ``TURNBACK`` after the
terminus (driven into a siding by the plant), ``DONE`` out of service.  The *masks* are
derived from the status and the dwell/breakdown flags after every discrete change
(:meth:`Fleet.update_masks`); the per-step code reads them instead of recomputing them.
"""

from __future__ import annotations

import math
from enum import IntEnum
from typing import Any

import numpy as np
from numpy.typing import NDArray

from metro_atc.core.line.geometry import LineGeometry
from metro_atc.core.line.vehicle import TrainParams

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]
_cnz = np.count_nonzero

MODE_OUT, MODE_DWELL, MODE_ACCEL, MODE_CRUISE, MODE_COAST, MODE_BRAKE, MODE_ATP = range(7)
"""Operating modes (the TrainState.MODE_* values)."""


class Status(IntEnum):
    """Service status of a train."""

    WAIT = 0
    RUN = 1
    TURNBACK = 2
    DONE = 3


WAIT, RUN, TURNBACK, DONE = (int(s) for s in Status)
"""The Status values as plain ints (array comparisons; enum member lookup is slow)."""


class Fleet:
    """Per-train state arrays of a line (positions, speeds, loads, stops, status)."""

    def __init__(self, n: int, p: TrainParams, geom: LineGeometry, load_pax: float) -> None:
        """All ``n`` trains waiting at the first stop, empty of events."""
        self.n = n
        self.p = p
        self.x = np.full(n, geom.x_first_stop)
        self.x_done = np.full(n, math.nan)
        self.v = np.zeros(n)
        self.acc = np.zeros(n)
        self.a_dem = np.zeros(n)
        self.u_last = np.zeros(n)
        self.status = np.zeros(n, dtype=np.int64)
        self.next_stop = np.zeros(n, dtype=np.int64)
        self.cur_station = np.full(n, -1, dtype=np.int64)
        self.stop_x = np.full(n, geom.x_first_stop)
        self.dwelling = np.zeros(n, dtype=bool)
        self.release_t = np.full(n, math.inf)
        self.arr_t = np.full(n, math.nan)
        self.done_t = np.full(n, math.inf)
        self.broken_until = np.full(n, -math.inf)
        self.trac_level = np.ones(n)
        self.load = np.full(n, float(load_pax))
        self.mass = p.mass_at_load(self.load)
        self.m_rot = p.rotary_allowance * p.mass_kg
        self.mass_changed()
        self.n_done = 0
        self.update_masks(0.0)

    def set_mass_from_load(self, i: int) -> None:
        """Mass of train i [kg] from its passenger load (positive: the loader checks it)."""
        self.mass[i] = self.p.mass_at_load(self.load[i])
        self.mass_changed()

    def mass_changed(self) -> None:
        """Per-train constants of the masses (new arrays; the step reads them).

        ``meff`` = m + m_rot [kg], ``inv_meff`` [1/kg], ``davis_bc`` = Davis B and C over
        ``meff`` [1/s, 1/m] (:func:`metro_atc.core.laws.davis_rk4_step`).
        """
        p = self.p
        self.meff: FloatArray = self.mass + self.m_rot
        self.inv_meff: FloatArray = 1.0 / self.meff
        self.davis_bc = (p.davis_b_n_per_mps * self.inv_meff,
                         p.davis_c_n_per_mps2 * self.inv_meff)

    @property
    def davis_b(self) -> FloatArray:
        """Davis B over ``meff`` [1/s] (first of ``davis_bc``)."""
        return self.davis_bc[0]

    @property
    def davis_c(self) -> FloatArray:
        """Davis C over ``meff`` [1/m] (second of ``davis_bc``)."""
        return self.davis_bc[1]

    def set_xv(self, i: int, x: float, v: float) -> None:
        """Set one train's position/speed without mutating arrays shared with the trace."""
        self.x = self.x.copy()
        self.v = self.v.copy()
        self.x[i] = x
        self.v[i] = v

    def update_masks(self, t: float) -> None:
        """Recompute the discrete-state masks at time ``t`` after any discrete change."""
        st = self.status
        tb = st == TURNBACK
        self.run: BoolArray = (st == RUN) | tb
        self.broken: BoolArray = self.broken_until > t
        self.hold: BoolArray = self.dwelling | self.broken | ~self.run
        self.cand: BoolArray = self.run & ~self.dwelling
        self.auto: BoolArray = tb & ~self.dwelling
        self.any_auto = bool(_cnz(self.auto))
        self.any_turnback = bool(_cnz(tb))
        self.lead_add: FloatArray = np.where(self.run[:-1], 0.0, math.inf)
        self.any_broken = bool(_cnz(self.broken))
        self.n_done = int(_cnz(st == DONE))

    def next_discrete_t(self) -> float:
        """Earliest departure, turnback end or breakdown end [s] (inf if none)."""
        nxt = min(float(self.release_t.min()), float(self.done_t.min()))
        if self.any_broken:
            nxt = min(nxt, float(self.broken_until[self.broken].min()))
        return nxt

    def modes(self, eb: BoolArray, sb: BoolArray, rows: Any = None) -> IntArray:
        """Operating mode per train from the last step (MODE_* values).

        ``rows`` (train indices): the modes of those trains only, in that order (the same
        values as the full array's entries).
        """
        if rows is None:
            return mode_of(self.v, self.acc, self.a_dem, eb | sb, self.dwelling, self.run)
        return mode_of(self.v[rows], self.acc[rows], self.a_dem[rows], eb[rows] | sb[rows],
                       self.dwelling[rows], self.run[rows])


def mode_of(v: FloatArray, acc: FloatArray, a_d: FloatArray, atp: BoolArray,
            dwelling: BoolArray, run: BoolArray) -> IntArray:
    """Operating mode (MODE_* values) of trains, per entry.

    ``v`` speed [m/s], ``acc`` acceleration and ``a_d`` demand [m/s^2], ``atp`` ATP braking,
    ``dwelling``, ``run`` in service.
    """
    m = np.full(v.shape, MODE_BRAKE)
    m = np.where(a_d > 0.02, np.where(acc > 0.05, MODE_ACCEL, MODE_CRUISE), m)
    m = np.where(np.abs(a_d) <= 0.02, MODE_COAST, m)
    m = np.where((a_d < -0.02) & (np.abs(acc) < 0.05) & (v > 0.5), MODE_CRUISE, m)
    m = np.where(atp, MODE_ATP, m)
    m = np.where(dwelling, MODE_DWELL, m)
    return np.asarray(np.where(run, m, MODE_OUT))
