"""Compiled multi-step run (numba): :func:`.kernel_step.step_all` driven by the reference driver.

:func:`run_rows` repeats what a Python loop of :func:`.driver.simple_driver` +
:meth:`.line.LineSim.step` does between two points that need Python (see
:mod:`.fast_run`), one compiled call for many steps: each step's command is the reference
driver's, computed by the previous step (row ``OUT.drv``); the sample instants are read from
the sensors' laid-out clock and the noise from their normals buffer (both advanced as the
per-step path does).  It stops *before* a step (other than the first, whose discrete
events the caller has done) that starts at or after the next discrete time, the duration
or the caller's limit, whose rail force needs the numpy slide model (the step's in-place
ATP updates are rolled back), or that would run past the laid-out clock, the drawn normals
or the output buffers; and *after* a step with an arrival or overrun candidate (the
station logic is Python's).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .kernel import CONSTANTS, MASS, OUT, _mn
from .kernel_step import BOOLS, DRIVER, FS, INTS, step_all

# why run_rows stopped
(STOP_TIME, STOP_SLOW, STOP_HIT, STOP_CLOCK, STOP_NORMALS, STOP_BUFFER) = range(6)
RESULT_FLOATS = ("t", "gmin")
"""Float results of :func:`run_rows` (:data:`RESULT_F`): the time after the last step [s],
the smallest gap to the obstacle ahead over the steps [m]."""
RESULT_F = np.dtype([(f, np.float64) for f in RESULT_FLOATS])
"""The float results by name (``rf``: a float vector viewed as this record in the kernel)."""
RESULT_INTS = ("steps", "why", "cpos", "zpos", "n_int", "n_civil", "any_atp", "any_viol",
               "samples")
"""Integer results of :func:`run_rows` (:data:`RESULT_I`): steps done, why it stopped
(``STOP_*``), the sensors' next clock position and normals position, new ATP
interventions, train-steps above the civil limit, the last step's ATP and violation flags
(0/1), sample instants computed."""
RESULT_I = np.dtype([(f, np.int64) for f in RESULT_INTS])
"""The integer results by name (``ri``: an int64 vector viewed as this record)."""


@njit(cache=True)
def run_rows(c, tabs, geo, stab, dcs, fs, ints, bools, grids, axc, blk0, blks, u0, axs,
             r_w, sidx, slip0, clock, zbuf, o4, o2, any_slide: bool, any_wsp: bool,
             auto: bool, sensed: bool, samples: bool, t0: float, t_next: float,
             t_dur: float, t_limit: float, cpos: int, zpos: int, tk, rf,
             ri):  # type: ignore[no-untyped-def]
    """Up to ``blks.shape[0]`` steps from time ``t0`` (see module doc); results in ``rf``/``ri``.

    ``blks[k]``: output block of step k (``blk0``: the one before); ``u0``: the first
    step's command; ``axs``: two axle buffers [2, 3, n, 4] used in turn (no rows: axles and
    samples not computed); ``slip0``: the axle slips of the step before ``t0``; ``clock``:
    the sample instants laid out, ``clock[cpos]`` the next one (``sensed``: an instrumented
    train runs); ``zbuf[zpos:]``: the normals drawn ahead; ``o4`` / ``o2``: the samples of
    all steps one after the other along their sample axis (``samples``: compute them).
    ``t_next`` / ``t_dur`` / ``t_limit``: next discrete time (the first step's discrete
    events are done), duration, caller's limit [s]; ``tk[k]``: the time at the end of step k;
    ``rf`` / ``ri``: a float / an int64 vector of :data:`RESULT_F` / :data:`RESULT_I`'s size.
    """
    cn = c.view(CONSTANTS)[0]
    dt = cn["dt"]
    m, na = sidx.shape[0], axc.shape[2]
    last = clock.shape[0] - 1
    cap = o4.shape[1]
    noise = cn["noise"]
    dr, dr_auto = dcs[0].view(DRIVER)[0], dcs[1].view(DRIVER)[0]
    eb, sb, inv = bools[BOOLS.eb], bools[BOOLS.sb], bools[BOOLS.in_violation]
    interv, viol, code = ints[INTS.interventions], ints[INTS.violations], fs[FS.speed_code]
    save_b = eb.copy()
    save_s, save_v, save_i = sb.copy(), inv.copy(), interv.copy()
    save_w, save_c = viol.copy(), code.copy()
    t = t0
    prev = blk0
    u = u0
    sl = slip0
    s_off = 0
    k = 0
    why = STOP_BUFFER
    n_int, n_civil, gmin = 0, 0, math.inf
    any_atp, any_viol = False, False
    while k < blks.shape[0]:
        if (k and t >= t_next - 1e-9) or t >= t_dur - 1e-9 or not t < t_limit:
            why = STOP_TIME
            break
        t1 = t + dt
        end = cpos
        if sensed and clock[cpos] <= t1 + 1e-9:
            while clock[end] <= t1 + 1e-9 and end < last:
                end += 1
            if end == last:
                why = STOP_CLOCK
                break
        ns = end - cpos
        n_s = ns if samples else 0
        if n_s and zpos + (2 * na + 2) * n_s * m > zbuf.shape[0]:
            why = STOP_NORMALS
            break
        if s_off + n_s > cap:
            why = STOP_BUFFER
            break
        save_b[:] = eb
        save_s[:] = sb
        save_v[:] = inv
        save_i[:] = interv
        save_w[:] = viol
        save_c[:] = code
        blk = blks[k]
        ax_out = axs[k % 2]
        r = step_all(
            cn, prev[OUT.x1], prev[OUT.v1], ints[INTS.status], bools[BOOLS.run:], u,
            prev[OUT.u], fs[FS.auto], prev[OUT.ad], fs[FS.mass:FS.mass + len(MASS)],
            fs[FS.trac_level], eb, sb, interv, viol, inv, grids, tabs, code,
            fs[FS.slide_ratio:FS.fric_mult + 1], any_slide, any_wsp, blk, geo, fs[FS.stop_x],
            fs[FS.e_trac], fs[FS.e_elec], fs[FS.e_fric], fs[FS.e_res], fs[FS.e_curve],
            fs[FS.e_grade], fs[FS.e_stop_corr], ints[INTS.n_in_service], axc, stab, ax_out, dr,
            True, sidx, r_w, sl, clock[cpos:end], t, t1, zbuf, zpos, noise,
            o4[:, s_off:s_off + n_s], o2[:, s_off:s_off + n_s], auto, prev[OUT.eoa], dr_auto,
            fs[FS.eoa_ext])
        if r[5] < 0:  # the numpy slide model: undo the step's ATP updates, Python steps
            eb[:] = save_b
            sb[:] = save_s
            inv[:] = save_v
            interv[:] = save_i
            viol[:] = save_w
            code[:] = save_c
            why = STOP_SLOW
            break
        n_int += r[0]
        any_atp, any_viol = r[1], r[2]
        gmin = _mn(gmin, r[3])
        n_civil += r[4]
        if ax_out.shape[1]:
            sl = ax_out[2]
        zpos += (2 * na + 2) * n_s * m
        s_off += n_s
        cpos = end
        t = t1
        prev = blk
        u = blk[OUT.drv]
        tk[k] = t
        k += 1
        if r[5] > 0:
            why = STOP_HIT
            break
    res_f, res_i = rf.view(RESULT_F)[0], ri.view(RESULT_I)[0]
    res_f["t"], res_f["gmin"] = t, gmin
    res_i["steps"], res_i["why"], res_i["cpos"], res_i["zpos"] = k, why, cpos, zpos
    res_i["n_int"], res_i["n_civil"] = n_int, n_civil
    res_i["any_atp"], res_i["any_viol"] = any_atp, any_viol
    res_i["samples"] = s_off
