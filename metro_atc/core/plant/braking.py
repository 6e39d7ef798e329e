"""Blended brake-by-wire with adhesion limits, and the instrumented car axle by axle.

The electric (regenerative) brake acts on the motored axles up to its power/force/fade
limits, the friction brake supplies the rest spread over all axles, the emergency brake is
friction only.  Each axle's rail force is limited by the slip-adhesion curve (dry/wet);
wheel-slide protection (WSP) keeps a sliding axle at least at the locked-wheel adhesion.
The *instrumented car* (a 4-axle trailer car, so no traction/electric-brake torque on its
axles) is modelled axle by axle with Lin 2010b, eq. 4
``J_w dw/dt = -2 mu_b R_b F_c + r_w F_x`` where **F_x > 0 retards the train**; pad-friction
and wheel faults act there (:meth:`Brakes.set_fault`).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from metro_atc.core import laws
from metro_atc.core.line.adhesion import AdhesionCurve
from metro_atc.core.line.track import G
from metro_atc.core.line.vehicle import TrainParams

from .tables import VehicleTables

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

N_AXLES_SENSED = 4
"""Axles of the instrumented car published in the brake sensor samples."""

_cnz = np.count_nonzero


class AxleState:
    """Instrumented-car axle state of one step: (F_x, clamp force, slip) per axle [n, 4].

    In the common case (no axle sliding, no WSP action) only the per-train friction share
    and demand are stored and the per-axle arrays are derived on first use (sensor samples,
    tests); sliding steps store the integrated arrays directly.  ``a_d``: the acceleration
    of the wheelset-inertia term, the step's actual one once :meth:`Brakes.follow` ran.
    """

    __slots__ = ("f_fa", "a_d", "w_axle", "coef", "arrays")

    def __init__(self, f_fa: FloatArray, a_d: FloatArray, w_axle: FloatArray,
                 coef: tuple[Any, ...],
                 arrays: tuple[FloatArray, FloatArray, FloatArray] | None = None) -> None:
        """Store the step's inputs (or the explicit arrays of a sliding step)."""
        self.f_fa, self.a_d, self.w_axle, self.coef = f_fa, a_d, w_axle, coef
        self.arrays = arrays

    def get(self) -> tuple[FloatArray, FloatArray, FloatArray]:
        """(fx, clamp, slip), each [n_trains, 4]."""
        if self.arrays is None:
            fc_per_n, tb_coef, inv_rw2, adh, jw, tab_mu, tab_slip = self.coef
            fc = np.empty(tb_coef.shape)
            fc[...] = (self.f_fa * fc_per_n)[:, None]
            fx = fc * tb_coef + (jw * np.minimum(self.a_d, 0.0))[:, None] * inv_rw2
            slip = np.interp(fx / (self.w_axle[:, None] * adh), tab_mu, tab_slip)
            self.arrays = (fx, fc, slip)
        return self.arrays


class Brakes:
    """Traction/brake blend and the adhesion-limited rail forces of a fleet."""

    def __init__(self, n: int, p: TrainParams, curve: AdhesionCurve, tables: VehicleTables,
                 control_period_s: float) -> None:
        """Healthy pads and wheels on every instrumented car, no axle sliding."""
        self.p = p
        self.curve = curve
        self.tables = tables
        self.dt = control_period_s
        self.mu_pk = curve.mu_peak
        self.mu_wsp = 0.5 * (curve.mu_peak + curve.mu_slide)
        n_ax = p.cars * p.axles_per_car
        self.n_ax = n_ax
        self.n_mot = int(round(p.motored_axle_fraction * n_ax))
        self.n_trail_plain = n_ax - self.n_mot - N_AXLES_SENSED
        if self.n_trail_plain < 0:
            raise ValueError("the instrumented 4-axle car must be a trailer car: "
                             "motored_axle_fraction too high")
        self.pad_mu = np.full((n, N_AXLES_SENSED), p.pad_mu_nominal)
        self.adh_factor = np.ones((n, N_AXLES_SENSED))
        self.r_w = np.full((n, N_AXLES_SENSED), p.wheel_radius_m)
        self.sliding = np.zeros((n, N_AXLES_SENSED), dtype=bool)
        self.wsp = np.zeros((n, N_AXLES_SENSED), dtype=bool)
        self.any_slide = False
        self.any_wsp = False
        z4 = np.zeros((n, N_AXLES_SENSED))
        self.ax = AxleState(np.zeros(n), np.zeros(n), np.ones(n), (), (z4, z4, z4))
        self.ax_prev = self.ax
        self.g_per_axle = G / n_ax
        self.trac_adh = curve.mu_peak * self.n_mot
        self.jw = p.wheel_inertia_kgm2
        # clamp force per N of tread effort: the inverse of the pad torque at r_w (eq. 4)
        self.fc_per_n = laws.clamp_force_for_torque(p.wheel_radius_m, p.pad_mu_nominal,
                                                    p.brake_radius_m)
        self.refresh_coefs()

    def refresh_coefs(self) -> None:
        """Per-axle coefficients of the instrumented car (refreshed when faults change)."""
        p = self.p
        # F_x per clamp N: pad torque per N (eq. 4) over r_w
        self.tb_coef = laws.pad_torque(1.0, self.pad_mu, p.brake_radius_m) / self.r_w
        self.inv_rw2 = 1.0 / (self.r_w * self.r_w)
        self.cap_coef = self.mu_pk * self.adh_factor
        adh = self.adh_factor.copy()
        self.ax_coef = (self.fc_per_n, self.tb_coef, self.inv_rw2, adh, self.jw,
                        self.tables.mu, self.tables.slip)
        # fast path: tread of the 4 sensed axles = f_fa * inst_sum; a slide is possible only
        # where f_fa * slide_ratio exceeds the axle load (the J_w term only lowers F_x)
        inst = self.fc_per_n * self.tb_coef
        self.inst_sum = inst.sum(axis=1)
        self.fric_mult = (self.n_ax - N_AXLES_SENSED) + self.inst_sum
        self.slide_ratio = np.max(inst / self.cap_coef, axis=1)

    def set_fault(self, i: int, axles: list[int], kind: str, on: bool, mu_b: float,
                  adhesion_factor: float, radius_factor: float) -> None:
        """Pad-friction (``pad_mu``) or wheel fault of train i's sensed axles on / off."""
        p = self.p
        # new arrays (copy on write): the sensor snapshots of past steps keep the old ones
        self.pad_mu, self.adh_factor, self.r_w = (self.pad_mu.copy(), self.adh_factor.copy(),
                                                  self.r_w.copy())
        for a in axles:
            if kind == "pad_mu":
                self.pad_mu[i, a] = mu_b if on else p.pad_mu_nominal
            else:
                self.adh_factor[i, a] = adhesion_factor if on else 1.0
                self.r_w[i, a] = p.wheel_radius_m * (radius_factor if on else 1.0)
        self.refresh_coefs()

    def rail_force(self, f_e: FloatArray, f_f: FloatArray, w_axle: FloatArray,
                   a_d: FloatArray, v: FloatArray) -> FloatArray:
        """Total braking force on the train [N] with adhesion limits (tread efforts).

        Plain axles: achieved = demand up to the peak adhesion, otherwise wheel-slide
        protection holds them at ``(mu_peak + mu_slide) / 2``.  The instrumented trailer car
        follows eq. 4 per axle (:meth:`instrumented_axles`).  Fast path when no axle can
        reach the peak adhesion (the usual case): everything demanded is achieved.
        """
        n_ax, n_mot = self.n_ax, self.n_mot
        f_fa = f_f * (1.0 / n_ax)  # friction share per axle
        cap_pk = self.mu_pk * w_axle
        d_mot = f_e * (1.0 / max(n_mot, 1)) + f_fa  # the most loaded plain axle
        if not (self.any_slide or self.any_wsp or _cnz(d_mot > cap_pk)
                or _cnz(f_fa * self.slide_ratio > w_axle)):
            self.ax_prev, self.ax = self.ax, AxleState(f_fa, a_d, w_axle, self.ax_coef)
            return np.asarray(f_e + f_fa * self.fric_mult)
        cap_wsp = self.mu_wsp * w_axle
        ach_mot = np.where(d_mot <= cap_pk, d_mot, cap_wsp)
        ach_tr = np.where(f_fa <= cap_pk, f_fa, cap_wsp)
        f_inst = self.instrumented_axles(f_fa, w_axle, a_d, v)
        return np.asarray(n_mot * ach_mot + self.n_trail_plain * ach_tr + f_inst)

    def instrumented_axles(self, f_fa: FloatArray, w_axle: FloatArray, a_d: FloatArray,
                           v: FloatArray) -> FloatArray:
        """Per-axle eq. 4 for the 4 sensed axles; returns their total retarding force [N].

        Brake-by-wire sets the clamp force for the *nominal* pad friction, so a degraded pad
        (``pad_mu``) gives less torque.  Rolling axles are quasi-static (the wheel follows the
        train, ``w_dot = a / r_w``; the stiff creep dynamics settle in ~10 ms):
        ``F_x = (2 mu_b R_b F_c + J_w a / r_w) / r_w`` and the slip is read off the rising
        branch of the adhesion curve; demand above the peak adhesion starts a slide.
        """
        fc = f_fa[:, None] * self.fc_per_n  # [n, 4] (WSP below)
        if self.any_wsp:
            fc = np.where(self.wsp, 0.3 * fc, fc)
        tread = fc * self.tb_coef  # brake torque / r_w
        fx_roll = tread + (self.jw * np.minimum(a_d, 0.0))[:, None] * self.inv_rw2
        nload = w_axle[:, None]
        cap = nload * self.cap_coef
        if self.any_slide or _cnz(fx_roll > cap):
            return self.slide_axles(f_fa[:, None] * self.fc_per_n, fx_roll, cap, nload, a_d, v)
        slip = np.interp(fx_roll / (nload * self.adh_factor), self.tables.mu, self.tables.slip)
        self.ax_prev, self.ax = self.ax, AxleState(f_fa, a_d, w_axle, self.ax_coef,
                                                   (fx_roll, fc, slip))
        # the train equation uses M_eff (wheelset inertia in the rotary allowance), so a rolling
        # axle contributes its tread effort T_b / r_w; F_x = tread + J_w a / r_w^2 is the rail
        # force of eq. 4 that the sensors/observer see.
        return np.asarray(tread.sum(axis=1))

    def follow(self, acc: FloatArray) -> None:
        """Wheelset inertia of the rolling axles at the step's *actual* acceleration ``acc``.

        The wheels follow the train (``w_dot = a / r_w``), not the demand: on a grade the two
        differ by the grade force, so :meth:`instrumented_axles` (called before the motion)
        is corrected here once the step's acceleration [m/s^2] is known.
        """
        ax = self.ax
        ax.a_d = acc
        if ax.arrays is not None:
            fx, fc, slip = ax.arrays
            fx_r = fc * self.tb_coef + (self.jw * np.minimum(acc, 0.0))[:, None] * self.inv_rw2
            s_r = np.interp(fx_r / (ax.w_axle[:, None] * self.adh_factor), self.tables.mu,
                            self.tables.slip)
            ax.arrays = (np.where(self.sliding, fx, fx_r), fc, np.where(self.sliding, slip, s_r))

    def slide_axles(self, fc_raw: FloatArray, fx_roll: FloatArray, cap: FloatArray,
                    nload: FloatArray, a_d: FloatArray, v_train: FloatArray) -> FloatArray:
        """Integrate eq. 4 explicitly (5 ms) for sliding axles with wheel-slide protection.

        WSP dumps the clamp force to 30 % above 15 % slip and re-applies it below 1.5 x the
        peak slip; an axle returns to the quasi-static rolling model when its slip is back on
        the stable branch and the demand is below the peak adhesion.
        """
        cur = self.curve
        rw = self.r_w
        jw = self.p.wheel_inertia_kgm2
        v = np.maximum(v_train[:, None], 0.05)
        slide0 = self.sliding | (fx_roll > cap)
        s0 = np.where(self.sliding, self.ax.get()[2], cur.slip_peak)
        omega = v * (1.0 - s0) / rw
        n_sub = max(int(round(self.dt / 0.005)), 1)
        h = self.dt / n_sub
        wsp = self.wsp.copy()
        tb_coef = laws.pad_torque(1.0, self.pad_mu, self.p.brake_radius_m)
        fx = fx_roll
        for _ in range(n_sub):
            s = np.clip(1.0 - omega * rw / v, 0.0, 1.0)
            wsp = np.where(s > 0.15, True, np.where(s < 1.5 * cur.slip_peak, False, wsp))
            tbm = tb_coef * fc_raw * np.where(wsp, 0.3, 1.0)
            fx = cur.mu(s) * self.adh_factor * nload
            omega = np.maximum(omega + h * (-tbm + rw * fx) / jw, 0.0)
        s = np.clip(1.0 - omega * rw / v, 0.0, 1.0)
        fc_now = fc_raw * np.where(wsp, 0.3, 1.0)
        demand = fc_now * self.tb_coef + (self.jw * np.minimum(a_d, 0.0))[:, None] \
            * self.inv_rw2
        still = slide0 & ((s > cur.slip_peak) | (demand > cap))
        s_roll = np.interp(demand / (nload * self.adh_factor), self.tables.mu,
                           self.tables.slip)
        self.sliding = still
        self.wsp = wsp & still
        self.any_slide = bool(still.any())
        self.any_wsp = bool(self.wsp.any())
        slip = np.where(still, s, s_roll)
        fx_all = np.where(still, fx, np.where(slide0, demand, fx_roll))
        clamp = np.where(slide0, fc_now, fc_raw)
        self.ax_prev, self.ax = self.ax, AxleState(
            fc_raw[:, 0] / self.fc_per_n, a_d, nload[:, 0], self.ax_coef,
            (fx_all, clamp, slip))
        tread = clamp * self.tb_coef
        # sliding axles transmit their adhesion force; rolling ones their tread effort
        return np.asarray(np.where(still, fx, tread).sum(axis=1))
