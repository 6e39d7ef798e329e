"""One trajectory's strategy step, compiled: the physics shared by the planners' numba kernels.

:func:`strategy_step_one` is :func:`metro_atc.core.ato.strategy.strategy_step` for one
trajectory with no speed code (traction: midpoint RK2 in distance, seed 002 eq. 3-5;
coasting: RK4 guess and one Newton step on the closed-form distance potential, seed 002
eq. 7-8; envelope cap; trapezoid time), written once for the compiled loops of ECTP/ACTP
(:mod:`metro_atc.core.ato.switching_kernel`) and of the DP
(:mod:`metro_atc.core.ato.dp_kernel`), in the numpy path's operation order: their tests
compare each with the numpy reference to round-off.

Train and limit constants travel as one float vector (``K_*`` indices, :func:`pack_train`).
Compiled with numba when it is installed (:func:`jit`), plain Python otherwise.
"""

from __future__ import annotations

import math
from typing import Any, Callable

import numpy as np
from numpy.typing import NDArray

from metro_atc.core.ato.envelope import MODE_COAST, MODE_CRUISE, OperatingLimits
from metro_atc.core import laws
from metro_atc.core.kernel_choice import numba_available
from metro_atc.core.line.vehicle import TrainParams

FloatArray = NDArray[np.float64]

(K_MASS, K_MEFF, K_DA, K_DB, K_DC, K_A1, K_V1, K_V2, K_A2, K_A3, K_B2, K_B3, K_AMAX,
 N_CONST) = range(14)

TINY = 1e-12


def jit(fn: Callable[..., Any]) -> Callable[..., Any]:
    """Compile ``fn`` with numba (cached, numpy error model) when installed, else return it."""
    if not numba_available():
        return fn
    from numba import njit
    return njit(cache=True, error_model="numpy")(fn)  # type: ignore[no-any-return]


def pack_train(train: TrainParams, limits: OperatingLimits) -> FloatArray:
    """Pack the train and limit constants the kernels read into one vector (``K_*``)."""
    c = np.zeros(N_CONST)
    c[K_MASS] = train.mass_kg
    c[K_MEFF] = train.effective_mass_kg
    c[K_DA] = train.davis_a_n
    c[K_DB] = train.davis_b_n_per_mps
    c[K_DC] = train.davis_c_n_per_mps2
    c[K_A1] = train.a1_mps2
    c[K_V1] = train.v1_mps
    c[K_V2] = train.v2_mps
    c[K_A2] = train.a2
    c[K_A3] = train.a3
    c[K_B2] = train.b2_mps
    c[K_B3] = train.b3_mps
    c[K_AMAX] = limits.accel_max_mps2
    return c


@jit
def mx(a: float, b: float) -> float:
    """``np.maximum`` of two floats (NaN propagates, ties keep ``a``)."""
    if a >= b or a != a:
        return a
    return b


@jit
def mn(a: float, b: float) -> float:
    """``np.minimum`` of two floats (NaN propagates, ties keep ``a``)."""
    if a <= b or a != a:
        return a
    return b


@jit
def traction_accel(c: FloatArray, v: float, fg: float, delta: float) -> float:
    """:func:`metro_atc.core.ato.strategy.traction_accel` of one speed v >= 0 [m/s^2].

    Level ``delta`` of :func:`metro_atc.core.laws.traction_accel` less
    :func:`metro_atc.core.laws.davis_resistance` and the grade force, capped at a_max.
    """
    phi = laws.traction_accel(v, c[K_A1], c[K_V1], c[K_V2], c[K_A2], c[K_A3], c[K_B2], c[K_B3])
    f = delta * (c[K_MASS] * phi) - laws.davis_resistance(v, c[K_DA], c[K_DB], c[K_DC]) - fg
    return mn(f / c[K_MEFF], c[K_AMAX])  # type: ignore[no-any-return]


@jit
def traction_step(c: FloatArray, e0: float, h: float, fg: float, delta: float) -> float:
    """:func:`metro_atc.core.ato.strategy.traction_step` of one trajectory (e0 >= 0)."""
    v0 = math.sqrt(2.0 * e0)
    e_p = mx(e0 + h * traction_accel(c, v0, fg, delta), 0.0)
    v_m = 0.5 * (v0 + math.sqrt(2.0 * e_p))
    return mx(e0 + h * traction_accel(c, v_m, fg, delta), 0.0)  # type: ignore[no-any-return]


@jit
def coast_x_t(w: float, d4: float, c2: float, bp: float) -> tuple[float, float]:
    """:func:`metro_atc.core.ato.strategy._coast_x_t` of one w (d4 != 0): (X [m], T [s])."""
    if d4 > 0.0:
        a = math.sqrt(d4)
        t = -math.atan(w / a) / (c2 * a)
        x_log = -0.5 * math.log(w * w + d4) / c2
        return x_log - bp * t, t
    k = math.sqrt(-d4)
    t = math.log(abs((k + w) / (k - w + TINY))) / (2.0 * c2 * k)
    x_log = -0.5 * math.log(abs(w * w + d4) + TINY) / c2
    return x_log - bp * t, t


@jit
def _rk4_f(e: float, c0: float, c1: float, c2: float) -> float:
    """de/ds of coasting (:func:`metro_atc.core.ato.strategy._rk4_coast`)."""
    v = math.sqrt(2.0 * mx(e, 0.0))
    return -(c0 + c1 * v + c2 * v * v)


@jit
def coast_step(c: FloatArray, e0: float, h: float, fg: float) -> tuple[float, float, bool]:
    """:func:`metro_atc.core.ato.strategy.coast_step` of one trajectory: (e1, dt [s], stalled)."""
    m = c[K_MEFF]
    c0 = (c[K_DA] + fg) / m
    c1 = c[K_DB] / m
    c2 = c[K_DC] / m
    v0 = math.sqrt(2.0 * e0)
    k1 = _rk4_f(e0, c0, c1, c2)
    k2 = _rk4_f(e0 + 0.5 * h * k1, c0, c1, c2)
    k3 = _rk4_f(e0 + 0.5 * h * k2, c0, c1, c2)
    k4 = _rk4_f(e0 + h * k3, c0, c1, c2)
    e_r = e0 + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
    stalled = (e_r <= 1e-9) and (c0 > 0.0)
    e_guess = mx(e_r, 0.0)
    if c2 <= 0.0:
        v1 = math.sqrt(2.0 * e_guess)
        dt = 2.0 * h / (v0 + v1 + 1e-300) if v0 + v1 > 0 else np.inf
        return e_guess, (np.inf if stalled else dt), stalled
    bp = c1 / (2.0 * c2)
    d4 = c0 / c2 - bp * bp
    if abs(d4) < 1e-9:
        d4 = 1e-9
    x0, t0 = coast_x_t(v0 + bp, d4, c2, bp)
    w = math.sqrt(2.0 * e_guess) + bp
    x, _ = coast_x_t(w, d4, c2, bp)
    dxdw = -(w - bp) / (c2 * (w * w + d4))
    if (not stalled) and abs(dxdw) > TINY:
        w = mx(w - (x - x0 - h) / dxdw, bp)
    v1 = mx(w - bp, 0.0)
    e1 = 0.0 if stalled else 0.5 * v1 * v1
    _, t1 = coast_x_t(math.sqrt(2.0 * e1) + bp, d4, c2, bp)
    dt = t1 - t0
    if not (math.isfinite(dt) and dt > 0.0):
        dt = 2.0 * h / mx(v0 + math.sqrt(2.0 * e1), TINY)
    return e1, (np.inf if stalled else dt), stalled


@jit
def strategy_step_one(c: FloatArray, e: float, h: float, fg: float, cap: float, mode: int,
                      e_hold: float, delta: float) -> tuple[float, float, float, bool]:
    """:func:`metro_atc.core.ato.strategy.strategy_step` of one trajectory, no speed code.

    ``mode``: MODE_ACCEL (traction at level ``delta``), MODE_CRUISE (the same, capped at
    ``e_hold``) or MODE_COAST. Returns (e_next [m^2/s^2], dt [s] (inf when stalled),
    traction energy [J], stalled).
    """
    e0 = mx(e, 0.0)
    dt_c = 0.0
    st_c = False
    coast = mode == MODE_COAST
    if coast:
        e_m, dt_c, st_c = coast_step(c, e0, h, fg)
    else:
        e_m = traction_step(c, e0, h, fg, delta)
        if mode == MODE_CRUISE:
            e_m = mn(e_m, e_hold)
    e1 = mx(mn(e_m, cap), 0.0)
    clamped = e_m > cap
    v0 = math.sqrt(2.0 * e0)
    v1 = math.sqrt(2.0 * e1)
    vm = 0.5 * (v0 + v1)
    force = c[K_MEFF] * (e1 - e0) / h \
        + c[K_DA] + c[K_DB] * vm + c[K_DC] * vm * vm + fg
    energy = 0.0 if coast else mx(force, 0.0) * h
    trap = 2.0 * h / mx(v0 + v1, 1e-300) if v0 + v1 > 0.0 else np.inf
    free_coast = coast and not clamped
    dt = dt_c if free_coast else trap
    stalled = (free_coast and st_c) or (e1 <= 0.0 and cap > 1e-9)
    if stalled:
        dt = np.inf
    return e1, dt, energy, stalled
