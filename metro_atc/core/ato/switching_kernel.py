"""Compiled (numba) twin of the numpy simulation of traction-then-coast strategies.

:func:`simulate_kernel` reproduces :func:`metro_atc.core.ato.coasting.simulate_switching_numpy`
(the numpy reference: :func:`metro_atc.core.ato.strategy.strategy_step` in accelerate /
coast mode with no speed code, closed-form coasting of seed 002 eq. 7-8) element by element,
in the same operation order (no fast-math, no fused multiply-add), one strategy at a time:
the numpy path pays ~60 array calls per distance step whatever the number of strategies,
this loop pays a few hundred nanoseconds per step and strategy.  Both paths agree to
round-off (``test/test_ato_switching_kernel.py`` compares them on generated lines).

Constants of the train are packed in one float array (indices ``K_*``, built by
:func:`pack_constants`).  Compiled on first use and cached on disk (``cache=True``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import NDArray

from metro_atc.core.ato.envelope import OperatingLimits
from metro_atc.core.line.vehicle import TrainParams

FloatArray = NDArray[np.float64]

(K_MASS, K_MEFF, K_DA, K_DB, K_DC, K_A1, K_V1, K_V2, K_A2, K_A3, K_B2, K_B3, K_AMAX,
 N_CONST) = range(14)

_TINY = 1e-12


def pack_constants(train: TrainParams, limits: OperatingLimits) -> FloatArray:
    """Pack the train and limit constants the kernel reads into one vector (``K_*``)."""
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


@njit(cache=True, inline="always")
def _mx(a: float, b: float) -> float:
    """``np.maximum`` of two floats (NaN propagates, ties keep ``a``)."""
    if a >= b or a != a:
        return a
    return b


@njit(cache=True, inline="always")
def _mn(a: float, b: float) -> float:
    """``np.minimum`` of two floats (NaN propagates, ties keep ``a``)."""
    if a <= b or a != a:
        return a
    return b


@njit(cache=True, error_model="numpy")
def _traction_accel(c: FloatArray, v: float, fg: float, delta: float) -> float:
    """:func:`metro_atc.core.ato.strategy.traction_accel` of one speed [m/s^2]."""
    va = abs(v)
    if va <= c[K_V1]:
        phi = c[K_A1]
    elif va <= c[K_V2]:
        phi = c[K_A2] / (va + c[K_B2] + 1e-12)
    else:
        q = va + c[K_B3] + 1e-12
        phi = c[K_A3] / (q * q)
    f = delta * (c[K_MASS] * phi) - (c[K_DA] + c[K_DB] * v + c[K_DC] * v * v) - fg
    return _mn(f / c[K_MEFF], c[K_AMAX])


@njit(cache=True, error_model="numpy")
def _traction(c: FloatArray, e0: float, h: float, fg: float, delta: float) -> float:
    """:func:`metro_atc.core.ato.strategy.traction_step` of one trajectory (e0 >= 0)."""
    v0 = math.sqrt(2.0 * e0)
    e_p = _mx(e0 + h * _traction_accel(c, v0, fg, delta), 0.0)
    v_m = 0.5 * (v0 + math.sqrt(2.0 * e_p))
    return _mx(e0 + h * _traction_accel(c, v_m, fg, delta), 0.0)


@njit(cache=True, error_model="numpy")
def _x_t(w: float, d4: float, c2: float, bp: float) -> tuple[float, float]:
    """:func:`metro_atc.core.ato.strategy._coast_x_t` of one w (d4 != 0): (X, T)."""
    if d4 > 0.0:
        a = math.sqrt(d4)
        t = -math.atan(w / a) / (c2 * a)
        x_log = -0.5 * math.log(w * w + d4) / c2
        return x_log - bp * t, t
    k = math.sqrt(-d4)
    t = math.log(abs((k + w) / (k - w + _TINY))) / (2.0 * c2 * k)
    x_log = -0.5 * math.log(abs(w * w + d4) + _TINY) / c2
    return x_log - bp * t, t


@njit(cache=True, error_model="numpy")
def _rk4_f(e: float, c0: float, c1: float, c2: float) -> float:
    """de/ds of coasting (:func:`metro_atc.core.ato.strategy._rk4_coast`)."""
    v = math.sqrt(2.0 * _mx(e, 0.0))
    return -(c0 + c1 * v + c2 * v * v)


@njit(cache=True, error_model="numpy")
def _coast(c: FloatArray, e0: float, h: float, fg: float) -> tuple[float, float, bool]:
    """:func:`metro_atc.core.ato.strategy.coast_step` of one trajectory: (e1, dt, stalled)."""
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
    e_guess = _mx(e_r, 0.0)
    if c2 <= 0.0:
        v1 = math.sqrt(2.0 * e_guess)
        dt = 2.0 * h / (v0 + v1 + 1e-300) if v0 + v1 > 0 else np.inf
        return e_guess, (np.inf if stalled else dt), stalled
    bp = c1 / (2.0 * c2)
    d4 = c0 / c2 - bp * bp
    if abs(d4) < 1e-9:
        d4 = 1e-9
    w0 = v0 + bp
    x0, t0 = _x_t(w0, d4, c2, bp)
    w = math.sqrt(2.0 * e_guess) + bp
    x, _ = _x_t(w, d4, c2, bp)
    dxdw = -(w - bp) / (c2 * (w * w + d4))
    if (not stalled) and abs(dxdw) > _TINY:
        w = _mx(w - (x - x0 - h) / dxdw, bp)
    v1 = _mx(w - bp, 0.0)
    e1 = 0.0 if stalled else 0.5 * v1 * v1
    _, t1 = _x_t(math.sqrt(2.0 * e1) + bp, d4, c2, bp)
    dt = t1 - t0
    if not (math.isfinite(dt) and dt > 0.0):
        dt = 2.0 * h / _mx(v0 + math.sqrt(2.0 * e1), _TINY)
    return e1, (np.inf if stalled else dt), stalled


@njit(cache=True, error_model="numpy")
def _step(c: FloatArray, e: float, h: float, fg: float, cap: float, accel: bool,
          delta: float) -> tuple[float, float, float, bool]:
    """:func:`metro_atc.core.ato.strategy.strategy_step` of one trajectory, no speed code.

    Returns (e_next, dt [s], traction energy [J], stalled).
    """
    e0 = _mx(e, 0.0)
    dt_c = 0.0
    st_c = False
    if accel:
        e_m = _traction(c, e0, h, fg, delta)
    else:
        e_m, dt_c, st_c = _coast(c, e0, h, fg)
    e1 = _mx(_mn(e_m, cap), 0.0)
    clamped = e_m > cap
    v0 = math.sqrt(2.0 * e0)
    v1 = math.sqrt(2.0 * e1)
    vm = 0.5 * (v0 + v1)
    force = c[K_MEFF] * (e1 - e0) / h \
        + c[K_DA] + c[K_DB] * vm + c[K_DC] * vm * vm + fg
    energy = 0.0 if not accel else _mx(force, 0.0) * h
    trap = 2.0 * h / _mx(v0 + v1, 1e-300) if v0 + v1 > 0.0 else np.inf
    free_coast = (not accel) and not clamped
    dt = dt_c if free_coast else trap
    stalled = (free_coast and st_c) or (e1 <= 0.0 and cap > 1e-9)
    if stalled:
        dt = np.inf
    return e1, dt, energy, stalled


@njit(cache=True, error_model="numpy")
def simulate_kernel(c: FloatArray, s: FloatArray, h: float, fg: FloatArray, cap: FloatArray,
                    yc: FloatArray, delta: FloatArray, record: bool
                    ) -> tuple[FloatArray, FloatArray, NDArray[np.bool_], FloatArray]:
    """Time [s], energy [J], stalled flag and (if ``record``) e = v^2/2 history per strategy.

    c: :func:`pack_constants`; s: (n+1,) uniform grid [m] of step h [m]; fg: (n,) mean grade
    force of each step [N]; cap: (n,) envelope e at each step's end; yc, delta: (K,)
    coasting points [m] and traction levels.  The history has shape (K, n+1) (or (0, 0)
    without ``record``).
    """
    n = s.shape[0] - 1
    k_n = yc.shape[0]
    t_out = np.zeros(k_n)
    en_out = np.zeros(k_n)
    st_out = np.zeros(k_n, dtype=np.bool_)
    hist = np.zeros((k_n, n + 1)) if record else np.zeros((0, 0))
    for j in range(k_n):
        y = yc[j]
        dl = delta[j]
        e = 0.0
        t = 0.0
        en = 0.0
        st = False
        for k in range(n):
            sk = s[k]
            sw = (y > sk + 1e-9) and (y < s[k + 1] - 1e-9)
            accel = sk + 1e-9 < y
            h1 = y - sk if sw else h
            e1, dt, de, st1 = _step(c, e, h1, fg[k], cap[k], accel, dl)
            if sw:
                e2, dt2, de2, st2 = _step(c, e1, h - h1, fg[k], cap[k], False, dl)
                e1 = e2
                dt += dt2
                de += de2
                st1 = st1 or st2
            e = e1
            if math.isfinite(dt):
                t += dt
            en += de
            st = st or st1
            if record:
                hist[j, k + 1] = e
        t_out[j] = np.inf if st else t
        en_out[j] = en
        st_out[j] = st
    return t_out, en_out, st_out, hist
