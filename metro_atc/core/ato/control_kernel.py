"""The per-train ATO control step compiled with numba: the one source of the control law.

:func:`metro_atc.core.ato.control_kernel_step.control_step` is everything
:meth:`metro_atc.core.ato.onboard.OnboardAto.control` does after its planning: the caps at
the preview position (supervision speed, static SBI table, end of movement authority, the
TSRs known), the speed dip and the TSR hold, the authority speed, the tracker command (the
incremental or the absolute fuzzy controller, or the PI controller, whose laws are
:mod:`metro_atc.core.ato.tracker_laws`) with its feedforward,
approach, brake-onset and stop bounds, the envelope and overshoot brakes, the jerk limit and
the guard.  There is no other copy: ``NUMBA_DISABLE_JIT=1`` runs this same source as Python
(debugging).  The caller validates the state first (finite, bounded time, position and
speed; time strictly after the last step's) and answers a train with no plan itself.

Every operation keeps the float semantics of CPython builtins (``min``/``max`` as CPython
picks, :func:`pmin` / :func:`pmax`; ``x ** 2`` and ``x ** 3`` as the C ``pow`` CPython calls,
the exponent read from the constants so that LLVM cannot fold it into products; ``int()``
truncation of finite values only), so that NUMBA_DISABLE_JIT=1 gives the compiled floats.
Compiled with ``cache=True`` and numba's numpy error model (IEEE results instead of
exceptions).

The kernel reads the per-train state as a record (:data:`STATE`), works on local copies and
writes them back when it finished.  Plan tables travel as one vector (``PLAN`` header,
:mod:`metro_atc.core.ato.control_kernel_pack`), line tables as another, the train, ATP and
controller constants as a record (:data:`CONSTANTS`).
"""

from __future__ import annotations

import math

import ctypes
from typing import Any

import numpy as np

from metro_atc.core.ato.step_kernel import jit
from metro_atc.core import laws
from metro_atc.core.laws import davis_resistance

_POW = "powf64" if hasattr(ctypes.CDLL(None), "powf64") else "pow"
"""The C library's pow under a name the compiler does not rewrite (glibc's alias of pow).

LLVM turns a call of ``pow`` (or ``math.pow``) with the constant exponent 2 into a product,
which differs from CPython's ``x ** 2`` (the C ``pow``) in the last bit for about one square
in a thousand; the alias keeps the call.  Without it (not glibc) ``pow`` is called.
"""


def _cpow_intrinsic() -> Any:
    """:func:`cpow`: a numba intrinsic calling the C ``pow``.

    ``x ** y`` in Python when ``NUMBA_DISABLE_JIT=1`` runs the kernels as Python.
    """
    from numba.core import config
    if config.DISABLE_JIT:  # type: ignore[attr-defined]
        return lambda x, y: x ** y
    from llvmlite import ir
    from numba import types
    from numba.extending import intrinsic

    @intrinsic  # type: ignore[misc]
    def cpow(typingctx, x, y):  # type: ignore[no-untyped-def]
        """CPython's float ``x ** y``: the C library's ``pow``, bit for bit."""
        def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
            fnty = ir.FunctionType(ir.DoubleType(), [ir.DoubleType(), ir.DoubleType()])
            fn = builder.module.globals.get(_POW)
            if fn is None:
                fn = ir.Function(builder.module, fnty, name=_POW)
            return builder.call(fn, args)
        return types.float64(types.float64, types.float64), codegen
    return cpow


cpow = _cpow_intrinsic()
"""CPython's float ``x ** y`` in compiled code (the C ``pow``, never folded into products)."""

CONSTANT_FIELDS = (
    "mass", "meff", "davis_a", "davis_b", "davis_c",
    "a1", "v1", "v2", "a2", "a3", "b2", "b3", "brake_service", "length",
    "w_a1", "w_v1", "w_v2", "w_a2", "w_a3", "w_b2", "w_b3",
    "g_down", "sbi_offset", "c0a", "bt", "btt", "t_r", "two_b", "t_sbi", "grid_x0",
    "grid_dx", "tol", "resp_dist", "sbi_dist", "b_g",
    "period", "swing", "du_max", "brake_share", "approach_jerk", "feedforward", "e_scale",
    "d_scale", "gain", "tracker", "kp", "ki", "lead", "margin", "accel_max")
"""Constants record (:data:`CONSTANTS`), every field float64.

Train: mass, effective mass [kg], Davis a [N], b [N s/m], c [N s^2/m^2], the traction
curve (a1 [m/s^2], v1, v2 [m/s], a2 [m^2/s^3], a3 [m^3/s^4], b2, b3 [m/s]; Lin 2013,
eq. 3-5), the service brake [m/s^2] and the length [m]; ``w_*``: the traction curve of the
ATP's train (worst-case response); ATP: g_down [m/s^2], SBI offset [m/s], (b_g t_r)^2,
b_g t_r, b_g t_r t_r, t_r [s], 2 b_g, t_sbi [s], grid x0 [m], grid dx [m], the ceiling
tolerance [m/s], the response and SBI look-ahead distances [m], b_g [m/s^2]; controller:
period [s], swing [s], effort rate [1/s], brake share [-], approach jerk [m/s^3],
feedforward 0/1, fuzzy e scale [m/s], d scale [m/s], gain [-], the tracker
(:data:`TRACKER_FUZZY`, :data:`TRACKER_PI`, :data:`TRACKER_FUZZY_ABS`), the PI gains kp
[1/(m/s)], ki [1/m],
the restriction lead [m], the speed margin below a TSR [m/s] and the planning
acceleration limit [m/s^2].
"""
CONSTANTS = np.dtype((np.record, [(f, np.float64) for f in CONSTANT_FIELDS]))
"""The constants the kernel reads, by name: it takes a float vector and reads it through
this record view (``c.view(CONSTANTS)[0]``), which costs nothing in compiled code.  A
``np.record`` dtype (as :data:`PLAN` and :data:`STATE`): the element keeps attribute access
when ``NUMBA_DISABLE_JIT=1`` runs the kernel as Python."""

PLAN_FIELDS = ("x0", "direction", "length", "pss_start", "tail_brake", "ref_length",
               "departure_speed", "creep_start", "brake_start", "creep_v2", "two_decel",
               "two_brake", "creep_speed", "n_ref", "n_grade", "n_env", "n_brake")
"""Plan header (:data:`PLAN`): the run's start x [m], direction (+1/-1), length [m], PSS
start [m], tail brake [m/s^2]; the reference's length [m], departure speed [m/s], creep
start [m], brake start [m], creep speed^2, 2 decel, 2 brake, creep speed [m/s]; the table
lengths.  The plan vector holds it, then ref s, ref v^2, grade breakpoints, grade-force
integral, envelope s, ceiling energy and the planned-deceleration table (``n_*`` long
each)."""
PLAN = np.dtype((np.record, [(f, np.float64) for f in PLAN_FIELDS]))
"""The plan header by name: the plan vector's first :data:`N_PH` floats, viewed once per
step as this record (``ph``) and handed with the vector (``p``) to the functions below."""
N_PH = len(PLAN_FIELDS)
"""Length of the plan header in the plan vector."""

CORE_STATE_FIELDS = ("has_t", "t", "u", "ff", "arrived", "still", "has_e", "e", "tu")
"""The part of :data:`STATE` the controller core holds (``AtoCore.kernel_state``)."""
STATE_FIELDS = CORE_STATE_FIELDS + ("has_ma", "ma_t", "ma", "v_ma", "peak", "next_stop",
                                    "held")
"""Per-train state record (:data:`STATE`; flags as 0/1): the last step's time [s], effort,
feedforward, arrival flag, time stood still [s], the tracker's last error [m/s] and
integrated effort (the PI controller's: its last error and its integral [m]), the last
movement authority's time [s] and end [m], the authority speed [m/s], the speed peak
[m/s], the next stop point [m], the held speed [m/s]."""
STATE = np.dtype((np.record, [(f, np.float64) for f in STATE_FIELDS]))
"""The per-train state the kernel reads and updates, by name (a float vector viewed as this
record in compiled code; numpy's record fields are slow from Python, ~1 us each)."""
STATE_INDEX = {f: i for i, f in enumerate(STATE_FIELDS)}
"""Position of each state field in the float vector (the Python side's hand-over)."""

TRACKER_FUZZY, TRACKER_PI, TRACKER_FUZZY_ABS = 0.0, 1.0, 2.0
"""The ``tracker`` constant: the incremental fuzzy controller (Li n.d. as a fuzzy PI), the
PI controller, the fuzzy controller's absolute form (Li n.d., Sec. 2.3)."""
R_TRACKING, R_PSS, R_ENVELOPE, R_STOPPED, R_OVERSHOOT, R_FAULT = 0, 1, 2, 3, 4, 5
"""Reason codes of :attr:`AtoCore.last_reason` (``REASONS``)."""
REASONS = ("tracking", "programmed station stopping", "above the speed envelope",
           "stopped at platform", "overshot the stopping point: full service brake",
           "tracker input not finite: full service brake")

HOLD_BRAKE = -0.5
"""Holding-brake command at the platform (and of a train with no plan at rest) [-]."""
SAFE_BRAKE = -1.0
"""Full service brake: past the stopping point, above the envelope, on a tracker input that
is not a number, a moving train with no plan [-]."""
JOIN_BAND = 0.3
"""Below the reference by more than this [m/s], the tracker aims at the reference where a
swing from full traction to the planned braking would end (no overshoot of a braking
curve joined from below); also the band of the speed dip and of the TSR hold."""
JOIN_MIN = 3.0
"""The join rule applies above this speed only (in the final creep to the stopping point the
reference ahead is zero) [m/s]."""
PREVIEW = 1.0
"""The tracker follows the reference this many control periods ahead of the train (the
effort is held over the next period and the plant limits its rate) [-]."""
APPROACH_MIN = 1.0
"""The approach bound applies above this speed (not in the creep to the stop point) [m/s]."""
RESTART_MAX = 3.0
"""Below this speed the stop bound (:func:`stop_bound`) limits the traction [m/s]."""
BERTH = 0.3
"""A standstill this close to the stopping point is the arrival (+-0.30 m, the
platform-screen-door tolerance); stopped further short, the train creeps on [m]."""
STOP_FF = 0.5
"""Below this desired speed [m/s] the feedforward never commands traction."""
LOOKAHEAD = 2.0
"""The speed cap takes the lowest static SBI speed over the distance run in this time [s]."""
SPEED_MARGIN = 0.5
"""Margin kept below the ATP supervision (intervention) speeds [m/s]."""
AUTH_MARGIN = 10.0
"""Distance the ATO aims to stop short of the end of movement authority [m]."""
STOP_GUARD = 0.85
"""Deceleration needed to stop at the platform, as a share of the achievable service brake,
above which the stopping guard brakes [-]."""
GUARD_GAIN = 0.8
"""Effort per m/s of speed above a guard curve [1/(m/s)]."""
GUARD_SLACK = 0.3
"""The hard guard brakes only when the speed is this far above a cap [m/s] (below it the
tracker follows the cap)."""


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
    """``np.clip`` of one float (x below lo: lo; above hi: hi)."""
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
    """``np.interp(x, a[xo:xo+n], a[fo:fo+n])`` of one float x (numpy's algorithm)."""
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
def train_traction(c, v):  # type: ignore[no-untyped-def]
    """The train's maximum traction acceleration at v [m/s^2]."""
    return laws.traction_accel(v, c.a1, c.v1, c.v2, c.a2, c.a3, c.b2, c.b3)


@jit
def atp_traction(c, v):  # type: ignore[no-untyped-def]
    """The ATP train's (worst-case response) maximum traction acceleration at v [m/s^2]."""
    return laws.traction_accel(v, c.w_a1, c.w_v1, c.w_v2, c.w_a2, c.w_a3, c.w_b2, c.w_b3)


@jit
def resistance(c, v):  # type: ignore[no-untyped-def]
    """Running resistance at v [N]: :func:`metro_atc.core.laws.davis_resistance`."""
    return davis_resistance(v, c.davis_a, c.davis_b, c.davis_c)


@jit
def speed_at(ph, p, s):  # type: ignore[no-untyped-def]
    """The planned reference r [m/s] at run coordinate s [m] (finite s).

    :meth:`metro_atc.core.ato.reference_curve.ProfileReference.speed` at one point: the
    profile's v^2 interpolated (exact for constant-acceleration pieces), at least the
    departure speed in the first half, capped by the stop tail (Li n.d. regions 3-5), 0 at
    and beyond the stop point.
    """
    n = int(ph.n_ref)
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
    length = ph.ref_length
    if s < 0.5 * length:
        dep = ph.departure_speed
        if not (plan != plan or plan >= dep):
            plan = dep
    if s < ph.creep_start:
        m = ph.creep_start - s
        tail = math.sqrt(ph.creep_v2 + ph.two_decel * (m if m != m or m >= 0.0 else 0.0))
    elif s < ph.brake_start:
        tail = ph.creep_speed
    else:
        m = length - s
        tail = math.sqrt(ph.two_brake * (m if m != m or m >= 0.0 else 0.0))
    if s >= length:
        return 0.0
    return plan if plan != plan or plan <= tail else tail


@jit
def grade_force(c, ph, p, s):  # type: ignore[no-untyped-def]
    """Mean grade force [N] over the train, its front at run coordinate s [m].

    ``RunModel.mean_grade_force(s - train length, s)``: the grade-force integral's rise over
    the train length; over a vanishing length (a train shorter than the floats resolve at
    s) the grade force of the piece at s (the integral's slope there).
    """
    s0 = s - c.length
    nr = int(ph.n_ref)
    n = int(ph.n_grade)
    xo = N_PH + 2 * nr
    length = ph.length
    a = clip1(s, 0.0, length)
    if not abs(s - s0) > 1e-12:
        j = bisect_right(p, xo, n, a) - 1
        j = 0 if j < 0 else (j if j < n - 2 else n - 2)
        if n < 2 or not p[xo + j + 1] > p[xo + j]:
            return 0.0
        return (p[xo + n + j + 1] - p[xo + n + j]) / (p[xo + j + 1] - p[xo + j])
    b = clip1(s0, 0.0, length)
    i1 = interp1(a, p, xo, xo + n, n)
    i0 = interp1(b, p, xo, xo + n, n)
    return (i1 - i0) / (s - s0)


@jit
def ceiling_e(ph, p, s):  # type: ignore[no-untyped-def]
    """The run's ceiling energy at run coordinate s [m^2/s^2] (``RunModel.ceiling_e``)."""
    nr, ng, ne = int(ph.n_ref), int(ph.n_grade), int(ph.n_env)
    xo = N_PH + 2 * nr + 2 * ng
    return interp1(s, p, xo, xo + ne, ne)


@jit
def as_effort(c, f, v):  # type: ignore[no-untyped-def]
    """A force [N] as the effort the plant applies (traction or service-brake scale)."""
    if f >= 0.0:
        return pmin(f / pmax(c.mass * train_traction(c, v), 1.0), 1.0)
    return pmax(f / (c.meff * c.brake_service), -1.0)


@jit
def feedforward(c, ph, p, s, v, r, has_cap, a_cap):  # type: ignore[no-untyped-def]
    """Effort [-1, 1] that holds the reference r on the grade (Li n.d. Newton's law).

    ``F = M_eff a_ref + F_r(v) + F_g`` with the grade force averaged over the train length
    behind the front at s and ``a_ref = d(r^2/2)/ds`` of the planned reference (``a_cap``,
    the cap's slope, when an outer cap sets r: ``has_cap``); normalised by the maximum
    tractive force (F > 0) or the service brake ``M_eff b_s`` (F < 0), as the plant applies
    the effort.  Below ``STOP_FF`` no traction (the final stop).
    """
    a_ref = a_cap if has_cap and math.isfinite(a_cap) else 0.0
    if (not has_cap) and r > 0.0:
        h = pmax(v * c.period, 0.5)
        r1 = speed_at(ph, p, s + h)
        a_ref = (r1 * r1 - r * r) / (2.0 * h)
    f = c.meff * a_ref + resistance(c, v) + grade_force(c, ph, p, s)
    if r < STOP_FF:
        f = pmin(f, 0.0)
    return as_effort(c, f, v)


@jit
def approach_bound(c, ph, p, s, v, r_end):  # type: ignore[no-untyped-def]
    """Highest effort [-1, 1] that still reaches ``r_end`` [m/s] from below without overshoot.

    Accelerating toward a speed the train must then hold (a cap or a cruise level), the
    surplus acceleration ``a`` over the holding effort (resistance and grade at s) can only
    be taken off at the approach jerk ``J``, one control period ``T`` after the decision;
    the speed still gained is ``a T + a^2 / (2 J)``.  It must fit in the gap ``r_end - v``:
    ``a = J (-T + sqrt(T^2 + 2 gap / J))``.  The bound is the force ``F_hold + M_eff a`` as
    an effort (traction or service brake scale).
    """
    j, t = c.approach_jerk, c.period
    gap = pmax(r_end - v, 0.0)
    a_ex = j * (-t + math.sqrt(t * t + 2.0 * gap / j))
    f = resistance(c, v) + grade_force(c, ph, p, s) + c.meff * a_ex
    return as_effort(c, f, v)


@jit
def brake_onset_bound(c, ph, p, s, s_p, v, r, dt, u0):  # type: ignore[no-untyped-def]
    """Highest effort [-1, 1] that still joins the plan's braking curve ahead on time.

    The brake builds up at the ATO's effort rate rho (the jerk limit): from the last effort
    u0 to the curve's effort u_c (:func:`feedforward` with the curve's deceleration) a
    linear ramp of tau = (u0 - u_c) / rho, which loses the speed of braking at the curve's
    deceleration for tau / 2 only.  Started when the train reaches the curve's speed
    v tau / 2 ahead of the preview point ``s_p`` [m run coordinate], the ramp ends on the
    curve.  Once the onset is reached the bound keeps ramping, ``rho dt`` per step, down to
    u_c; 1 (no bound) before it, when the curve ahead is not a braking curve (no steeper
    than coasting: resistance and grade at s) or when the effort is already at the curve's.
    """
    rho = c.du_max
    h = pmax(v * c.period, 0.5)
    tau = (c.brake_share + u0) / rho
    u_c = u0
    r_a = r
    for _ in range(2):
        s_a = s_p + 0.5 * v * tau
        r_a = speed_at(ph, p, s_a)
        r_h = speed_at(ph, p, s_a + h)
        # _braking_needed(s, v, r_a, r_h, h) (h > 0)
        a_ref = (r_a * r_a - r_h * r_h) / (2.0 * h)
        a_coast = (resistance(c, v) + grade_force(c, ph, p, s)) / c.meff
        if not a_ref > a_coast:
            return 1.0
        u_c = feedforward(c, ph, p, s, v, r_a, True, (r_h * r_h - r_a * r_a) / (2.0 * h))
        tau = pmax(u0 - u_c, 0.0) / rho
        if tau <= 0.0:
            return 1.0
    if v < r_a:
        return 1.0
    return pmax(u_c, u0 - rho * dt)


@jit
def stop_distance(c, ph, p, v, a):  # type: ignore[no-untyped-def]
    """Distance [m] to rest from speed v [m/s] with the surplus acceleration a [m/s^2].

    The effort is held one control period ``T``, then taken off at the approach jerk ``J``
    down to the gentlest braking of the stop tail ``b``, which then holds to rest:
    ``v T + a T^2/2`` + the jerk-limited ramp + ``v_1^2 / (2 b)``.
    """
    j, t, b = c.approach_jerk, c.period, pmax(ph.tail_brake, 0.05)
    v0 = v + a * t
    x0 = v * t + 0.5 * a * t * t
    tau = (a + b) / j
    v1 = v0 + a * tau - 0.5 * j * tau * tau
    if v1 <= 0.0:
        ts = (a + math.sqrt(a * a + 2.0 * j * v0)) / j
        return x0 + v0 * ts + 0.5 * a * ts * ts - j * cpow(ts, 3.0) / 6.0
    return x0 + v0 * tau + 0.5 * a * tau * tau - j * cpow(tau, 3.0) / 6.0 \
        + v1 * v1 / (2.0 * b)


@jit
def stop_bound(c, ph, p, s, v, u_last):  # type: ignore[no-untyped-def]
    """Highest effort [-1, 1] from which the train can still stop at the stopping point.

    Restarting close to the platform the tracker sees the stop tail ahead as a speed to
    reach; full traction there overruns the stop.  The bound is the largest surplus
    acceleration whose :func:`stop_distance` fits in the distance left (bisection), as an
    effort; 0 (no traction) when even coasting does not fit.  The surplus of the last
    command (``u_last``) counts as well (the plant takes it off at the jerk limit whatever
    is commanded now).
    """
    d = ph.length - s
    meff = c.meff
    f_hold = resistance(c, v) + grade_force(c, ph, p, s)
    f_max = pmax(c.mass * train_traction(c, v), 1.0)
    a_hi = pmax((f_max - f_hold) / meff, 0.0)
    a_last = pmax((u_last * f_max - f_hold) / meff, 0.0) if u_last > 0.0 else 0.0
    if stop_distance(c, ph, p, v, a_last) >= d:
        return 0.0
    if stop_distance(c, ph, p, v, a_hi) <= d:
        return 1.0
    lo, hi = 0.0, a_hi
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        if stop_distance(c, ph, p, v, pmax(mid, a_last)) <= d:
            lo = mid
        else:
            hi = mid
    return pmin(pmax((f_hold + meff * lo) / f_max, 0.0), 1.0)
