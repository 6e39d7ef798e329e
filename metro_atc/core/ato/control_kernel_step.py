"""The compiled per-train control step: caps, speed dip, tracker command and guard.

:func:`control_step` over the vectors of :mod:`metro_atc.core.ato.control_kernel` (the
module docstring there: what it covers, what the caller validates, how it keeps its
floats).  Line vector: ``[n_sbi, n_grades, n_stations, n_tsrs]``, then the
static SBI table, the grade starts [m], the grades [-], the stop points [m] and the TSRs as
the ATO knows them (start [m], end [m], limit [m/s], known from [s], until [s] each).
"""

from __future__ import annotations

import math

from metro_atc.core.ato.control_kernel import (
    APPROACH_MIN, AUTH_MARGIN, BERTH, CONSTANTS, GUARD_GAIN, GUARD_SLACK, HOLD_BRAKE, JOIN_BAND,
    JOIN_MIN, LOOKAHEAD, N_PH, PLAN, PREVIEW, R_ENVELOPE, R_FAULT, R_OVERSHOOT, R_PSS,
    R_STOPPED, R_TRACKING, RESTART_MAX, SAFE_BRAKE, SPEED_MARGIN, STATE, STOP_GUARD,
    TRACKER_FUZZY, TRACKER_PI, approach_bound, atp_traction, bisect_right, brake_onset_bound,
    ceiling_e, cpow, feedforward, grade_force, pmax, pmin, resistance, speed_at,
    stop_bound, train_traction)
from metro_atc.core.ato.step_kernel import jit
from metro_atc.core.ato.tracker_laws import fuzzy_inputs, fuzzy_law, pi_law, tracker_state
from metro_atc.core.laws import braking_speed, ebi_speed_from, guaranteed_decel_on_grade

N_LH = 4
"""Line vector header length."""
N_TSR = 5
"""Floats per TSR in the line vector (start, end, limit, known from, until)."""


@jit
def plan_decel(ph, p, x):  # type: ignore[no-untyped-def]
    """Planned braking deceleration at chainage x [m/s^2].

    The lowest planned deceleration over [s - 50, s + 400] m of the run (the table packed
    by ``OnboardAto``, 10 m grid), clamped at both ends.
    """
    nb = int(ph.n_brake)
    bo = N_PH + 2 * int(ph.n_ref) + 2 * int(ph.n_grade) + 2 * int(ph.n_env)
    i = int((ph.direction * (x - ph.x0) + 50.0) / 10.0)
    return p[bo + (0 if i < 0 else (i if i < nb else nb - 1))]


@jit
def tsr_offset(ln):  # type: ignore[no-untyped-def]
    """Index of the first TSR in the line vector."""
    return N_LH + int(ln[0]) + 2 * int(ln[1]) + int(ln[2])


@jit
def tsr_known(ln, o, t):  # type: ignore[no-untyped-def]
    """The TSR at ``ln[o:]`` is known and not yet ended at time t [s]."""
    return ln[o + 3] <= t < ln[o + 4]


@jit
def sbi_speed_to(c, dist, target):  # type: ignore[no-untyped-def]
    """Static SBI speed [m/s] ``dist`` [m] before a point where the limit is ``target``.

    The plant's static construction (:mod:`metro_atc.core.line.track`): braking envelope
    ``E^2 = (target + tol)^2 + 2 b_g D`` evaluated past the response and SBI look-ahead
    distances, ``v + a_w(v) t_r = E`` (one fixed-point step), less the SBI offset.
    """
    d = pmax(dist - c.resp_dist - c.sbi_dist, 0.0)
    e = math.sqrt(cpow(target + c.tol, 2.0) + 2.0 * c.b_g * d)
    vv = e - (atp_traction(c, e) + c.g_down) * c.t_r
    vv = e - (atp_traction(c, pmax(vv, 0.0)) + c.g_down) * c.t_r
    return vv - c.sbi_offset


@jit
def sbi_speed_of(cr, dist, target):  # type: ignore[no-untyped-def]
    """:func:`sbi_speed_to` over a constants vector (``AtpModel.sbi_speed_to``) [m/s]."""
    return sbi_speed_to(cr.view(CONSTANTS)[0], dist, target)


@jit
def cap_at(c, ph, p, ln, x, v, cap, ma, c0, c2, authority, t):  # type: ignore[no-untyped-def]
    """Ceiling on the desired speed at chainage x [m] from the ATP data and known TSRs [m/s].

    ``cap``: the supervision cap (the ATP's EBI speed of the state less the SBI offset and
    ``SPEED_MARGIN``; inf when unknown); the lowest static SBI speed over the distance run
    in ``LOOKAHEAD`` less ``SPEED_MARGIN``; with ``authority``, the end of movement
    authority ``ma``: a braking curve at the planned deceleration to a stop
    ``AUTH_MARGIN`` short of it and the speed whose SBI distance fits in it (``c0``, ``c2``:
    the ATP curve's terms at v); every TSR known at t [s] and not yet cleared by the rear:
    a braking curve at the planned deceleration reaching ``limit - margin`` ``lead`` metres
    before the zone and the zone's SBI curve.  Never below 0.
    """
    n = int(ln[0])
    x0, dx = c.grid_x0, c.grid_dx
    k0 = int((x - x0) / dx)
    k1 = int((x + v * LOOKAHEAD + 1.0 - x0) / dx) + 1
    k0 = 0 if k0 < 0 else (k0 if k0 < n else n - 1)
    k1 = k0 + 1 if k1 < k0 + 1 else (k1 if k1 < n else n)
    m = ln[N_LH + k0]
    for k in range(k0 + 1, k1):
        if ln[N_LH + k] < m:
            m = ln[N_LH + k]
    cc = m - c.sbi_offset - SPEED_MARGIN
    if cc < cap:
        cap = cc
    b = plan_decel(ph, p, x)
    if authority and math.isfinite(ma):
        d = ma - x - AUTH_MARGIN
        cc = braking_speed(d, b)
        if cc < cap:
            cap = cc
        cc = ebi_speed_from(c0, c.two_b, c2, d - c.t_sbi * v) - c.sbi_offset - SPEED_MARGIN
        if cc < cap:
            cap = cc
    zo = tsr_offset(ln)
    rear = x - c.length
    for k in range(int(ln[3])):
        o = zo + N_TSR * k
        if not tsr_known(ln, o, t) or rear >= ln[o + 1]:
            continue
        limit = ln[o + 2]
        lim = pmax(limit - c.margin, 0.5 * limit)
        d = ln[o] - c.lead - x
        cap = pmin(pmin(cap, math.sqrt(lim * lim + 2.0 * b * pmax(d, 0.0))),
                   sbi_speed_to(c, ln[o] - x - v * LOOKAHEAD, limit) - SPEED_MARGIN)
    return 0.0 if 0.0 > cap else cap


@jit
def net_accel(c, ph, p, x, v):  # type: ignore[no-untyped-def]
    """Net acceleration [m/s^2] of full traction at chainage x [m] and speed v [m/s].

    Traction less resistance and the grade over the train (Li n.d. Newton's law), at most
    the planning limit ``accel_max``.
    """
    s = ph.direction * (x - ph.x0)
    f = c.mass * train_traction(c, v) - resistance(c, v) - grade_force(c, ph, p, s)
    return pmin(pmax(f / c.meff, 0.0), c.accel_max)


@jit
def tsr_hold(c, ph, p, ln, xp, v, r, dip, x_stop, cap0, ma, c0, c2,
             t):  # type: ignore[no-untyped-def]
    """No traction toward r [m/s] when a known TSR's curve takes the gain back.

    Accelerating from v to r and braking back to v takes ``H = (r^2 - v^2) / (2 a) +
    v swing + (r^2 - v^2) / (2 b)`` metres at the net acceleration a of full traction
    (:func:`net_accel`) and the planned deceleration b.  When the braking curve of a TSR
    ahead falls below v within H of the preview position ``xp`` [m], the gain would be
    braked away before the zone (hunting); the train holds its speed instead.  ``dip``: the
    speed has fallen since its peak; then any TSR ahead before the next stop ``x_stop``
    whose target is below v holds it, whatever the distance.
    """
    if r <= v + JOIN_BAND:
        return False
    zo = tsr_offset(ln)
    nz = int(ln[3])
    if dip:
        for k in range(nz):
            o = zo + N_TSR * k
            if not tsr_known(ln, o, t):
                continue
            limit = ln[o + 2]
            lim = pmax(limit - c.margin, 0.5 * limit)
            if xp < ln[o] - c.lead < x_stop and lim + JOIN_BAND < v:
                return True
    a = net_accel(c, ph, p, xp, v)
    b = plan_decel(ph, p, xp)
    dv2 = r * r - v * v
    reach = v * c.swing + dv2 / (2.0 * b) + (dv2 / (2.0 * a) if a > 1e-3 else math.inf)
    rear = xp - c.length
    for k in range(nz):
        o = zo + N_TSR * k
        if not tsr_known(ln, o, t) or rear >= ln[o + 1]:
            continue
        x_e = pmin(xp + reach, pmax(ln[o] - c.lead, xp))
        if cap_at(c, ph, p, ln, x_e, v, cap0, ma, c0, c2, False, t) < v:
            return True
    return False


@jit
def brake_capability(c, ln, x):  # type: ignore[no-untyped-def]
    """Service deceleration [m/s^2] achievable with the front at x: the steepest downhill.

    Full service brake less the pull of the steepest downhill grade piece under the train
    or within 1 m ahead (every piece from x - length to x + 1 m; resistance neglected:
    conservative), at least 0.05 m/s^2.
    """
    ns, ng = int(ln[0]), int(ln[1])
    so = N_LH + ns
    i0 = min(max(bisect_right(ln, so, ng, x - c.length) - 1, 0), ng - 1)
    i1 = min(max(bisect_right(ln, so, ng, x + 1.0) - 1, 0), ng - 1)
    g = ln[so + ng + i0]
    for i in range(i0 + 1, i1 + 1):
        g = pmin(g, ln[so + ng + i])
    return pmax(guaranteed_decel_on_grade(c.brake_service, -pmin(g, 0.0)), 0.05)


@jit
def set_output(c, u, u_ff, e):  # type: ignore[no-untyped-def]
    """The tracker's state for the applied effort u [-] (its ``set_output``).

    The fuzzy controller keeps the feedback part ``u - u_ff``; the PI controller the
    integral that gives u with its last error e [m/s].
    """
    return tracker_state(c.tracker == TRACKER_PI, u, u_ff, e, c.kp, c.ki)


@jit
def control_step(cr, p, ln, sr, t, x, v, sup, ma, nxt):  # type: ignore[no-untyped-def]
    """One control step: (effort u [-1, 1], reason code); ``sr`` updated.

    cr: the constants (float vector of ``control_kernel.CONSTANTS``); p: the plan vector;
    ln: the line vector; t [s], x [m], v [m/s]: the state, validated by the caller (finite,
    |t| <= 1e15 s, |x| <= 1e12 m, |v| <= 1e6 m/s, t later than the last step's); sup:
    supervision speed [m/s] (inf: unknown), ma: end of authority [m], nxt: the next station
    index of the state; sr: the per-train state (float vector of ``control_kernel.STATE``).
    """
    c = cr.view(CONSTANTS)[0]
    st = sr.view(STATE)[0]
    ph = p[:N_PH].view(PLAN)[0]
    period = c.period
    has_t = st.has_t != 0.0
    dt = period if not has_t else t - st.t
    length = ph.length
    s = ph.direction * (x - ph.x0)
    arrived = st.arrived != 0.0
    b_ach = brake_capability(c, ln, x)
    u_last = st.u
    last_ff = st.ff
    trk_u = st.tu
    # ---- the caps at the preview position
    xp = x + PREVIEW * v * period
    h = pmax(v * period, 0.5)
    a_w = atp_traction(c, v) + c.g_down
    cap0 = math.inf
    if math.isfinite(sup):
        cap0 = sup - c.sbi_offset - SPEED_MARGIN
    c0 = c.c0a + c.btt * a_w
    c2 = c.bt + c.t_r * a_w
    cap_p = cap_at(c, ph, p, ln, xp, v, cap0, ma, c0, c2, True, t)
    if cap_p - v > JOIN_BAND and v > JOIN_MIN and u_last > 0.0:
        xp += v * c.swing
        cap_p = pmin(cap_p, cap_at(c, ph, p, ln, xp, v, cap0, ma, c0, c2, True, t))
    # the speed dip: the peak follows the speed up, and restarts on the envelope
    ns, ng = int(ln[0]), int(ln[1])
    n_st = int(ln[2])
    x_stop = ln[N_LH + ns + 2 * ng + nxt] if 0 <= nxt < n_st else math.inf
    cc = math.sqrt(2.0 * pmax(ceiling_e(ph, p, ph.direction * (x - ph.x0)), 0.0))
    peak = st.peak
    if v >= cc - JOIN_BAND or v > peak:
        peak = v
    # the TSR hold (OnboardAto.control)
    known = False
    zo = tsr_offset(ln)
    for k in range(int(ln[3])):
        if tsr_known(ln, zo + N_TSR * k, t):
            known = True
    hold = False
    if known and v > JOIN_MIN and cap_p > v:
        r_x = speed_at(ph, p, ph.direction * (xp - ph.x0))
        hold = tsr_hold(c, ph, p, ln, xp, v, pmin(cap_p, r_x), v < peak - JOIN_BAND, x_stop,
                        cap0, ma, c0, c2, t)
    held = 0.0
    if hold:
        cap_p = pmin(v, st.held) if st.held > 0.0 else v
        held = cap_p
    cap_h = cap_p if hold else cap_at(c, ph, p, ln, xp + h, v, cap0, ma, c0, c2, True, t)
    slope = (cap_h * cap_h - cap_p * cap_p) / (2.0 * h) \
        if math.isfinite(cap_p) and math.isfinite(cap_h) else 0.0
    # the speed of the end of authority (the train ahead) from the last two states; a
    # moving end scales the cap's slope by (1 - v_ma / v)
    v_ma = st.v_ma
    if st.has_ma == 0.0 or not (math.isfinite(ma) and math.isfinite(st.ma)):
        v_ma = 0.0
    elif 0.0 < t - st.ma_t <= 2.0:
        v_ma = pmax((ma - st.ma) / (t - st.ma_t), 0.0)
    if slope < 0.0 and v_ma > 0.0 and v > 0.0 \
            and cap_p < cap_at(c, ph, p, ln, xp, v, cap0, ma, c0, c2, False, t) - 1e-9:
        slope *= pmin(pmax(1.0 - v_ma / v, 0.0), 1.0)
    # ---- the tracker, its feedforward and bounds, the jerk limit
    vc = pmax(v, 0.0)
    dt = pmin(dt, 5.0 * period)
    has_e = st.has_e != 0.0
    e_prev = st.e
    still = st.still
    if arrived:
        u_trk = HOLD_BRAKE
        reason = R_STOPPED
        u_new_last = HOLD_BRAKE
    elif s > length + 2.0:
        # past the stopping point (more than the 2 m the stop tail may run over): brake
        u_trk = SAFE_BRAKE
        reason = R_OVERSHOOT
        u_new_last = SAFE_BRAKE
    else:
        s_p = s + PREVIEW * vc * period
        r = speed_at(ph, p, s_p)
        r_swing = math.nan
        if r - vc > JOIN_BAND and vc > JOIN_MIN and u_last > 0.0:
            r_swing = speed_at(ph, p, s_p + vc * c.swing)
            r = pmin(r, r_swing)
        r_plan = r
        capped = cap_p < r
        if capped:
            r = pmax(cap_p, 0.0)
        u_ff = feedforward(c, ph, p, s, vc, r, capped, slope) if c.feedforward != 0.0 else 0.0
        e = r - vc
        e_n, d_n = fuzzy_inputs(e, has_e, e_prev, c.e_scale, c.d_scale)
        if not (math.isfinite(e) and math.isfinite(u_ff)
                and (c.tracker == TRACKER_PI or (math.isfinite(e_n) and math.isfinite(d_n)))):
            # a tracker input that is not a number: full service brake, the tracker's state
            # kept (no NaN enters it)
            u_trk = SAFE_BRAKE
            reason = R_FAULT
            u_new_last = SAFE_BRAKE
        else:
            last_ff = u_ff
            has_e, e_prev = True, e
            # the tracker (tracker_laws; trk_u: the PI integral [m] or the fuzzy state)
            if c.tracker == TRACKER_PI:
                u, trk_u = pi_law(trk_u, e, dt, u_ff, c.kp, c.ki)
            else:
                u, trk_u = fuzzy_law(trk_u, e_n, d_n, u_ff, c.gain, c.tracker == TRACKER_FUZZY)
            bounded = False
            if u > 0.0 and vc > APPROACH_MIN:
                if not capped and r_swing != r_swing:
                    r_swing = speed_at(ph, p, s_p + vc * c.swing)
                r_end = r if capped else pmin(pmax(r, r_swing), cap_p)
                u_b = approach_bound(c, ph, p, s, vc, r_end)
                if u_b < u:
                    u, bounded = u_b, True
            if not capped and vc > JOIN_MIN and u_last > -c.brake_share:
                u_b = brake_onset_bound(c, ph, p, s, s_p, vc, r, dt, u_last)
                if u_b < u:
                    u, bounded = u_b, True
            if u > 0.0 and vc < RESTART_MAX and s > 0.5 * length:
                u_b = stop_bound(c, ph, p, s, vc, u_last)
                if u_b < u:
                    u, bounded = u_b, True
            if r_plan <= 0.0 and s >= length - BERTH:
                u = pmin(u, HOLD_BRAKE)
            q = 2.0 * ceiling_e(ph, p, pmin(pmax(s, 0.0), length))
            ceiling = math.sqrt(q) if q >= 0.0 else math.nan
            reason = R_TRACKING
            if s >= ph.pss_start:
                reason = R_PSS
            if vc > ceiling + 1.0 and s < length:
                u = SAFE_BRAKE
                reason = R_ENVELOPE
            du = c.du_max * dt
            u_lim = pmin(pmax(u, u_last - du), u_last + du)
            if (u_lim != u or bounded) and reason != R_ENVELOPE:
                trk_u = set_output(c, u_lim, u_ff, e_prev)
            u = u_lim
            if vc <= 1e-6 and s > length - BERTH:
                still += dt
                if still >= 1.0:
                    arrived = True
                    u = HOLD_BRAKE
                    reason = R_STOPPED
            else:
                still = 0.0
            u_trk = u
            u_new_last = u
    # ---- guard
    bound = 1.0
    bs = c.brake_service
    dd = x_stop - x
    if 0.0 < dd < 400.0 and v > 0.3:
        a_req = v * v / (2.0 * pmax(dd - 0.15, 0.05))
        if a_req > STOP_GUARD * b_ach:
            bound = pmin(bound, -pmin(1.0, (a_req + bs - b_ach) / bs))
    cap = cap_at(c, ph, p, ln, x, v, cap0, ma, c0, c2, True, t)
    over = v - cap - GUARD_SLACK
    if over > 0.0:
        bound = pmin(bound, -pmin(1.0, (bs - b_ach) / bs + GUARD_GAIN * over))
    u = pmin(u_trk, bound)
    if u < u_trk and math.isfinite(u) and u != u_new_last:
        u_new_last = u
        trk_u = set_output(c, u, last_ff, e_prev)
    # ---- write the state back
    st.has_t = 1.0
    st.t = t
    st.u = u_new_last
    st.ff = last_ff
    st.arrived = 1.0 if arrived else 0.0
    st.still = still
    st.has_e = 1.0 if has_e else 0.0
    st.e = e_prev
    st.tu = trk_u
    st.has_ma = 1.0
    st.ma_t = t
    st.ma = ma
    st.v_ma = v_ma
    st.peak = peak
    st.next_stop = x_stop
    st.held = held
    return u, reason
