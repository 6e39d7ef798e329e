"""Compiled (numba) motion, energy and reference driver; :func:`step_all` fuses a step.

RK4 with the energy quadrature of each force (:func:`metro_atc.core.laws.davis_rk4_step`),
the energy meter's counters (:class:`.energy.EnergyMeter`) and the reference driver
(:func:`.driver.driver_command`); see :mod:`.kernel`.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from metro_atc.core import laws

from .kernel import (CONSTANTS, GRIDS, MASKS, MASS, OUT, _cell, _mn, _mx, axle_fill, front,
                     rows)
from .kernel_aux import sensor_block

DRIVER_FIELDS = ("x0", "inv_dx", "b_drive", "t_sbi", "c0", "c2", "c1", "bs", "tol", "gain",
                 "lookahead")
"""Fields of :data:`DRIVER` (float64, in the vector's order): grid x0 [m], 1/dx [1/m],
driving deceleration [m/s^2], t_sbi [s], the EBI curve's coefficients c0, c2, c1 at the
ATP's worst-case acceleration, service brake [m/s^2], stopping tolerance [m], gain [s/m],
look-ahead [s] (:func:`.driver.driver_command`)."""
DRIVER = np.dtype([(f, np.float64) for f in DRIVER_FIELDS])
"""The reference driver's constants by name: a float vector viewed as this record in
:func:`driver` (one row of ``dcs``: the reference driver's, the plant driver's)."""
FS = rows("trac_level", "stop_x", "speed_code", "eoa_ext", "e_trac", "e_elec", "e_fric",
          "e_res", "e_curve", "e_grade", "e_stop_corr", *MASS._fields, "slide_ratio",
          "fric_mult", "auto")
"""Rows of the persistent float block of :func:`step_rows` (:mod:`.fast_state`, laid out
by ``fast._blocks`` from these names): the state the kernel owns (traction level [-],
stop point [m], speed code [m/s], end of authority given from outside [m], energy
counters [J]), then the copied mass constants
(:data:`.kernel.MASS` order, from ``mass``) and brake ratios (from ``slide_ratio``), then
the plant driver's command (scratch, ``auto``)."""
N_F = len(FS)
"""Rows of the float block."""
INTS = rows("status", "interventions", "violations", "n_in_service")
"""Rows of the integer block (the fleet's, ATP's and energy meter's attributes)."""
BOOLS = rows("eb", "sb", "in_violation", *MASKS._fields)
"""Rows of the boolean block: the ATP's flags, then the fleet masks (:data:`.kernel.MASKS`
order, from ``run``)."""


@njit(cache=True)
def motion(c, x, v, f_trac, f_brake, f_e, f_bdem, mp, geo, masks, stop_x, e_trac, e_elec,
           e_fric, e_res, e_curve, e_grade, e_stop_corr, n_in_service,
           blk):  # type: ignore[no-untyped-def]
    """:func:`motion_rec` with the run constants as their float vector ``c`` (from Python)."""
    return motion_rec(c.view(CONSTANTS)[0], x, v, f_trac, f_brake, f_e, f_bdem, mp, geo,
                      masks, stop_x, e_trac, e_elec, e_fric, e_res, e_curve, e_grade,
                      e_stop_corr, n_in_service, blk)


@njit(cache=True)
def motion_rec(cn, x, v, f_trac, f_brake, f_e, f_bdem, mp, geo, masks, stop_x, e_trac,
               e_elec, e_fric, e_res, e_curve, e_grade, e_stop_corr, n_in_service,
               blk):  # type: ignore[no-untyped-def]
    """RK4 with energy quadrature, energy meter, arrival candidates of one step.

    ``cn``: the run constants (a ``kernel.CONSTANTS`` record).  Writes x1, v1, acc and the
    distance to the stop point into ``blk``; returns the number of trains at or past their
    stop point (arrival / overrun candidates).
    """
    n = x.shape[0]
    n_cells = geo.shape[1]
    mass, meff, inv_m = mp[MASS.mass], mp[MASS.meff], mp[MASS.inv_meff]
    cb, cc = mp[MASS.davis_b], mp[MASS.davis_c]
    x0, inv_dx = cn["x0"], cn["inv_dx"]
    da, db, dc = cn["davis_a"], cn["davis_b"], cn["davis_c"]
    dt = cn["dt"]
    substeps = int(cn["substeps"])
    h = dt / substeps
    h6 = h / 6.0
    xs = x.copy()
    vs = v.copy()
    w_res = np.zeros(n)
    w_grade = np.zeros(n)
    w_curve = np.zeros(n)
    clamped = np.zeros(n, dtype=np.bool_)
    vn = np.empty(n)
    dxs = np.empty(n)
    pr = np.empty(n)
    k1s = np.empty(n)
    fg = np.empty(n)
    fcv = np.empty(n)
    for _ in range(substeps):
        n_stop = 0
        n_stop_moving = 0
        for i in range(n):
            kk = _cell(xs[i], x0, inv_dx, n_cells)
            f_g = mass[i] * geo[0, kk]
            f_c = mass[i] * geo[1, kk]
            fg[i], fcv[i] = f_g, f_c
            f_const = f_trac[i] - f_brake[i] - da
            q = (f_const - f_g - f_c) * inv_m[i]
            v1_ = vs[i]
            vn[i], dxs[i], k1, kv = laws.davis_rk4_step(v1_, q, cb[i], cc[i], h)
            # resistance work: Davis force = A + M_eff (q_A - k), by the same quadrature
            pr[i] = (q * dxs[i] - h6 * kv) * meff[i] + da * dxs[i]
            k1s[i] = k1
            if vn[i] <= 0.0:
                n_stop += 1
                if v1_ != 0.0:
                    n_stop_moving += 1
        for i in range(n):
            if n_stop and vn[i] <= 0.0:
                vi = vs[i]
                vn[i] = 0.0
                if n_stop_moving == 0:  # only trains already at rest: exactly at rest
                    dxs[i] = 0.0
                    pr[i] = 0.0
                else:  # uniform deceleration to rest (no roll-back)
                    d_stop = laws.stop_distance_in_step(vi, k1s[i], h)
                    dxs[i] = d_stop
                    pr[i] = laws.davis_resistance(vi, da, db, dc) * d_stop
                    clamped[i] = True
            w_res[i] = w_res[i] + pr[i]
            w_grade[i] = w_grade[i] + fg[i] * dxs[i]
            w_curve[i] = w_curve[i] + fcv[i] * dxs[i]
            xs[i] = xs[i] + dxs[i]
            vs[i] = vn[i]
    inv_dt = 1.0 / dt
    n_hit = 0
    tol = cn["tol"]
    run, cand = masks[MASKS.run], masks[MASKS.cand]
    for i in range(n):
        x1, v1, v0 = xs[i], vs[i], v[i]
        dxt = x1 - x[i]
        w_trac = f_trac[i] * dxt
        w_brk = f_brake[i] * dxt
        if clamped[i]:  # the friction brake absorbs what is left (energy.py)
            resid = (w_trac - w_grade[i] - w_curve[i] - w_res[i]
                     - 0.5 * meff[i] * (v1 * v1 - v0 * v0))
            w_new = _mx(resid, 0.0)
            e_stop_corr[i] += abs(w_new - w_brk)
            w_brk = w_new
        w_e = w_brk * (f_e[i] / _mx(f_bdem[i], 1e-9))
        e_trac[i] += w_trac
        e_elec[i] += w_e
        e_fric[i] += w_brk - w_e
        e_res[i] += w_res[i]
        e_curve[i] += w_curve[i]
        e_grade[i] += w_grade[i]
        if run[i]:
            n_in_service[i] += 1
        blk[OUT.x1, i] = x1
        blk[OUT.v1, i] = v1
        blk[OUT.acc, i] = (v1 - v0) * inv_dt
        d = x1 - stop_x[i]
        blk[OUT.d, i] = d
        if cand[i] and (d > tol or (v1 <= 0.0 and d >= -tol)):
            n_hit += 1
    return n_hit


@njit(cache=True)
def driver(dc, x, v, stop_x, eoa, speed_code, drive_env, sbi_static, status,
           fixed: bool, active_only: bool, out):  # type: ignore[no-untyped-def]
    """:func:`driver_rec` with the constants as their float vector ``dc`` (from Python)."""
    driver_rec(dc.view(DRIVER)[0], x, v, stop_x, eoa, speed_code, drive_env, sbi_static,
               status, fixed, active_only, out)


@njit(cache=True)
def driver_rec(d, x, v, stop_x, eoa, speed_code, drive_env, sbi_static, status,
               fixed: bool, active_only: bool, out):  # type: ignore[no-untyped-def]
    """Reference driver command per train into ``out`` (0 for trains not RUN if asked).

    ``d``: the driver's constants (a :data:`DRIVER` record).
    """
    n = x.shape[0]
    n_cells = drive_env.shape[0]
    b_drive = d["b_drive"]
    c0, c1, c2 = d["c0"], d["c1"], d["c2"] + 1.0
    tol = 0.5 * d["tol"]
    for i in range(n):
        xi, vi = x[i], v[i]
        la = vi * d["lookahead"]
        kl = _cell(xi + la, d["x0"], d["inv_dx"], n_cells)
        d_stop = stop_x[i] - xi
        d_ma = eoa[i] - xi - 3.0
        d_eff = _mn(d_stop, d_ma)
        v_curve = laws.braking_speed(d_eff - la, b_drive)
        lead = vi * (d["t_sbi"] + 2.0)
        v_atp = laws.ebi_speed_from(c0, c1, c2, d_ma - lead)
        v_ref = _mn(_mn(drive_env[kl], v_curve), _mn(v_atp, sbi_static[kl] - 1.0))
        if fixed:
            v_ref = _mn(v_ref, speed_code[i] - 0.5)
        err = d["gain"] * (v_ref - vi)
        u = err
        if d_eff < (0.65 / b_drive) * vi * vi + 1.0:
            ff = (vi * vi) / (-2.0 * d["bs"] * _mx(d_eff, 0.05))
            u = _mn(err, ff + err)
        if vi < 0.3 and d_stop > tol and v_ref > 1.0:
            u = _mx(u, 0.3)
        if d_stop <= tol and vi < 0.5:
            u = -1.0
        u = _mn(_mx(u, -1.0), 1.0)
        if active_only and status[i] != 1:
            u = 0.0
        out[i] = u


@njit(cache=True)
def step_all(cn, x, v, status, masks, u, u_last, auto_u, a_prev, mp, trac_level, eb, sb,
             interventions, violations, in_violation, grids, tabs, speed_code, bk,
             any_slide: bool, any_wsp: bool, blk, geo, stop_x, e_trac, e_elec, e_fric, e_res,
             e_curve, e_grade, e_stop_corr, n_in_service, axc, stab, ax_out, dr,
             want_drv: bool, sidx, r_w, slip0, ts, t0: float, t1: float, zbuf, zpos: int,
             noise, o4, o2, auto: bool, eoa0, dr_auto,
             eoa_ext):  # type: ignore[no-untyped-def]
    """One step: :func:`.kernel.front`, then (rail force done) :func:`motion`.

    Also fills ``ax_out`` (instrumented axles, when it has rows), the sensor samples of the
    trains ``sidx`` at the instants ``ts`` (when ``o4`` has samples and ``ax_out`` rows:
    :func:`.kernel_aux.sensor_block` with the normals ``zbuf[zpos:]``, previous axle slips
    ``slip0``) and, with ``want_drv`` and no arrival candidate, the reference driver's next
    command (row ``OUT.drv``).  Returns front's figures and the number of arrival candidates
    (-1: rail force left to numpy).  With ``auto`` the commands of the plant-driven
    trains are first computed into ``auto_u`` (:func:`driver_rec`, constants ``dr_auto``,
    movement authority ``eoa0`` of the previous step).  ``cn``: the run constants (a
    ``kernel.CONSTANTS`` record); ``dr`` / ``dr_auto``: :data:`DRIVER` records;
    ``eoa_ext``: the end of authority of each train given from outside [m].
    """
    fixed = cn["fixed"] != 0.0
    if auto:
        driver_rec(dr_auto, x, v, stop_x, eoa0, speed_code, grids[GRIDS.drive_env],
                   grids[GRIDS.sbi_static], status, fixed, False, auto_u)
    r = front(cn, x, v, status, masks, u, u_last, auto_u, a_prev, mp, trac_level, eb, sb,
              interventions, violations, in_violation, grids, tabs, speed_code, bk,
              any_slide, any_wsp, blk, eoa_ext)
    if not r[5]:
        return r[0], r[1], r[2], r[3], r[4], -1
    n_hit = motion_rec(cn, x, v, blk[OUT.ftrac], blk[OUT.fbrk], blk[OUT.fe], blk[OUT.fbdem], mp,
                       geo, masks, stop_x, e_trac, e_elec, e_fric, e_res, e_curve, e_grade,
                       e_stop_corr, n_in_service, blk)
    if ax_out.shape[1]:
        axle_fill(cn, blk[OUT.ffa], blk[OUT.acc], blk[OUT.wax], axc, stab, ax_out)
        if o4.shape[1]:
            sensor_block(sidx, r_w, slip0, ax_out[2], ax_out[1], v, blk[OUT.v1], blk[OUT.acc],
                         ts, t0, t1, zbuf[zpos:], noise, o4, o2)
    if want_drv and n_hit == 0:
        driver_rec(dr, blk[OUT.x1], blk[OUT.v1], stop_x, blk[OUT.eoa], speed_code,
                   grids[GRIDS.drive_env], grids[GRIDS.sbi_static], status, fixed, True,
                   blk[OUT.drv])
    return r[0], r[1], r[2], r[3], r[4], n_hit


@njit(cache=True)
def step_rows(c, tabs, geo, stab, dcs, fs, ints, bools, grids, axc, blk0, blk, u, ax_out,
              r_w, sidx, slip0, ts, zbuf, zpos: int, so, any_slide: bool, any_wsp: bool,
              want_drv: bool, auto: bool, t0: float, t1: float):  # type: ignore
    """:func:`step_all` on the persistent blocks (few arguments: cheap to call).

    ``fs`` / ``ints`` / ``bools``: the :data:`FS` / :data:`INTS` / :data:`BOOLS` rows;
    ``blk0``: the previous step's output block (x, v, commanded and demanded effort,
    movement authority are its rows); ``dcs`` = (reference driver, plant driver)
    constants; ``so``: flat buffer of the sensor samples, (omega, clamp) [2, s, m, 4]
    then (accel, vref) [2, s, m].
    """
    ns, m, na = ts.shape[0], sidx.shape[0], ax_out.shape[2]
    k4 = 2 * ns * m * na
    o4 = so[:k4].reshape((2, ns, m, na))
    o2 = so[k4:k4 + 2 * ns * m].reshape((2, ns, m))
    cn = c.view(CONSTANTS)[0]
    return step_all(
        cn, blk0[OUT.x1], blk0[OUT.v1], ints[INTS.status], bools[BOOLS.run:], u,
        blk0[OUT.u], fs[FS.auto], blk0[OUT.ad], fs[FS.mass:FS.mass + len(MASS)],
        fs[FS.trac_level], bools[BOOLS.eb], bools[BOOLS.sb], ints[INTS.interventions],
        ints[INTS.violations], bools[BOOLS.in_violation], grids, tabs, fs[FS.speed_code],
        fs[FS.slide_ratio:FS.fric_mult + 1], any_slide, any_wsp, blk, geo, fs[FS.stop_x],
        fs[FS.e_trac], fs[FS.e_elec], fs[FS.e_fric], fs[FS.e_res], fs[FS.e_curve],
        fs[FS.e_grade], fs[FS.e_stop_corr], ints[INTS.n_in_service], axc, stab, ax_out,
        dcs[0].view(DRIVER)[0], want_drv, sidx, r_w, slip0,
        ts, t0, t1, zbuf, zpos, cn["noise"], o4, o2, auto, blk0[OUT.eoa],
        dcs[1].view(DRIVER)[0], fs[FS.eoa_ext])
