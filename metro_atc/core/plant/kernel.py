"""Compiled step kernel of the plant (numba): ATP, demand and brake blend fused per train.

The physics is :mod:`metro_atc.core.laws` (traction, brakes, adhesion, ATP braking curves,
RK4), called per train and inlined by numba; no fast-math, no fused multiply-add.  The
kernels read and write the components' own arrays (:mod:`.atp`, :mod:`.braking`,
:mod:`.energy`, :mod:`.fleet`; no state of their own).  References: the golden traces
(``test_plant_golden.py``) and the recorded generated-line traces
(``test_plant_kernel.py``), both recorded when a numpy twin of this step still existed.

Constants of a run travel as one float vector (built by :mod:`.fast`) that each kernel reads
through the record :data:`CONSTANTS` (``c.view(CONSTANTS)[0]``: free in compiled code; numpy
record fields cost ~1 us each from Python, so the Python side keeps the plain vector);
per-step outputs are the rows of one fresh ``[N_OUT, n]`` block (:data:`OUT`: the fleet's and
the ATP's arrays are views of those rows).
Compiled on first use and cached on disk (``cache=True``; numba falls back to the user
cache directory when the package directory is read-only).
"""

from __future__ import annotations

import math
from collections import namedtuple
from typing import Any

import numpy as np
from numba import njit

from metro_atc.core import laws

CONSTANT_FIELDS = (
    "x0", "inv_dx", "train_length", "x_switch", "block", "margin", "eoa_end", "g_down", "b_g",
    "t_r", "t_sbi", "sbi_offset", "ceiling_tol", "bs", "eb_decel", "jerk", "jerk_eb",
    "civil_tol", "n_ax", "trac_adh", "mu_pk", "inv_nax", "inv_nmot", "davis_a", "davis_b",
    "davis_c", "dt", "tol", "code_step", "fixed", "n_sid", "substeps", "fc_per_n", "jw",
    "m_trac", "meff_sb", "meff_eb", "lead_ext")
"""Scalar fields of :data:`CONSTANTS` (float64, in the vector's order).

Grid x0 [m] and 1/dx [1/m]; train length [m]; turn-back switch position [m]; block length
[m]; ATP safety margin [m]; movement authority's end at the line's end [m]; ATP: downhill
acceleration g_down [m/s^2], guaranteed brake b_g [m/s^2], reaction time t_r [s], t_sbi
[s], SBI offset [m/s], ceiling tolerance [m/s]; service brake [m/s^2], emergency brake
[m/s^2]; jerk limits x dt (service, emergency) [m/s^2]; civil-limit tolerance [m/s];
brakes: axles per train, peak adhesion x motored axles [-], peak adhesion [-], 1/axles,
1/motored axles; Davis a [N], b [N s/m], c [N s^2/m^2]; control period dt [s]; stopping
tolerance [m]; speed-code step [m/s]; fixed block 0/1; turn-back sidings; RK4 substeps;
clamp force per brake force [-]; wheel inertia [kg m^2]; the mass the traction curve is
specified at [kg] (:func:`metro_atc.core.laws.traction_mass`); the effective masses up to
which the service and the emergency brake are load-weighed [kg]
(:func:`metro_atc.core.laws.load_weighed_decel`); 1 when the train ahead is given from
outside (the index order is not the track order: no obstacle by index,
:attr:`.atp.AtpSupervisor.lead_ext`), else 0.
"""
CONSTANTS = np.dtype([(f, np.float64) for f in CONSTANT_FIELDS]
                     + [("noise", np.float64, (4,))])
"""The run constants by name, then the sensor noise standard deviations (omega [rad/s],
clamp [N], accel [m/s^2], reference speed [m/s]; :func:`.kernel_aux.sensor_block`).  A
float vector of ``CONSTANTS.itemsize / 8`` values, viewed as this record once per compiled
call from Python (:func:`.kernel_step.step_rows`, :func:`.kernel_run.run_rows`, the
wrappers :func:`.kernel_step.motion` / :func:`.kernel_step.driver`) and handed down."""


def rows(*names: str) -> Any:
    """Named rows of a block: a namedtuple of the row indices 0, 1, ... of ``names``.

    Read as ``blk[OUT.x1, i]`` in compiled code (numba freezes the global tuple: the
    index is a constant, as the numbered constants were) and from Python alike.
    """
    return namedtuple("Rows", names)(*range(len(names)))


OUT = rows("x1", "v1", "acc", "lim", "eoa", "ad", "ffa", "wax", "u", "drv", "phi", "ftrac",
           "fbdem", "fe", "ff", "fbrk", "d", "vsbi", "obst", "ebr")
"""Rows of the per-step output block ``[N_OUT, n]``: position, speed, acceleration after the
step [m, m/s, m/s^2]; ATP limit [m/s]; movement authority [m]; demanded acceleration
[m/s^2]; friction force per axle [N]; axle load [N]; clean command [-]; the reference
driver's next command [-]; traction curve phi [m/s^2]; tractive force, brake demand,
electric and friction brake force, brake force on the rail [N]; distance past the stop
point [m]; SBI speed [m/s]; obstacle ahead [m]; electric brake limit [N]."""
N_OUT = len(OUT)
"""Rows of the output block."""
MASKS = rows("run", "hold", "broken", "auto", "cand")
"""Rows of the packed fleet masks (in service, held, broken down, plant-driven, arrival
candidate)."""
MASS = rows("mass", "meff", "inv_meff", "davis_b", "davis_c")
"""Rows of the packed mass constants: mass, effective mass [kg], 1 / M_eff [1/kg], Davis B
and C over M_eff [1/s, 1/m] (the fleet's attributes of these names)."""
GRIDS = rows("ebi_static", "sbi_static", "ceiling_phys", "limit_eff", "drive_env")
"""Rows of the packed supervision grids (the ATP's attributes of these names) [m/s]."""
_TURNBACK = 2


_mx = laws.fmax
"""``np.maximum`` of two floats (:func:`metro_atc.core.laws.fmax`)."""
_mn = laws.fmin
"""``np.minimum`` of two floats (:func:`metro_atc.core.laws.fmin`)."""


@njit(cache=True, inline="always")
def interp_j(x: float, xp) -> int:  # type: ignore[no-untyped-def]
    """Interval of ``x`` in ``xp`` for :func:`interp_at` (-1 NaN, -2 below, n above)."""
    n = xp.shape[0]
    if x != x:
        return -1
    if x < xp[0]:
        return -2
    if x > xp[n - 1]:
        return n
    lo, hi = 0, n
    while lo < hi:  # last j with xp[j] <= x
        mid = (lo + hi) >> 1
        if x >= xp[mid]:
            lo = mid + 1
        else:
            hi = mid
    return lo - 1


@njit(cache=True, inline="always")
def interp_at(x: float, xp, fp, j: int) -> float:  # type: ignore[no-untyped-def]
    """``np.interp(x, xp, fp)`` with ``j = interp_j(x, xp)`` (numpy's special cases)."""
    n = xp.shape[0]
    if j == -1:
        return x
    if j == -2:
        return fp[0]
    if j == n:
        return fp[n - 1]
    if j == n - 1 or xp[j] == x:
        return fp[j]
    slope = (fp[j + 1] - fp[j]) / (xp[j + 1] - xp[j])
    r = slope * (x - xp[j]) + fp[j]
    if r != r:
        r = slope * (x - xp[j + 1]) + fp[j + 1]
        if r != r and fp[j] == fp[j + 1]:
            r = fp[j]
    return r


@njit(cache=True)
def interp1(x: float, xp, fp) -> float:  # type: ignore[no-untyped-def]
    """``np.interp(x, xp, fp)`` for one value (numpy's algorithm and special cases)."""
    return interp_at(x, xp, fp, interp_j(x, xp))


@njit(cache=True, inline="always")
def _cell(x: float, x0: float, inv_dx: float, n_cells: int) -> int:
    """Grid cell of ``x`` (``int((x - x0) / dx)``; clamped to the grid)."""
    k = int((x - x0) * inv_dx)
    return min(max(k, 0), n_cells - 1)


@njit(cache=True)
def obstacles(cn, x, status, run, n_sid: int, blocks: bool, out) -> None:  # type: ignore
    """:meth:`.atp.AtpSupervisor.obstacle_rear` into ``out`` [m] (``cn``: run constants)."""
    n = x.shape[0]
    if cn["lead_ext"] != 0.0:  # the train ahead comes from outside (eoa_ext)
        for i in range(n):
            out[i] = math.inf
        return
    x0, blen, ln, xsw = cn["x0"], cn["block"], cn["train_length"], cn["x_switch"]
    out[0] = math.inf
    for i in range(1, n):
        j = i - 1
        rear = x[j] - ln
        if run[j] and not (status[j] == _TURNBACK and rear > xsw):
            if blocks:
                rear = x0 + math.floor((rear - x0) / blen) * blen
            out[i] = rear
        else:
            out[i] = math.inf
    for i in range(n_sid, n):
        j = i - n_sid
        rear = x[j] - ln
        if status[j] == _TURNBACK and rear > xsw and run[j]:
            out[i] = _mn(out[i], rear)


@njit(cache=True)
def front(cn, x, v, status, masks, u, u_last, auto_u, a_prev, mp, trac_level, eb, sb,
          interventions, violations, in_violation, grids, tabs, speed_code, bk,
          any_slide: bool, any_wsp: bool, blk, eoa_ext):  # type: ignore[no-untyped-def]
    """ATP supervision + monitors, jerk-limited demand, blend (fast path) of one step.

    ``cn``: the run constants (a :data:`CONSTANTS` record); ``masks`` = fleet (run, hold,
    broken, auto, cand); ``mp`` = (mass, meff, 1/meff, Davis B/meff, C/meff); ``grids`` =
    (ebi_static, sbi_static, ceiling_phys, limit_eff, drive_env); ``tabs`` = (v, phi,
    ebrake); ``bk`` = brakes (slide_ratio, fric_mult); ``eoa_ext``: end of authority of
    each train given from outside [m] (:attr:`.atp.AtpSupervisor.eoa_ext`).
    Returns (new interventions, any_atp, any_violation, smallest gap [m], train-steps above
    the civil limit, rail force done) -- the rail force is left to the numpy slide model
    when an axle may reach the peak adhesion.
    """
    n = x.shape[0]
    fixed = cn["fixed"] != 0.0
    n_cells = grids.shape[1]
    run, hold = masks[MASKS.run], masks[MASKS.hold]
    broken, auto = masks[MASKS.broken], masks[MASKS.auto]
    mass, meff = mp[MASS.mass], mp[MASS.meff]
    ebi_s, sbi_s = grids[GRIDS.ebi_static], grids[GRIDS.sbi_static]
    ceil_p, lim_eff = grids[GRIDS.ceiling_phys], grids[GRIDS.limit_eff]
    tv, tphi, tebr = tabs[0], tabs[1], tabs[2]
    x0, inv_dx = cn["x0"], cn["inv_dx"]
    obst, eoa, lim = blk[OUT.obst], blk[OUT.eoa], blk[OUT.lim]
    vsbi, phi = blk[OUT.vsbi], blk[OUT.phi]
    any_atp = False
    any_viol = False
    any_broken = False
    for i in range(n):  # commands: NaN keeps the last one, clip to [-1, 1]
        ui = u[i]
        if ui != ui:
            ui = u_last[i]
        blk[OUT.u, i] = _mn(_mx(ui, -1.0), 1.0)
        any_atp = any_atp or eb[i] or sb[i]
        any_viol = any_viol or in_violation[i]
        any_broken = any_broken or broken[i]
    n_sid = int(cn["n_sid"])
    if fixed:
        obstacles(cn, x, status, run, n_sid, True, obst)
        for i in range(n):
            eoa[i] = _mn(_mn(obst[i] - cn["margin"], cn["eoa_end"]), eoa_ext[i])
    obstacles(cn, x, status, run, n_sid, False, obst)
    if not fixed:
        for i in range(n):
            eoa[i] = _mn(_mn(obst[i] - cn["margin"], cn["eoa_end"]), eoa_ext[i])
    n_over = 0
    for i in range(n):
        k = _cell(x[i], x0, inv_dx, n_cells)
        dist = eoa[i] - x[i]
        jv = interp_j(v[i], tv)  # one look-up for the traction and e-brake tables
        ph = interp_at(v[i], tv, tphi, jv)
        phi[i] = ph
        blk[OUT.ebr, i] = interp_at(v[i], tv, tebr, jv)
        a_w = ph + cn["g_down"]
        c0, c1, c2 = laws.ebi_coef(cn["b_g"], cn["t_r"], a_w)
        v_ma = laws.ebi_speed_from(c0, c1, c2, dist)
        lim[i] = _mn(ebi_s[k], v_ma)
        v_sb_ma = laws.ebi_speed_from(c0, c1, c2, dist - cn["t_sbi"] * v[i])
        vs = _mn(sbi_s[k], v_sb_ma) - cn["sbi_offset"]
        if fixed:
            start = x0 + math.floor((x[i] - x0) / cn["block"]) * cn["block"]
            code = laws.braking_speed(eoa[i] - start, cn["bs"])
            code = math.floor(code / cn["code_step"]) * cn["code_step"]
            speed_code[i] = _mn(code, lim_eff[k])
            vs = _mn(vs, speed_code[i] + 0.5 * cn["ceiling_tol"])
        vsbi[i] = vs
        if run[i] and v[i] > vs:
            n_over += 1
    n_int = 0
    if any_atp or n_over:
        any_atp = False
        for i in range(n):
            moving = v[i] > 0.0
            e0, s0 = eb[i], sb[i]
            e1 = run[i] and ((e0 and moving) or v[i] > lim[i])
            over = run[i] and v[i] > vsbi[i]
            s1 = (not e1) and (over or (s0 and moving and run[i] and v[i] > vsbi[i] - 0.5))
            if moving and ((e1 and not e0) or (s1 and not s0 and not e0)):
                n_int += 1
                interventions[i] += 1
            eb[i], sb[i] = e1, s1
            any_atp = any_atp or e1 or s1
    # safety monitors (state at the start of the step)
    n_civil = 0
    gmin = math.inf
    n_bad = 0
    for i in range(n):
        k = _cell(x[i], x0, inv_dx, n_cells)
        if run[i]:
            if v[i] > (ceil_p[k] - cn["ceiling_tol"]) + cn["civil_tol"]:
                n_civil += 1
            gap = obst[i] - x[i]
            gmin = _mn(gmin, gap)
            if gap < cn["margin"] - 1e-6 or v[i] > ceil_p[k] + 1e-6:
                n_bad += 1
    if any_viol or n_bad:
        for i in range(n):
            k = _cell(x[i], x0, inv_dx, n_cells)
            bad = run[i] and (obst[i] - x[i] < cn["margin"] - 1e-6
                              or v[i] > ceil_p[k] + 1e-6)
            if bad and not in_violation[i]:
                violations[i] += 1
            in_violation[i] = bad
        any_viol = n_bad > 0
    # demand, jerk limit, blend
    override = any_atp or any_broken
    bs = cn["bs"]
    fast = not (any_slide or any_wsp)
    slide_ratio, fric_mult = bk[0], bk[1]
    m_trac, meff_sb = cn["m_trac"], cn["meff_sb"]
    for i in range(n):
        ui = auto_u[i] if auto[i] else blk[OUT.u, i]
        # motor force limit above the load the curve is given at; service brake at its
        # load-weighed rate (its maximum force above the load-weigh limit)
        f_max = phi[i] * laws.traction_mass(mass[i], m_trac) * trac_level[i]
        bs_i = laws.load_weighed_decel(bs, meff[i], meff_sb)
        a_t = ui * f_max / meff[i] if ui >= 0.0 else ui * bs_i
        if hold[i]:
            a_t = -bs_i
        jmax = cn["jerk"]
        ebm = False
        if override:
            ebm = eb[i] or broken[i]
            if sb[i]:
                a_t = _mn(a_t, -bs_i)
            if ebm:
                a_t = -laws.load_weighed_decel(cn["eb_decel"], meff[i], cn["meff_eb"])
                jmax = cn["jerk_eb"]
        a_d = _mn(_mx(a_t, a_prev[i] - jmax), a_prev[i] + jmax)
        blk[OUT.ad, i] = a_d
        w_ax = laws.axle_load(mass[i], cn["n_ax"])
        blk[OUT.wax, i] = w_ax
        blk[OUT.ftrac, i] = laws.traction_demand_force(a_d, meff[i], f_max,
                                                       w_ax * cn["trac_adh"])
        f_bdem = laws.brake_demand_force(a_d, meff[i])
        blk[OUT.fbdem, i] = f_bdem
        f_e = laws.electric_brake_share(f_bdem, blk[OUT.ebr, i])
        if ebm:
            f_e = 0.0
        blk[OUT.fe, i] = f_e
        f_f = f_bdem - f_e
        blk[OUT.ff, i] = f_f
        f_fa = f_f * cn["inv_nax"]
        blk[OUT.ffa, i] = f_fa
        if (f_e * cn["inv_nmot"] + f_fa > laws.adhesion_limit(cn["mu_pk"], w_ax)
                or f_fa * slide_ratio[i] > w_ax):
            fast = False
        blk[OUT.fbrk, i] = f_e + f_fa * fric_mult[i]
    return n_int, any_atp, any_viol, gmin, n_civil, fast


@njit(cache=True)
def axle_fill(cn, f_fa, a_d, w_axle, axc, stab, out):  # type: ignore[no-untyped-def]
    """(F_x, clamp force, slip) of the instrumented axles into ``out`` [3, n, 4].

    :meth:`.braking.AxleState.get` (quasi-static rolling); ``axc`` = (F_x per clamp N,
    1 / r_w^2, adhesion factor) [3, n, 4]; ``stab`` = adhesion table (mu, slip); ``cn``: a
    :data:`CONSTANTS` record.
    """
    n, m = axc.shape[1], axc.shape[2]
    fc_per_n, jw = cn["fc_per_n"], cn["jw"]
    tab_mu, tab_slip = stab[0], stab[1]
    for i in range(n):
        fci = f_fa[i] * fc_per_n
        ja = jw * _mn(a_d[i], 0.0)
        q_prev = math.nan
        s_prev = 0.0
        for a in range(m):
            out[1, i, a] = fci
            f = fci * axc[0, i, a] + ja * axc[1, i, a]
            out[0, i, a] = f
            q = f / (w_axle[i] * axc[2, i, a])
            if q != q_prev:  # healthy axles of a car share the argument: one look-up
                s_prev = interp1(q, tab_mu, tab_slip)
                q_prev = q
            out[2, i, a] = s_prev
