"""The distance step of the driving strategies, compiled: the planners' one step (Ke 2010).

State: kinetic energy per unit mass ``e = v^2 / 2`` [m^2/s^2] at run coordinate s [m], steps
of length h [m].  Modes (Ke 2010, Sec. 4.2 item 2; ACTP n.d., Sec. 2):

- accelerate: traction at level ``delta`` of the maximum tractive force (ACTP n.d., eq. 3-5),
  net acceleration capped at ``a_max``; integrated with a midpoint (RK2) step in distance;
- cruise: hold a speed; traction limited as above, braking if a down-grade pushes above it;
- coast: no effort.  The coasting speed is the closed-form solution of
  ``dv/dt = -(c0 + c1 v + c2 v^2)`` (ACTP n.d., eq. 7-8,
  :func:`metro_atc.core.ato.strategy.coast_speed`); within a step the distance relation
  ``x(v)`` (integral of v dt) is inverted by one Newton step from an RK4-in-distance guess
  and the step time is the closed-form time (ACTP n.d., eq. 8, running-time integral
  eq. 13 for the coasting mode).

Every mode is finally capped by a speed code (ATO command; above it the train brakes at the
planning deceleration) and by the envelope (limits and braking curves); the trapezoid time
otherwise.  :func:`strategy_step` is that step for one trajectory, written once: the
pre-work tables of MMAS (:mod:`metro_atc.core.ato.sections`) and of the DP
(:mod:`metro_atc.core.ato.dp`) run it through :func:`run_substeps`, the ECTP/ACTP loops
(:mod:`metro_atc.core.ato.switching_kernel`) and the DP's exact simulations
(:mod:`metro_atc.core.ato.dp_kernel`) through :func:`strategy_step_one` (no speed code).
``NUMBA_DISABLE_JIT=1`` runs the same source as Python.

Train and limit constants travel as one record (:data:`TRAIN`, :func:`pack_train`; the
kernels' entry points take the one-element array and hand its record ``c[0]`` down).
"""

from __future__ import annotations

import math
from typing import Any, Callable

import numpy as np
from numpy.typing import NDArray

from metro_atc.core.ato.envelope import MODE_ACCEL, MODE_COAST, MODE_CRUISE, OperatingLimits
from metro_atc.core import laws
from metro_atc.core.line.vehicle import TrainParams

FloatArray = NDArray[np.float64]

TRAIN_FIELDS = ("mass", "meff", "davis_a", "davis_b", "davis_c", "a1", "v1", "v2", "a2", "a3",
                "b2", "b3", "accel_max")
"""Fields of :data:`TRAIN`: mass, effective mass [kg], Davis a [N], b [N s/m], c [N s^2/m^2],
the traction curve (a1 [m/s^2], v1, v2 [m/s], a2 [m^2/s^3], a3 [m^3/s^4], b2, b3 [m/s]) and
the planning acceleration limit [m/s^2]."""
TRAIN = np.dtype((np.record, [(f, np.float64) for f in TRAIN_FIELDS]))
"""The train and limit constants the kernels read, by name (one-element arrays; a
``np.record`` dtype: attribute access also when ``NUMBA_DISABLE_JIT=1`` runs them as
Python)."""

TINY = 1e-12


def jit(fn: Callable[..., Any]) -> Callable[..., Any]:
    """Compile ``fn`` with numba (cached, numpy error model; numba is a pinned dependency)."""
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
    """Net acceleration [m/s^2] under traction level delta at one speed v >= 0 [m/s].

    Level ``delta`` of :func:`metro_atc.core.laws.traction_accel` less
    :func:`metro_atc.core.laws.davis_resistance` and the grade force, capped at a_max.
    """
    phi = laws.traction_accel(v, c.a1, c.v1, c.v2, c.a2, c.a3, c.b2, c.b3)
    f = delta * (c.mass * phi) - laws.davis_resistance(v, c.davis_a, c.davis_b, c.davis_c) - fg
    return mn(f / c.meff, c.accel_max)  # type: ignore[no-any-return]


@jit
def traction_step(c: Any, e0: float, h: float, fg: float, delta: float) -> float:
    """One traction step of length h [m] (midpoint RK2 in distance on e = v^2/2, e0 >= 0)."""
    v0 = math.sqrt(2.0 * e0)
    e_p = mx(e0 + h * traction_accel(c, v0, fg, delta), 0.0)
    v_m = 0.5 * (v0 + math.sqrt(2.0 * e_p))
    return mx(e0 + h * traction_accel(c, v_m, fg, delta), 0.0)  # type: ignore[no-any-return]


@jit
def coast_x_t(w: float, d4: float, c2: float, bp: float) -> tuple[float, float]:
    """Closed-form distance X(w) [m] and time T(w) [s] potentials of coasting (d4 != 0).

    w = v + c1/(2 c2) = v - beta; d4 = c0/c2 - c1^2/(4 c2^2) (= alpha^2 > 0 or -kappa^2 < 0);
    bp = c1/(2 c2).  With dw/dt = -c2 (w^2 + d4): ``T(w) = -atan(w/alpha)/(c2 alpha)``
    (ACTP n.d., eq. 8 solved for t), or ``ln|(kappa+w)/(kappa-w)|/(2 c2 kappa)`` for
    d4 < 0, and ``X(w) = -ln|w^2 + d4|/(2 c2) - bp T(w)`` (integral of v dt).
    """
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
    """de/ds of coasting (the RK4-in-distance guess of :func:`coast_step`)."""
    v = math.sqrt(2.0 * mx(e, 0.0))
    return -(c0 + c1 * v + c2 * v * v)


@jit
def coast_coefficients(c: Any, fg: float) -> tuple[float, float, float]:
    """Coasting deceleration coefficients c0 [m/s^2], c1 [1/s], c2 [1/m] (ACTP n.d., eq. 2, 7).

    ``dv/dt = -(c0 + c1 v + c2 v^2)`` with the Davis terms and the grade force ``fg`` [N]
    divided by the effective (rotating-mass) mass.
    """
    m = c.meff
    return (c.davis_a + fg) / m, c.davis_b / m, c.davis_c / m


@jit
def coast_step(c: Any, e0: float, h: float, fg: float) -> tuple[float, float, bool]:
    """One coasting step of length h [m] from e0 = v^2/2: (e1, dt [s], stalled).

    Closed form (ACTP n.d., eq. 7-8): v1 solves ``X(w1) - X(w0) = h`` (:func:`coast_x_t`)
    by a Newton step started from an RK4-in-distance estimate; the step time is
    ``T(w1) - T(w0)`` (the trapezoid time where that is ill-conditioned).  ``stalled``: the
    trajectory stops within the step.
    """
    c0, c1, c2 = coast_coefficients(c, fg)
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
def strategy_step(c: Any, e: float, h: float, fg: float, e_cap: float, mode: int,
                  e_code: float, e_hold: float, delta: float, brake_decel: float,
                  latch: bool) -> tuple[float, float, float, bool, bool]:
    """Advance one trajectory by h [m]: (e_next, dt [s], traction energy [J], stalled, latch).

    e: state v^2/2 [m^2/s^2]; fg: mean grade force over the step [N]; e_cap: envelope at
    the end of the step; ``mode``: MODE_ACCEL (traction at level ``delta``), MODE_CRUISE
    (the same, capped at ``e_hold``) or MODE_COAST; e_code: speed code as v^2/2 (above it
    the train brakes at ``brake_decel`` [m/s^2]; inf: none); latch: an accelerate-mode
    trajectory that has reached its speed code coasts from then on (Ke 2010 "acceleration
    mode": accelerate to the code; the section's remainder is coasted), returned updated.
    dt is inf when stalled.
    """
    e0 = mx(e, 0.0)
    if latch and mode == MODE_ACCEL:
        mode = MODE_COAST
    dt_c = 0.0
    st_c = False
    coast = mode == MODE_COAST
    if coast:
        e_m, dt_c, st_c = coast_step(c, e0, h, fg)
    else:
        e_m = traction_step(c, e0, h, fg, delta)
        if mode == MODE_CRUISE:
            e_m = mn(e_m, e_hold)
    cap = mn(mx(e_code, e0 - brake_decel * h), e_cap)
    e1 = mx(mn(e_m, cap), 0.0)
    clamped = e_m > cap
    v0 = math.sqrt(2.0 * e0)
    v1 = math.sqrt(2.0 * e1)
    vm = 0.5 * (v0 + v1)
    force = laws.step_force(c.meff, e0, e1, h, vm, c.davis_a, c.davis_b, c.davis_c, fg)
    energy = 0.0 if coast else mx(force, 0.0) * h
    trap = 2.0 * h / mx(v0 + v1, 1e-300) if v0 + v1 > 0.0 else np.inf
    free_coast = coast and not clamped
    dt = dt_c if free_coast else trap
    stalled = (free_coast and st_c) or (e1 <= 0.0 and e_cap > 1e-9)
    if stalled:
        dt = np.inf
    latch = latch or (mode == MODE_ACCEL and e1 >= e_code * (1 - 1e-9))
    return e1, dt, energy, stalled, latch


@jit
def strategy_step_one(c: Any, e: float, h: float, fg: float, cap: float, mode: int,
                      e_hold: float, delta: float) -> tuple[float, float, float, bool]:
    """:func:`strategy_step` with no speed code and no latch (the ECTP/ACTP and DP loops).

    Returns (e_next [m^2/s^2], dt [s] (inf when stalled), traction energy [J], stalled).
    """
    e1, dt, energy, stalled, _ = strategy_step(c, e, h, fg, cap, mode, np.inf, e_hold, delta,
                                               0.0, False)
    return e1, dt, energy, stalled


@jit
def run_substeps(p: Any, e_in: FloatArray, h: float, fg: FloatArray, e_cap: FloatArray,
                 mode: int, e_code: FloatArray, e_hold: FloatArray, delta: float,
                 brake_decel: float, latch: NDArray[np.bool_], finite_time: bool
                 ) -> tuple[FloatArray, FloatArray, FloatArray, NDArray[np.bool_]]:
    """Trajectories through the sub-steps of their stage: (e, time [s], energy [J], stalled).

    The tables' pre-work (:mod:`metro_atc.core.ato.sections`, :mod:`metro_atc.core.ato.dp`):
    every trajectory in one ``mode`` by :func:`strategy_step`, sub-steps of h [m]; ``p``:
    the train constants (:func:`pack_train`, as a record array).
    Trajectory i of the (n,) arrays ``e_in``, ``e_code``, ``e_hold`` and ``latch`` (the
    latch's start) belongs to stage ``i // (n // n_g)`` of the (n_g, n_sub) sub-step grade
    forces ``fg`` [N] and end-of-step envelopes ``e_cap`` [m^2/s^2] (trajectories grouped
    by stage, in order).  The time sums the finite step times only when ``finite_time``
    (else a stalled trajectory's is inf).
    """
    c = p[0]
    n = e_in.shape[0]
    n_g, n_sub = fg.shape
    per = n // n_g
    e_out = np.empty(n)
    t_out = np.empty(n)
    j_out = np.empty(n)
    st_out = np.zeros(n, dtype=np.bool_)
    for i in range(n):
        g = i // per
        e = e_in[i]
        lt = latch[i]
        t = 0.0
        en = 0.0
        stalled = False
        for q in range(n_sub):
            e, dt, de, st, lt = strategy_step(c, e, h, fg[g, q], e_cap[g, q], mode, e_code[i],
                                              e_hold[i], delta, brake_decel, lt)
            if finite_time:
                t += dt if math.isfinite(dt) else 0.0
            else:
                t += dt
            en += de
            stalled = stalled or st
        e_out[i] = e
        t_out[i] = t
        j_out[i] = en
        st_out[i] = stalled
    return e_out, t_out, j_out, st_out
