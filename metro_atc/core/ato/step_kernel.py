"""One trajectory's strategy step, compiled: the physics shared by the planners' numba kernels.

:func:`strategy_step_one` is :func:`metro_atc.core.ato.strategy.strategy_step` for one
trajectory with no speed code (traction: midpoint RK2 in distance, ACTP n.d., eq. 3-5;
coasting: RK4 guess and one Newton step on the closed-form distance potential, ACTP n.d.
eq. 7-8; envelope cap; trapezoid time), written once for the compiled loops of ECTP/ACTP
(:mod:`metro_atc.core.ato.switching_kernel`) and of the DP
(:mod:`metro_atc.core.ato.dp_kernel`), in the numpy path's operation order: their tests
compare each with the numpy reference to round-off.

Train and limit constants travel as one record (:data:`TRAIN`, :func:`pack_train`; the
kernels' entry points take the one-element array and hand its record ``c[0]`` down).
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

TRAIN_FIELDS = ("mass", "meff", "davis_a", "davis_b", "davis_c", "a1", "v1", "v2", "a2", "a3",
                "b2", "b3", "accel_max")
"""Fields of :data:`TRAIN`: mass, effective mass [kg], Davis a [N], b [N s/m], c [N s^2/m^2],
the traction curve (a1 [m/s^2], v1, v2 [m/s], a2 [m^2/s^3], a3 [m^3/s^4], b2, b3 [m/s]) and
the planning acceleration limit [m/s^2]."""
TRAIN = np.dtype([(f, np.float64) for f in TRAIN_FIELDS])
"""The train and limit constants the kernels read, by name (one-element arrays)."""

TINY = 1e-12


def jit(fn: Callable[..., Any]) -> Callable[..., Any]:
    """Compile ``fn`` with numba (cached, numpy error model) when installed, else return it."""
    if not numba_available():
        return fn
    from numba import njit
    return njit(cache=True, error_model="numpy")(fn)  # type: ignore[no-any-return]


TRACTION_FIELDS = ("a1", "v1", "v2", "a2", "a3", "b2", "b3")
"""Record fields of the traction curve, in the order of ``TrainParams.traction_law``."""


def train_fields(train: TrainParams) -> tuple[tuple[str, float], ...]:
    """(field, value) of the train constants every ATO kernel record carries.

    Mass [kg], effective mass [kg], Davis A, B, C [N, N/(m/s), N/(m/s)^2] and the traction
    curve (:data:`TRAIN` and the control step's ``CONSTANTS``).
    """
    return (("mass", train.mass_kg), ("meff", train.effective_mass_kg),
            ("davis_a", train.davis_a_n), ("davis_b", train.davis_b_n_per_mps),
            ("davis_c", train.davis_c_n_per_mps2), *zip(TRACTION_FIELDS, train.traction_law))


def pack_train(train: TrainParams, limits: OperatingLimits) -> NDArray[np.void]:
    """The train and limit constants the kernels read (a one-element :data:`TRAIN` array)."""
    c = np.zeros(1, dtype=TRAIN)
    r = c[0]
    for name, val in train_fields(train):
        r[name] = val
    r["accel_max"] = limits.accel_max_mps2
    return c


mx = laws.fmax
"""``np.maximum`` of two floats (:func:`metro_atc.core.laws.fmax`)."""
mn = laws.fmin
"""``np.minimum`` of two floats (:func:`metro_atc.core.laws.fmin`)."""


@jit
def traction_accel(c: Any, v: float, fg: float, delta: float) -> float:
    """:func:`metro_atc.core.ato.strategy.traction_accel` of one speed v >= 0 [m/s^2].

    Level ``delta`` of :func:`metro_atc.core.laws.traction_accel` less
    :func:`metro_atc.core.laws.davis_resistance` and the grade force, capped at a_max.
    """
    phi = laws.traction_accel(v, c.a1, c.v1, c.v2, c.a2, c.a3, c.b2, c.b3)
    f = delta * (c.mass * phi) - laws.davis_resistance(v, c.davis_a, c.davis_b, c.davis_c) - fg
    return mn(f / c.meff, c.accel_max)  # type: ignore[no-any-return]


@jit
def traction_step(c: Any, e0: float, h: float, fg: float, delta: float) -> float:
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
def coast_step(c: Any, e0: float, h: float, fg: float) -> tuple[float, float, bool]:
    """:func:`metro_atc.core.ato.strategy.coast_step` of one trajectory: (e1, dt [s], stalled)."""
    m = c.meff
    c0 = (c.davis_a + fg) / m
    c1 = c.davis_b / m
    c2 = c.davis_c / m
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
def strategy_step_one(c: Any, e: float, h: float, fg: float, cap: float, mode: int,
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
    force = c.meff * (e1 - e0) / h \
        + c.davis_a + c.davis_b * vm + c.davis_c * vm * vm + fg
    energy = 0.0 if coast else mx(force, 0.0) * h
    trap = 2.0 * h / mx(v0 + v1, 1e-300) if v0 + v1 > 0.0 else np.inf
    free_coast = coast and not clamped
    dt = dt_c if free_coast else trap
    stalled = (free_coast and st_c) or (e1 <= 0.0 and cap > 1e-9)
    if stalled:
        dt = np.inf
    return e1, dt, energy, stalled
