"""The per-train ATO control step compiled with numba: the same floats as the Python path.

:func:`control_step` is :meth:`metro_atc.core.ato.onboard.OnboardAto.control` after its
planning part (the caps of ``_cap_at`` at the preview position, ``_speed_dip``,
``_authority_speed``, :meth:`AtoCore.command_ex` with the fuzzy tracker, its feedforward and
bounds, and ``guard``) for the common case: a plan, the fuzzy tracker on a scalar state, no
TSR known, the static SBI table, a fresh state with a later time stamp, the train not past
its stopping point (issue 13, graph speed).  Every operation is written in the Python path's
order with its builtins' semantics (``min``/``max`` as CPython picks, :func:`pmin` /
:func:`pmax`; ``x ** 2`` and ``x ** 3`` as the C ``pow`` CPython calls, the exponent read from
the constants so that LLVM cannot fold it into products; ``int()`` truncation of finite
values only).  Compiled with ``cache=True`` and numba's numpy error model (IEEE results
instead of exceptions: the Python path's divisions never divide by zero on the states the
kernel takes).

The kernel reads the per-train state from a float vector (``S_*``), works on local copies and
writes them back only when it finished: a state it cannot take (``FALLBACK``) leaves
everything untouched and the caller runs the Python path, so the hand-over in both
directions is the Python objects' own state.  Plan tables travel as one vector (``P_*``
header, :mod:`metro_atc.core.ato.control_kernel_pack`), line tables as another, the train,
ATP and controller constants as a third (``C_*``).  Proven equal (``==``) to the Python path
on generated lines in ``test/test_ato_control_kernel.py``.
"""

from __future__ import annotations

import math

from metro_atc.core.ato.step_kernel import jit

(C_MASS, C_MEFF, C_DA, C_DB, C_DC, C_A1, C_V1, C_V2, C_A2, C_A3, C_B2, C_B3, C_BS, C_LEN,
 C_WA1, C_WV1, C_WV2, C_WA2, C_WA3, C_WB2, C_WB3, C_GDOWN, C_OFF, C_C0A, C_BT, C_BTT,
 C_TR, C_TWOB, C_TSBI, C_GX0, C_GDX, C_PERIOD, C_SWING, C_DUMAX, C_BSHARE, C_AJERK,
 C_FF, C_ESC, C_DSC, C_GAIN, C_TWO, C_THREE, N_C) = range(43)
"""Constants vector: train, the ATP's train (worst-case response), ATP, controller."""

(P_X0, P_DIR, P_LEN, P_PSS, P_TAILB, P_RLEN, P_DEP, P_SC, P_SB, P_CV2, P_D2, P_B2, P_CV,
 P_NREF, P_NGBP, P_NENV, P_NB, N_PH) = range(18)
"""Plan header; then ref s, ref v^2, grade breakpoints, grade-force integral, envelope s,
ceiling energy, planned-deceleration table (``P_N*`` long each)."""

(S_HAS_T, S_T, S_U, S_FF, S_ARR, S_STILL, S_HAS_E, S_E, S_TU, S_HAS_MA, S_MA_T, S_MA,
 S_VMA, S_PEAK, S_NSTOP, S_HELD, N_S) = range(17)
"""Per-train state vector (flags as 0/1)."""

FALLBACK = -1
"""Reason code: the kernel did not take the state (nothing changed; run the Python path)."""
R_TRACKING, R_PSS, R_ENVELOPE, R_STOPPED = 0, 1, 2, 3
"""Reason codes of :attr:`AtoCore.last_reason` (``REASONS``)."""
REASONS = ("tracking", "programmed station stopping", "above the speed envelope",
           "stopped at platform")

HOLD_BRAKE = -0.5
SAFE_BRAKE = -1.0
JOIN_BAND = 0.3
JOIN_MIN = 3.0
PREVIEW = 1.0
APPROACH_MIN = 1.0
RESTART_MAX = 3.0
BERTH = 0.3
STOP_FF = 0.5
LOOKAHEAD = 2.0
SPEED_MARGIN = 0.5
AUTH_MARGIN = 10.0
STOP_GUARD = 0.85
GUARD_GAIN = 0.8
GUARD_SLACK = 0.3
G = 9.80665


def _rules() -> tuple[float, ...]:
    from metro_atc.core.ato.fuzzy import RULE_MATRIX
    return tuple(float(x) for x in RULE_MATRIX.ravel())


RULES = _rules()
R0, R1, R2, R3, R4, R5, R6, R7, R8, R9, R10, R11, R12, R13, R14 = RULES


@jit
def pmin(a, b):  # type: ignore[no-untyped-def]
    """CPython ``min(a, b)``: ``b`` only when ``b < a``."""
    return b if b < a else a


@jit
def pmax(a, b):  # type: ignore[no-untyped-def]
    """CPython ``max(a, b)``: ``b`` only when ``b > a``."""
    return b if b > a else a


@jit
def clip1(x, lo, hi):  # type: ignore[no-untyped-def]
    """:func:`metro_atc.core.scalar_math.clip1`."""
    if x < lo:
        x = lo
    if x > hi:
        x = hi
    return x


@jit
def bisect_right(a, lo, n, x):  # type: ignore[no-untyped-def]
    """``bisect.bisect_right`` over ``a[lo:lo + n]`` (index relative to lo)."""
    i, j = 0, n
    while i < j:
        m = (i + j) // 2
        if x < a[lo + m]:
            j = m
        else:
            i = m + 1
    return i


@jit
def interp1(x, a, xo, fo, n):  # type: ignore[no-untyped-def]
    """:func:`metro_atc.core.scalar_math.interp1` over ``a[xo:xo+n]``, ``a[fo:fo+n]``."""
    if x != x:
        return x
    j = bisect_right(a, xo, n, x) - 1
    if j < 0:
        return a[fo]
    if j >= n - 1:
        return a[fo + n - 1]
    x0 = a[xo + j]
    if x0 == x:
        return a[fo + j]
    y0, y1 = a[fo + j], a[fo + j + 1]
    slope = (y1 - y0) / (a[xo + j + 1] - x0)
    out = slope * (x - x0) + y0
    if out != out:
        out = slope * (x - a[xo + j + 1]) + y1
        if out != out and y0 == y1:
            out = y0
    return out


@jit
def traction_accel(c, k, v):  # type: ignore[no-untyped-def]
    """``max_traction_accel_at`` with the traction constants at ``c[k:k+7]`` [m/s^2]."""
    va = abs(v)
    if va <= c[k + 1]:
        return c[k]
    if va <= c[k + 2]:
        return c[k + 3] / (va + c[k + 5] + 1e-12)
    return c[k + 4] / math.pow(va + c[k + 6] + 1e-12, c[C_TWO])


@jit
def resistance(c, v):  # type: ignore[no-untyped-def]
    """``resistance_force_at`` [N]."""
    va = abs(v)
    return c[C_DA] + c[C_DB] * va + c[C_DC] * va * va


@jit
def speed_at(p, s):  # type: ignore[no-untyped-def]
    """``ProfileReference.speed_at`` (finite s) [m/s]."""
    n = int(p[P_NREF])
    xo = N_PH
    fo = xo + n
    j = bisect_right(p, xo, n, s) - 1
    if j < 0:
        e = p[fo]
    elif j >= n - 1:
        e = p[fo + n - 1]
    else:
        x0 = p[xo + j]
        if x0 == s:
            e = p[fo + j]
        else:
            y0, y1 = p[fo + j], p[fo + j + 1]
            e = (y1 - y0) / (p[xo + j + 1] - x0) * (s - x0) + y0
            if e != e:
                e = interp1(s, p, xo, fo, n)
    plan = math.sqrt(e) if e >= 0.0 else math.nan
    length = p[P_RLEN]
    if s < 0.5 * length:
        dep = p[P_DEP]
        if not (plan != plan or plan >= dep):
            plan = dep
    if s < p[P_SC]:
        m = p[P_SC] - s
        tail = math.sqrt(p[P_CV2] + p[P_D2] * (m if m != m or m >= 0.0 else 0.0))
    elif s < p[P_SB]:
        tail = p[P_CV]
    else:
        m = length - s
        tail = math.sqrt(p[P_B2] * (m if m != m or m >= 0.0 else 0.0))
    if s >= length:
        return 0.0
    return plan if plan != plan or plan <= tail else tail


@jit
def grade_force(c, p, s):  # type: ignore[no-untyped-def]
    """``RunModel.mean_grade_force_at(s - train length, s)`` (non-degenerate) [N]."""
    s0 = s - c[C_LEN]
    nr = int(p[P_NREF])
    n = int(p[P_NGBP])
    xo = N_PH + 2 * nr
    length = p[P_LEN]
    a = clip1(s, 0.0, length)
    b = clip1(s0, 0.0, length)
    i1 = interp1(a, p, xo, xo + n, n)
    i0 = interp1(b, p, xo, xo + n, n)
    return (i1 - i0) / (s - s0)


@jit
def ceiling_e(p, s):  # type: ignore[no-untyped-def]
    """``RunModel.ceiling_e_at`` [m^2/s^2]."""
    nr, ng, ne = int(p[P_NREF]), int(p[P_NGBP]), int(p[P_NENV])
    xo = N_PH + 2 * nr + 2 * ng
    return interp1(s, p, xo, xo + ne, ne)


@jit
def as_effort(c, f, v):  # type: ignore[no-untyped-def]
    """A force [N] as the effort the plant applies (traction or service-brake scale)."""
    if f >= 0.0:
        return pmin(f / pmax(c[C_MASS] * traction_accel(c, C_A1, v), 1.0), 1.0)
    return pmax(f / (c[C_MEFF] * c[C_BS]), -1.0)


@jit
def feedforward(c, p, s, v, r, has_cap, a_cap):  # type: ignore[no-untyped-def]
    """``AtoCore._feedforward`` (``has_cap``: a_cap given, not None)."""
    a_ref = a_cap if has_cap and math.isfinite(a_cap) else 0.0
    if (not has_cap) and r > 0.0:
        h = pmax(v * c[C_PERIOD], 0.5)
        r1 = speed_at(p, s + h)
        a_ref = (r1 * r1 - r * r) / (2.0 * h)
    f = c[C_MEFF] * a_ref + resistance(c, v) + grade_force(c, p, s)
    if r < STOP_FF:
        f = pmin(f, 0.0)
    return as_effort(c, f, v)


@jit
def approach_bound(c, p, s, v, r_end):  # type: ignore[no-untyped-def]
    """``AtoCore.approach_bound``."""
    j, t = c[C_AJERK], c[C_PERIOD]
    gap = pmax(r_end - v, 0.0)
    a_ex = j * (-t + math.sqrt(t * t + 2.0 * gap / j))
    f = resistance(c, v) + grade_force(c, p, s) + c[C_MEFF] * a_ex
    return as_effort(c, f, v)


@jit
def brake_onset_bound(c, p, s, s_p, v, r, dt, u0):  # type: ignore[no-untyped-def]
    """``AtoCore.brake_onset_bound`` (u0: the last effort)."""
    rho = c[C_DUMAX]
    h = pmax(v * c[C_PERIOD], 0.5)
    tau = (c[C_BSHARE] + u0) / rho
    u_c = u0
    r_a = r
    for _ in range(2):
        s_a = s_p + 0.5 * v * tau
        r_a = speed_at(p, s_a)
        r_h = speed_at(p, s_a + h)
        # _braking_needed(s, v, r_a, r_h, h) (h > 0)
        a_ref = (r_a * r_a - r_h * r_h) / (2.0 * h)
        a_coast = (resistance(c, v) + grade_force(c, p, s)) / c[C_MEFF]
        if not a_ref > a_coast:
            return 1.0
        u_c = feedforward(c, p, s, v, r_a, True, (r_h * r_h - r_a * r_a) / (2.0 * h))
        tau = pmax(u0 - u_c, 0.0) / rho
        if tau <= 0.0:
            return 1.0
    if v < r_a:
        return 1.0
    return pmax(u_c, u0 - rho * dt)


@jit
def stop_distance(c, p, v, a):  # type: ignore[no-untyped-def]
    """``AtoCore.stop_distance`` [m]."""
    j, t, b = c[C_AJERK], c[C_PERIOD], pmax(p[P_TAILB], 0.05)
    v0 = v + a * t
    x0 = v * t + 0.5 * a * t * t
    tau = (a + b) / j
    v1 = v0 + a * tau - 0.5 * j * tau * tau
    if v1 <= 0.0:
        ts = (a + math.sqrt(a * a + 2.0 * j * v0)) / j
        return x0 + v0 * ts + 0.5 * a * ts * ts - j * math.pow(ts, c[C_THREE]) / 6.0
    return x0 + v0 * tau + 0.5 * a * tau * tau - j * math.pow(tau, c[C_THREE]) / 6.0 \
        + v1 * v1 / (2.0 * b)


@jit
def stop_bound(c, p, s, v, u_last):  # type: ignore[no-untyped-def]
    """``AtoCore.stop_bound``."""
    d = p[P_LEN] - s
    meff = c[C_MEFF]
    f_hold = resistance(c, v) + grade_force(c, p, s)
    f_max = pmax(c[C_MASS] * traction_accel(c, C_A1, v), 1.0)
    a_hi = pmax((f_max - f_hold) / meff, 0.0)
    a_last = pmax((u_last * f_max - f_hold) / meff, 0.0) if u_last > 0.0 else 0.0
    if stop_distance(c, p, v, a_last) >= d:
        return 0.0
    if stop_distance(c, p, v, a_hi) <= d:
        return 1.0
    lo, hi = 0.0, a_hi
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        if stop_distance(c, p, v, pmax(mid, a_last)) <= d:
            lo = mid
        else:
            hi = mid
    return pmin(pmax((f_hold + meff * lo) / f_max, 0.0), 1.0)


@jit
def clip01(m):  # type: ignore[no-untyped-def]
    """The membership clip of ``flc_output_at``."""
    return 0.0 if m < 0.0 else (1.0 if m > 1.0 else m)


@jit
def flc(e_n, d_n):  # type: ignore[no-untyped-def]
    """:func:`metro_atc.core.ato.fuzzy.flc_output_at` (finite inputs)."""
    e0 = clip01((e_n - 0.5) / 0.5)
    up, dn = (e_n - 0.0) / 0.5, (1.0 - e_n) / 0.5
    e1 = clip01(up if up <= dn else dn)
    up, dn = (e_n - -0.5) / 0.5, (0.5 - e_n) / 0.5
    e2 = clip01(up if up <= dn else dn)
    up, dn = (e_n - -1.0) / 0.5, (0.0 - e_n) / 0.5
    e3 = clip01(up if up <= dn else dn)
    e4 = clip01((-0.5 - e_n) / 0.5)
    d0 = clip01((d_n - 0.0) / 1.0)
    up, dn = (d_n - -1.0) / 1.0, (1.0 - d_n) / 1.0
    d1 = clip01(up if up <= dn else dn)
    d2 = clip01((0.0 - d_n) / 1.0)
    w0, w1, w2, w3, w4 = d0 * e0, d0 * e1, d0 * e2, d0 * e3, d0 * e4
    w5, w6, w7, w8, w9 = d1 * e0, d1 * e1, d1 * e2, d1 * e3, d1 * e4
    w10, w11, w12, w13, w14 = d2 * e0, d2 * e1, d2 * e2, d2 * e3, d2 * e4
    den = ((w0 + w1) + (w2 + w3)) + ((w4 + w5) + (w6 + w7))
    den = den + w8 + w9 + w10 + w11 + w12 + w13 + w14
    num = ((w0 * R0 + w1 * R1) + (w2 * R2 + w3 * R3)) \
        + ((w4 * R4 + w5 * R5) + (w6 * R6 + w7 * R7))
    num = num + w8 * R8 + w9 * R9 + w10 * R10 + w11 * R11 + w12 * R12 \
        + w13 * R13 + w14 * R14
    return num / (den if den >= 1e-12 else 1e-12)
