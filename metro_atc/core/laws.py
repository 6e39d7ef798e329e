"""The physical laws of the train, each written once, compiled with numba.

Every function here is a scalar law on plain floats (SI units), compiled with
``numba.njit(cache=True)`` and callable from plain Python, from numpy code (through the
array helpers at the end) and from the other numba kernels (which inline them).  Each
reproduces, operation for operation, the expression the modules computed before it became
the one source (no fast-math, no fused multiply-add: the same IEEE float64 results); the
proofs are in ``test/test_laws.py``, the one-source check in ``test/test_laws_once.py``.
Squares are products ``x * x`` (correctly rounded; C ``pow(x, 2)``, which CPython's
``x ** 2`` calls, is one ulp off for about 1 value in 1 200).  Transcendentals are libm's
(``math.exp``, ``math.sin``, ``math.atan``); numpy's vectorised ones differ from them by an
ulp on some arguments, so array callers go through the ``*_array`` forms (one loop for
every law, :data:`ARRAY_LAWS`).
``NUMBA_DISABLE_JIT=1`` runs the same source as plain Python (debugging).

The laws are compiled at their first use, not at import: the first attribute access of a
law (``laws.traction_accel``, from Python or while numba compiles a kernel that calls it)
imports numba and wraps every law at once (:func:`__getattr__`), so a module that only
reads a scenario (the ATS, the recorder) does not pay numba's import.  :data:`plain` holds
the same laws uncompiled, for one-off evaluations (the scenario loader's checks) that should
not import numba at all.

numba's on-disk cache does not follow imports: a kernel that inlines a law keeps its cached
machine code when only this file changes.  After editing a law, delete the caches
(``find metro_atc install -name '*.nb[ic]' -delete``) or rebuild (``make setup``).

Sources (the equations are cited where used; full citations in ``docs/references.md``):

- ACTP n.d. (Taipei MRT train-profile control with adaptive critics; its authors and year
  are not in the source text): running resistance eq. 1-2, the piecewise traction
  characteristic eq. 3-5.
- Lin 2010b (Lin and Tang, "Active safety diagnosis of brake-by-wire systems with unscented
  Kalman filter"): axle dynamics and pad torque eq. 4.
- Ke 2010 (driving strategy by the MAX-MIN ant system): ATP braking curve Fig. 1,
  accel/decel and jerk limits.
- Li n.d. (fuzzy motion control of Taiwan High Speed Rail): RK4 integration of Newton's law.
- Roeckl's curve-resistance formula (standard gauge), the Burckhardt slip-adhesion curve.
"""

from __future__ import annotations

import math

import types
from typing import Any, Callable

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

G_MPS2 = 9.80665
"""Standard gravity [m/s^2]."""
TRACTION_EPS_MPS = 1e-12
"""Guard added to the speed in the traction law's divisions [m/s] (no division by zero)."""
EBRAKE_MIN_SPEED_MPS = 1e-3
"""Speed floor of the electric brake's power limit ``P / v`` [m/s]."""
STOP_DECEL_MIN_MPS2 = 1e-9
"""Smallest deceleration of the uniform stop inside an integration step [m/s^2]."""

_LAWS: dict[str, tuple[Callable[..., Any], dict[str, Any]]] = {}
"""Every law by name: its Python function and its ``numba.njit`` options."""


def njit(**options: Any) -> Callable[[Callable[..., Any]], Callable[..., Any]]:
    """Register a law: numba compiles it with these options at first use (module doc)."""
    def register(fn: Callable[..., Any]) -> Callable[..., Any]:
        _LAWS[fn.__name__] = (fn, options)
        return fn
    return register


@njit(cache=True, inline="always")
def fmin(a: float, b: float) -> float:
    """``np.minimum`` of two floats (NaN propagates, ties keep ``a``)."""
    if a <= b or a != a:
        return a
    return b


@njit(cache=True, inline="always")
def fmax(a: float, b: float) -> float:
    """``np.maximum`` of two floats (NaN propagates, ties keep ``a``)."""
    if a >= b or a != a:
        return a
    return b


# ---------------------------------------------------------------------------- traction


@njit(cache=True)
def traction_a2(a1: float, v1: float, b2: float) -> float:
    """Constant a_2 [m^2/s^3] of the constant-voltage region, continuity at v_1.

    ``a_2 = a_1 (v_1 + b_2)`` (ACTP n.d., eq. 3-4); a1 [m/s^2], v1, b2 [m/s].
    """
    return a1 * (v1 + b2)


@njit(cache=True)
def traction_a3(a1: float, v1: float, v2: float, b2: float, b3: float) -> float:
    """Constant a_3 [m^3/s^4] of the constant-power region, continuity at v_2.

    ``a_3 = a_2 / (v_2 + b_2) (v_2 + b_3)^2`` (ACTP n.d., eq. 4-5).
    """
    phi2_v2 = traction_a2(a1, v1, b2) / (v2 + b2)
    q = v2 + b3
    return phi2_v2 * (q * q)


@njit(cache=True)
def traction_accel(v: float, a1: float, v1: float, v2: float, a2: float, a3: float,
                   b2: float, b3: float) -> float:
    """Maximum tractive acceleration phi(v) [m/s^2] at speed v [m/s] (force / static mass).

    Piecewise (ACTP n.d., eq. 3-5): constant torque ``a_1`` up to ``v_1``,
    constant voltage ``a_2 / (|v| + b_2)`` up to ``v_2``, constant power
    ``a_3 / (|v| + b_3)^2`` above (each denominator plus :data:`TRACTION_EPS_MPS`).
    """
    va = abs(v)
    if va <= v1:
        return a1
    if va <= v2:
        return a2 / (va + b2 + 1e-12)
    q = va + b3 + 1e-12
    return a3 / (q * q)


@njit(cache=True)
def traction_force(v: float, mass: float, a1: float, v1: float, v2: float, a2: float,
                   a3: float, b2: float, b3: float) -> float:
    """Maximum tractive force [N]: mass [kg] times :func:`traction_accel` (eq. 3-5)."""
    return mass * traction_accel(v, a1, v1, v2, a2, a3, b2, b3)


@njit(cache=True)
def traction_mass(mass: float, m_ref: float) -> float:
    """Mass [kg] the tractive force is scaled by: ``min(mass, m_ref)``.

    The traction curve phi(v) (:func:`traction_accel`) is specified at the reference mass
    ``m_ref`` [kg] (the rolling stock's ``mass_kg`` with its ``mass_load_pax``).  Up to
    that load the drive is load-weighed (the same acceleration at every load, as the ATP's
    worst-case response acceleration ``phi + g max_down`` assumes); above it the motors are
    at their force limit ``phi(v) m_ref``, so a fuller train accelerates less.  The maximum
    tractive force of a train of ``mass`` is ``traction_force(v, traction_mass(mass,
    m_ref), ...)``.
    """
    return fmin(mass, m_ref)


@njit(cache=True)
def load_weighed_decel(decel: float, meff: float, meff_limit: float) -> float:
    """Full deceleration [m/s^2] of a load-weighed brake on the effective mass ``meff`` [kg].

    The brake's load-weighing valve compensates up to the effective mass ``meff_limit``
    [kg]: below it the full brake gives ``decel`` [m/s^2] at every load; above it the brake
    is at its maximum force ``decel meff_limit`` [N] (:func:`brake_force_max`) and the
    deceleration falls as ``decel meff_limit / meff``.
    """
    if meff <= meff_limit:
        return decel
    return brake_force_max(decel, meff_limit) / meff


@njit(cache=True)
def brake_force_max(decel: float, meff_limit: float) -> float:
    """Maximum force [N] of a brake of rate ``decel`` [m/s^2] load-weighed up to ``meff_limit``.

    ``decel meff_limit``: the force at the largest effective mass [kg] the load-weighing
    compensates (:func:`load_weighed_decel`).
    """
    return decel * meff_limit


@njit(cache=True)
def traction_demand_force(a_d: float, meff: float, f_max: float, f_adh: float) -> float:
    """Tractive force [N] for the demanded acceleration ``a_d`` [m/s^2].

    ``min(min(max(a_d, 0) M_eff, F_max), F_adh)``: the demand on the effective mass
    ``meff`` [kg], capped by the traction curve ``f_max`` [N] and the motored axles'
    adhesion ``f_adh`` [N].
    """
    return fmin(fmin(fmax(a_d, 0.0) * meff, f_max), f_adh)


@njit(cache=True)
def command_effort(u: float, f_trac_max: float, mass: float, brake_decel: float) -> float:
    """Traction/brake effort [N] of a normalised command u (clipped to [-1, 1]).

    u >= 0: the fraction u of the tractive force ``f_trac_max`` [N]; u < 0: the fraction
    of the service brake force ``mass`` [kg] x ``brake_decel`` [m/s^2].
    """
    ua = fmin(fmax(u, -1.0), 1.0)
    if ua >= 0.0:
        return ua * f_trac_max
    return ua * mass * brake_decel


# ---------------------------------------------------------------------------- resistances


@njit(cache=True)
def davis_resistance(v: float, a: float, b: float, c: float) -> float:
    """Davis running resistance ``A + B |v| + C v^2`` [N] (ACTP n.d., eq. 1-2).

    a [N], b [N/(m/s)], c [N/(m/s)^2] (or the same per unit mass: a deceleration [m/s^2]);
    v [m/s].  Always >= 0 for A, B, C >= 0 (the sign of the motion is the caller's).
    """
    va = abs(v)
    return a + b * va + c * va * va


@njit(cache=True)
def davis_odd(v: float, a: float, b: float, c: float) -> float:
    """Davis resistance opposing the motion, ``(B + C |v|) v + A sign(v)`` [N or m/s^2].

    The same law as :func:`davis_resistance` extended oddly through v = 0 (the form of the
    brake observer's transition, Lin 2010b, eq. 4 with the running resistance).
    """
    if v > 0.0:
        sg = 1.0
    elif v < 0.0:
        sg = -1.0
    elif v == 0.0:
        sg = 0.0
    else:
        sg = v
    return (b + c * abs(v)) * v + a * sg


@njit(cache=True)
def grade_sine(grade: float) -> float:
    """sin(theta) [-] of a grade given as rise / run [-] (positive uphill)."""
    return math.sin(math.atan(grade))


@njit(cache=True)
def grade_force(grade: float, mass: float) -> float:
    """Gravity force along the track [N]: ``m g sin(atan(grade))``; mass [kg]."""
    return mass * G_MPS2 * grade_sine(grade)


@njit(cache=True)
def curve_resistance_per_kg(radius_m: float) -> float:
    """Curve resistance [N/kg] by the Roeckl formula (standard gauge).

    ``w_r`` [N/kN] = 650 / (R - 55) for R >= 300 m, 500 / (R - 30) below (R [m]; each
    denominator at least 1 m).
    """
    if radius_m >= 300.0:
        wr = 650.0 / fmax(radius_m - 55.0, 1.0)
    else:
        wr = 500.0 / fmax(radius_m - 30.0, 1.0)
    return wr / 1000.0 * G_MPS2


@njit(cache=True)
def net_accel(v: float, effort_n: float, f_grade: float, a: float, b: float, c: float,
              meff: float) -> float:
    """Newton's law: dv/dt [m/s^2] = (effort - sign(v) F_r(v) - F_grade) / M_eff.

    ``effort_n`` and ``f_grade`` [N], Davis a, b, c as :func:`davis_resistance`, effective
    mass ``meff`` [kg].
    """
    sg = 1.0 if v > 0.0 else (-1.0 if v < 0.0 else (0.0 if v == 0.0 else v))
    f = effort_n - sg * davis_resistance(v, a, b, c) - f_grade
    return f / meff


@njit(cache=True, inline="always")
def step_force(meff: float, e0: float, e1: float, h: float, v: float, a: float, b: float,
               c: float, f_grade: float) -> float:
    """Mean force [N] the train needs over a distance step: the planners' energy integrand.

    ``M_eff (e1 - e0) / h + A + B v + C v^2 + F_grade`` summed left to right: the inertial
    force of the change of kinetic energy per unit mass e = v^2/2 [m^2/s^2] over h [m],
    the Davis resistance (ACTP n.d., eq. 1-2) at the step's mean speed v >= 0 [m/s] and the
    grade force [N]; its positive part times h is the step's traction energy (Ke 2010,
    eq. 6: the sum of the sections' energies the ant system minimises).  The planners'
    tables and tours are built on this order (:func:`davis_resistance` grouped first would
    move their last bits).
    """
    return meff * (e1 - e0) / h + a + b * v + c * v * v + f_grade


@njit(cache=True)
def davis_rk4_step(v: float, q: float, cb: float, cc: float,
                   h: float) -> tuple[float, float, float, float]:
    """One RK4 step (Li n.d.) of ``dv/dt = q - v (cb + cc v)``.

    The longitudinal ODE at constant effort and grade: ``q = (F - A - F_g - F_c) / M_eff``
    [m/s^2], ``cb = B / M_eff`` [1/s], ``cc = C / M_eff`` [1/m] (Davis A, B, C), step h
    [s].  Returns (v after the step [m/s], distance by the same quadrature [m], the slope
    k1 at the start [m/s^2], the quadrature sum ``k1 v + 2 (k2 v2 + k3 v3) + k4 v4``
    [m^2/s^3], whose h/6 multiple is the work of the velocity-dependent resistance per
    effective mass).
    """
    h2 = 0.5 * h
    h6 = h / 6.0
    k1 = q - v * (cb + cc * v)
    v2 = v + h2 * k1
    k2 = q - v2 * (cb + cc * v2)
    v3 = v + h2 * k2
    k3 = q - v3 * (cb + cc * v3)
    v4 = v + h * k3
    k4 = q - v4 * (cb + cc * v4)
    vn = v + h6 * (k1 + 2.0 * (k2 + k3) + k4)
    dx = h6 * (v + 2.0 * (v2 + v3) + v4)
    kv = k1 * v + 2.0 * (k2 * v2 + k3 * v3) + k4 * v4
    return vn, dx, k1, kv


@njit(cache=True)
def stop_distance_in_step(v: float, k1: float, h: float) -> float:
    """Distance [m] to rest inside a step at the step-start deceleration ``-k1`` [m/s^2].

    ``min(v^2 / (-2 min(k1, -1e-9)), h v)``: exact for a constant deceleration, bounded by
    the distance at constant speed over the step h [s] (no roll-back).
    """
    return fmin(v * v / (-2.0 * fmin(k1, -1e-9)), h * v)


# ---------------------------------------------------------------------------- brakes


@njit(cache=True)
def brake_demand_force(a_d: float, meff: float) -> float:
    """Brake force [N] demanded by the acceleration ``a_d`` [m/s^2]: ``max(-a_d, 0) M_eff``."""
    return fmax(-a_d, 0.0) * meff


@njit(cache=True)
def electric_brake_force_max(v: float, mass: float, brake_decel: float, power_max_w: float,
                             fade_speed_mps: float) -> float:
    """Maximum electric (regenerative) brake force [N] at speed v [m/s].

    ``min(b m, P / max(v, 1e-3)) min(v / v_fade, 1)``: the service brake force, the power
    limit P [W] and a linear fade below ``fade_speed_mps``.
    """
    vv = fmax(v, 1e-3)
    return fmin(brake_decel * mass, power_max_w / vv) * fmin(v / fade_speed_mps, 1.0)


@njit(cache=True)
def electric_brake_share(f_demand: float, f_e_max: float) -> float:
    """Electric part [N] of a brake demand [N]: ``min(demand, max electric force)``.

    The friction brake supplies the rest, ``f_demand - share``.
    """
    return fmin(f_demand, f_e_max)


@njit(cache=True)
def pad_torque(clamp_force_n: float | FloatArray, mu_b: float | FloatArray,
               r_b: float) -> float | FloatArray:
    """Friction brake torque [N m] of one axle ``2 mu_b R_b F_c`` (Lin 2010b, eq. 4).

    Clamp force [N], pad friction coefficient [-], effective pad radius [m].  Plain
    arithmetic: numba also compiles it for arrays (elementwise, the same operation order).
    """
    return 2.0 * mu_b * r_b * clamp_force_n


@njit(cache=True)
def clamp_force_for_torque(torque_nm: float | FloatArray, mu_b: float,
                           r_b: float) -> float | FloatArray:
    """Clamp force [N] giving a brake torque [N m]: the inverse of :func:`pad_torque`.

    Like :func:`pad_torque`, numba also compiles it for arrays (elementwise).
    """
    return torque_nm / (2.0 * mu_b * r_b)


# ---------------------------------------------------------------------------- adhesion


@njit(cache=True)
def axle_load(mass: float, n_axles: float) -> float:
    """Normal load of one axle [N]: ``m (g / n_axles)``; mass [kg]."""
    return mass * (G_MPS2 / n_axles)


@njit(cache=True)
def adhesion_limit(mu: float, normal_load_n: float) -> float:
    """Largest rail force [N] an axle transmits: adhesion coefficient [-] x normal load [N]."""
    return mu * normal_load_n


@njit(cache=True)
def burckhardt_mu(s: float, c1: float, c2: float, c3: float) -> float:
    """Burckhardt adhesion ``mu(s) = c1 (1 - exp(-c2 s)) - c3 s`` [-], slip s clipped to [0, 1]."""
    sa = fmin(fmax(s, 0.0), 1.0)
    return c1 * (1.0 - math.exp(-c2 * sa)) - c3 * sa


# ---------------------------------------------------------------------------- ATP curves


@njit(cache=True)
def ebi_coef(b_g: float, t_r: float, a_w: float) -> tuple[float, float, float]:
    """Coefficients (c0 [m^2/s^2], c1 [m/s^2], c2 [m/s]) of the ATP braking curve.

    ``v_ebi(D) = sqrt(c0 + c1 D) - c2`` with ``c0 = (b_g t_r)^2 + b_g t_r^2 a_w``,
    ``c1 = 2 b_g``, ``c2 = b_g t_r + t_r a_w`` (Ke 2010, Fig. 1): a
    response time t_r [s] at the worst-case acceleration a_w [m/s^2], then the guaranteed
    deceleration b_g [m/s^2].
    """
    bt = b_g * t_r
    return bt * bt + b_g * t_r * t_r * a_w, 2.0 * b_g, bt + t_r * a_w


@njit(cache=True)
def ebi_speed_from(c0: float, c1: float, c2: float, dist_m: float) -> float:
    """EBI speed [m/s] at ``dist_m`` [m] before the stop from :func:`ebi_coef`.

    ``sqrt(max(c0 + c1 D, 0)) - c2`` (NaN and -0.0 pass the max); negative: the train
    must already be stopped.
    """
    z = c0 + c1 * dist_m
    if z < 0.0:
        z = 0.0
    return math.sqrt(z) - c2


@njit(cache=True)
def ebi_speed(dist_m: float, target_mps: float, a_w: float, t_r: float, b_g: float) -> float:
    """EBI speed [m/s] at ``dist_m`` [m] before a point of speed ``target_mps`` [m/s].

    :func:`ebi_coef` with ``c0 + v_t^2`` (Ke 2010, Fig. 1).
    """
    c0, c1, c2 = ebi_coef(b_g, t_r, a_w)
    if target_mps != 0.0:
        c0 = c0 + target_mps * target_mps
    return ebi_speed_from(c0, c1, c2, dist_m)


@njit(cache=True)
def stopping_distance(v: float, a_w: float, t_r: float, b_g: float) -> float:
    """Worst-case ATP stopping distance [m] from speed v [m/s]; the inverse of the EBI curve.

    ``v t_r + a_w t_r^2 / 2 + (v + a_w t_r)^2 / (2 b_g)`` (response, then braking).
    """
    w = v + a_w * t_r
    return v * t_r + 0.5 * a_w * t_r * t_r + w * w / (2.0 * b_g)


@njit(cache=True)
def response_distance(v: float, a_w: float, t_r: float) -> float:
    """Distance [m] run during the response time t_r [s] from v [m/s] accelerating at a_w."""
    return v * t_r + 0.5 * a_w * (t_r * t_r)


@njit(cache=True)
def braking_speed(dist_m: float, decel: float) -> float:
    """Speed [m/s] from which a constant deceleration [m/s^2] stops within ``dist_m`` [m].

    ``sqrt(2 b max(D, 0))`` (the speed codes, the reference driver's curve).
    """
    return math.sqrt(2.0 * decel * fmax(dist_m, 0.0))


@njit(cache=True)
def downhill_accel(max_down: float) -> float:
    """Gravity acceleration [m/s^2] on a downhill grade ``max_down`` [-]: ``g max_down``.

    The ATP's small-angle assumption (sin(atan(i)) <= i).
    """
    return G_MPS2 * max_down


@njit(cache=True)
def guaranteed_decel_on_grade(b_level: float, max_down: float) -> float:
    """Guaranteed deceleration [m/s^2] on the steepest downhill grade ``max_down`` [-].

    ``b_level - g max_down`` (:func:`downhill_accel`).
    """
    return b_level - downhill_accel(max_down)


@njit(cache=True)
def response_accel(a1: float, max_down: float) -> float:
    """Worst-case acceleration during the ATP response time [m/s^2]: ``a_1 + g max_down``."""
    return a1 + downhill_accel(max_down)


@njit(cache=True)
def adhesion_guaranteed_decel(mu_slide: float, tare_kg: float, m_rot_kg: float) -> float:
    """Adhesion-limited emergency deceleration [m/s^2]: locked wheels, 10 % margin.

    ``0.9 mu_slide g m_tare / (m_tare + m_rot)`` (the empty train: the smallest adhesion
    mass relative to the rotating allowance).
    """
    return 0.9 * mu_slide * G_MPS2 * tare_kg / (tare_kg + m_rot_kg)


# ---------------------------------------------------------------------------- arrays


ARRAY_LAWS = ("traction_accel", "davis_resistance", "davis_odd", "electric_brake_force_max",
              "burckhardt_mu", "curve_resistance_per_kg", "stopping_distance", "grade_force",
              "net_accel", "grade_sine")
"""Laws with an array form ``<law>_array(x, *args)``: the law of each element of the 1-d
float64 array ``x``; an argument that is an array of x's length is taken element by element,
a float as it is (:func:`_elementwise`, reached as ``laws.<law>_array``)."""


_ARRAYS_READY: list[bool] = []
"""Not empty once :func:`_compile_arrays` registered the compiled :func:`_law_at`."""


def _law_at(name: str, i: int, x: FloatArray, args: tuple[Any, ...]) -> float:
    """The law ``name`` at element i of x and of the array arguments (plain Python).

    Compiled code calls the implementation :func:`_compile_arrays` registers instead (the
    law inlined, the argument list written for the arguments' types at compile time).
    """
    law = globals()[name]
    return law(x[i], *[a[i] if isinstance(a, np.ndarray) else a for a in args])  # type: ignore


def _elementwise(name: str) -> Callable[..., FloatArray]:
    """``<name>_array``: the one loop of every array form, compiled for the law ``name``.

    The loop's only free variable is the law's name (a string constant to numba), so
    numba's on-disk cache keys each law's loop by it and reloads it in the next process.
    """
    from numba import njit as numba_njit

    def loop(x: FloatArray, *args: Any) -> FloatArray:
        out = np.empty(x.shape[0])
        for i in range(x.shape[0]):
            out[i] = _law_at(name, i, x, args)
        return out
    loop.__name__ = loop.__qualname__ = f"{name}_array"
    loop.__doc__ = f":func:`{name}` of each element of a 1-d array (:data:`ARRAY_LAWS`)."
    return numba_njit(cache=True)(loop)  # type: ignore[no-any-return]


def _compile_arrays() -> None:
    """Register the compiled :func:`_law_at` (once; the laws compiled first)."""
    if _ARRAYS_READY:
        return
    from numba import types as nbt
    from numba.extending import overload

    @overload(_law_at)  # type: ignore[misc]
    def _law_at_impl(name, i, x, args):  # type: ignore[no-untyped-def]
        if not isinstance(name, nbt.StringLiteral):
            return None
        terms = "".join(f", args[{k}][i]" if isinstance(a, nbt.Array) else f", args[{k}]"
                        for k, a in enumerate(args))
        ns = {"law": globals()[name.literal_value]}
        exec(f"def impl(name, i, x, args):\n    return law(x[i]{terms})\n", ns)
        return ns["impl"]
    _ARRAYS_READY.append(True)


def on_array(fn, x, *args):  # type: ignore[no-untyped-def]
    """Apply a ``*_array`` law to any array-like ``x`` (any shape, returns that shape)."""
    xa = np.asarray(x, dtype=np.float64)
    out = fn(np.ascontiguousarray(xa).reshape(-1), *args).reshape(xa.shape)
    return out[()] if out.ndim == 0 else out


def _compile() -> None:
    """Bind every law to its numba dispatcher (compiled lazily by numba, cached on disk)."""
    from numba import njit as numba_njit
    g = globals()
    for name, (fn, options) in _LAWS.items():
        g[name] = numba_njit(**options)(fn)


def __getattr__(name: str) -> Any:
    """The compiled law ``name`` (the first access compiles them all: module docstring).

    ``<law>_array`` (:data:`ARRAY_LAWS`): its loop, built at its first access.
    """
    if name in _LAWS:
        _compile()
        return globals()[name]
    if name.endswith("_array") and name[:-len("_array")] in ARRAY_LAWS:
        if "traction_accel" not in globals():
            _compile()
        _compile_arrays()
        fn = _elementwise(name[:-len("_array")])
        globals()[name] = fn
        return fn
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def _plain() -> types.SimpleNamespace:
    """Every law as plain Python (calling each other uncompiled), without numba."""
    g = dict(globals())
    fns = {name: types.FunctionType(fn.__code__, g, name, fn.__defaults__, fn.__closure__)
           for name, (fn, _) in _LAWS.items()}
    g.update(fns)
    return types.SimpleNamespace(**fns)


plain = _plain()
"""The laws uncompiled (``laws.plain.traction_force(...)``): the same source, no numba."""

for _name in _LAWS:  # reached through __getattr__ until compiled
    del globals()[_name]
