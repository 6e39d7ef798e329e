"""ATP supervisor (Ke 2010, Fig. 1) and the independent safety monitors.

The per-step supervision runs in the compiled step (:func:`.kernel.front`, braking curves
of :mod:`metro_atc.core.laws`); this module holds its constants, grids and state.

Moving-block end of authority = rear of the train ahead minus the safety margin (fixed
block: entry of the block holding its rear minus the margin); static/temporary speed-limit
supervision on precomputed grids; service-brake intervention ``sbi_lead_s`` before the
emergency-brake intervention; EB latched to standstill.  ATP is independent of the
driver/ATO command.  Separation and overspeed are monitored separately against the physical
limits and counted as *violations* (must stay 0).

The braking curve is :class:`metro_atc.core.line.track.BrakingCurve` (one implementation);
:attr:`AtpSupervisor.curve`, the grids and the per-train state are the public view that the
reference driver and the plots read.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from metro_atc.core.line.adhesion import AdhesionCurve
from metro_atc.core.line.atp_constants import atp_constants
from metro_atc.core.line.geometry import LineGeometry
from metro_atc.core.line.scenario import Scenario
from metro_atc.core.line.service import drive_envelope
from metro_atc.core.line.track import (BrakingCurve, braking_envelope, window_min_ahead,
                                       window_min_behind)
from metro_atc.core.line.vehicle import TrainParams

from .fleet import TURNBACK, Fleet
from .tables import VehicleTables

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]

_cnz = np.count_nonzero

CIVIL_TOL_MPS = 0.01
"""Speed above the civil limit counted as running above it [m/s] (numerical slack)."""


class AtpSupervisor:
    """ATP constants, supervision grids and per-train ATP state (EB, SB, counters)."""

    def __init__(self, scn: Scenario, p: TrainParams, geom: LineGeometry,
                 tables: VehicleTables, curve: AdhesionCurve, b_drive: float) -> None:
        """Constants and the worst-case assumptions; state for ``scn.trains.count`` trains."""
        self.geom = geom
        self.p = p
        self.tables = tables
        c = atp_constants(scn, p, geom, curve)
        self.constants = c
        self.b_guar_level = c.b_guar_level
        self.b_g = c.b_g
        self.a_w = c.a_w
        self.t_r = c.t_r
        self.margin = c.margin_m
        self.t_sbi = c.t_sbi
        self.tsr_notice_s = c.tsr_notice_s
        self.fixed_block = c.fixed_block
        self.block_len = geom.block_len
        self.n_resp = c.n_resp
        self.n_sbi = c.n_sbi
        # v_ebi(D) with the worst-case response acceleration at the current speed,
        # a_w(v) = phi(v) + g max_down (traction only falls as the speed rises during the
        # response time, so this is conservative)
        self.curve = BrakingCurve(self.b_g, self.t_r)
        self.g_down = c.g_down
        # static curve: v + a_w(v) t_r <= E  ->  v = g^-1(E), g monotone on the speed table
        aw_tab = tables.phi + self.g_down
        self._ebi_g_tab = np.maximum.accumulate(tables.v + aw_tab * self.t_r)
        self._aw0_tr = float(aw_tab[0] * self.t_r)
        self.b_drive = b_drive
        n = scn.trains.count
        self.eb = np.zeros(n, dtype=bool)
        self.sb = np.zeros(n, dtype=bool)
        self.interventions = np.zeros(n, dtype=np.int64)
        self.violations = np.zeros(n, dtype=np.int64)
        self.in_violation = np.zeros(n, dtype=bool)
        self.any_violation = False
        self.any_atp = False
        self.eoa = np.full(n, geom.eoa_end)
        self.eoa_ext = np.full(n, math.inf)
        """End of movement authority of each train given from outside [m] (inf: none; the
        compiled step takes the smallest of it, the train ahead's rear minus the margin and
        the line's end): a service day's interlocking routes and train ahead
        (:meth:`metro_atc.core.plant.line.LineSim.set_authority_ends`)."""
        self.lead_ext = False
        """True when the trains' index order is not their order on the track (a service
        day's fleet on a loop): no train ahead by index; the train ahead comes from outside
        through :attr:`eoa_ext`."""
        self.atp_limit = np.full(n, p.max_speed_mps)
        self.speed_code = np.full(n, p.max_speed_mps)
        self.min_sep = math.inf
        self.steps_above_civil = 0
        """Train-steps run above the civil speed limit (see :meth:`monitor`)."""
        self.drive_env = drive_envelope(geom, geom.static_limit, b_drive)

    # ------------------------------------------------------------------ grids

    def refresh(self, lim_atp: FloatArray, lim_phys: FloatArray) -> None:
        """Supervision grids from the per-cell limits known to ATP / in force [m/s]."""
        g = self.geom
        ceil_atp = window_min_behind(lim_atp, g.n_len) + g.ceiling_tol
        env = braking_envelope(ceil_atp, g.dx, self.b_g)
        e_min = window_min_ahead(env, self.n_resp)
        self.ebi_static = np.where(e_min < self._ebi_g_tab[0], e_min - self._aw0_tr,
                                   np.interp(e_min, self._ebi_g_tab, self.tables.v))
        self.sbi_static = window_min_ahead(self.ebi_static, self.n_sbi)
        self.limit_eff = window_min_behind(lim_atp, g.n_len)
        self.ceiling_phys = window_min_behind(lim_phys, g.n_len) + g.ceiling_tol
        self.drive_env = drive_envelope(g, lim_atp, self.b_drive)

    # ------------------------------------------------------------------ supervision

    def obstacle_rear(self, fl: Fleet, blocks: bool) -> FloatArray:
        """Chainage of the nearest obstacle ahead of each train's front [m] (inf if none).

        The train ahead on the running line (its rear; with ``blocks`` the entry of the block
        holding its rear), or -- beyond the terminus -- the train still standing in the
        turnback siding this train will use (siding ``i % turnback_sidings``); trains on a
        siding are off the running line for the others.
        """
        g = self.geom
        x, n, ns, run = fl.x, fl.n, g.n_sid, fl.run
        if self.lead_ext:  # the train ahead is given from outside (eoa_ext)
            return np.full(n, math.inf)
        rear = x - g.length_m
        if not (blocks or fl.any_turnback):  # fast path: nobody near the sidings
            obst = np.empty(n)
            obst[0] = math.inf
            np.add(rear[:-1], fl.lead_add, out=obst[1:])
            return obst
        obst = np.full(n, math.inf)
        on_siding = (fl.status == TURNBACK) & (rear > g.x_switch)
        if n > 1:
            lead_main = run[:-1] & ~on_siding[:-1]
            r1 = rear[:-1]
            if blocks:
                r1 = g.x0 + np.floor((r1 - g.x0) / self.block_len) * self.block_len
            obst[1:] = np.where(lead_main, r1, math.inf)
        if n > ns:
            same = on_siding[:-ns] & run[:-ns]
            obst[ns:] = np.minimum(obst[ns:], np.where(same, rear[:-ns], math.inf))
        return obst

    def monitor(self, fl: Fleet, obst: FloatArray, k: IntArray, count: bool = True) -> None:
        """Independent safety monitors: separation and overspeed violations, min separation.

        Checks the state at the start of the step (= the end of the previous one) against the
        physical limits (not the ATP's anticipated ones).  With ``count`` it also counts the
        train-steps run above the civil limit (the limit in force over the whole train, by
        more than ``CIVIL_TOL_MPS``; the ATP overspeed margin is for faults, not driving).
        """
        x, v, run = fl.x, fl.v, fl.run
        if count:
            civil = self.ceiling_phys[k] - self.geom.ceiling_tol
            self.steps_above_civil += int(_cnz(run & (v > civil + CIVIL_TOL_MPS)))
        gap = obst - x
        gmin = float(np.where(run, gap, math.inf).min())
        if gmin < self.min_sep:
            self.min_sep = gmin
        bad = run & ((gap < self.margin - 1e-6) | (v > self.ceiling_phys[k] + 1e-6))
        if self.any_violation or _cnz(bad):
            new = bad & ~self.in_violation
            if new.any():
                self.violations += new
            self.in_violation = bad
            self.any_violation = bool(bad.any())

    def monitor_now(self, fl: Fleet) -> None:
        """The safety monitors on the current state (end of a run, before the KPIs)."""
        self.monitor(fl, self.obstacle_rear(fl, False), self.geom.cells(fl.x), count=False)
