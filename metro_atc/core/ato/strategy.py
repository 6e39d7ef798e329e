"""Distance-step simulator of driving strategies with closed-form coasting (Ke 2010, 002).

State: kinetic energy per unit mass ``e = v^2 / 2`` [m^2/s^2] at run coordinate s [m].
Steps of length h [m]; every function is vectorised (numpy broadcasting) over trajectories.

Modes (Ke 2010, Sec. 4.2 item 2; ACTP n.d., Sec. 2):

- accelerate: traction at level ``delta`` of the maximum tractive force (ACTP n.d., eq. 3-5),
  net acceleration capped at ``a_max``; integrated with a midpoint (RK2) step in distance;
- cruise: hold a speed; traction limited as above, braking if a down-grade pushes above it;
- coast: no effort.  The coasting speed is the closed-form solution of
  ``dv/dt = -(c0 + c1 v + c2 v^2)`` (ACTP n.d., eq. 7-8), see :func:`coast_speed`;
  within a step the distance relation ``x(v)`` (integral of v dt) is inverted by Newton's
  method and the step time is the closed-form time (ACTP n.d., eq. 8, running-time integral
  eq. 13 for the coasting mode).

Every mode is finally capped by a speed code (ATO command; above it the train brakes at the
planning deceleration) and by the envelope (limits and braking curves).

Reconstruction note (ACTP n.d., eq. 7-8).  The extraction prints eq. 7 as
``v = alpha tan(beta + gamma (C_v - t))``; with the printed constants
``alpha^2 = c0/c2 - c1^2/(4 c2^2)``, ``beta = -c1/(2 c2)``, ``gamma = c2 alpha`` and eq. 8
``C_v = t_c + atan((v_c - beta)/alpha)/gamma`` the consistent solution of the coasting ODE is
``v(t) = beta + alpha tan(gamma (C_v - t))`` (beta is an offset, not a phase).  For steep
down-grades (``alpha^2 < 0``) the tan becomes tanh/coth; both branches are implemented.
"""

from __future__ import annotations

from typing import Optional, Union

import numpy as np
from numpy.typing import ArrayLike, NDArray

from metro_atc.core.ato.envelope import MODE_ACCEL, MODE_COAST, MODE_CRUISE, OperatingLimits
from metro_atc.core.laws import davis_resistance_array, on_array
from metro_atc.core.line.vehicle import TrainParams, max_traction_force

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]
ArrayOrFloat = Union[FloatArray, float]

_TINY = 1e-12


# ----------------------------------------------------------------------------- coasting
def coast_coefficients(train: TrainParams, fg_n: ArrayLike
                       ) -> tuple[FloatArray, float, float]:
    """Coasting deceleration coefficients c0 [m/s^2], c1 [1/s], c2 [1/m] (ACTP n.d., eq. 2, 7).

    ``dv/dt = -(c0 + c1 v + c2 v^2)`` with the Davis terms and the grade force ``fg_n`` [N]
    divided by the effective (rotating-mass) mass.
    """
    m = train.effective_mass_kg
    c0 = (train.davis_a_n + np.asarray(fg_n, dtype=float)) / m
    return c0, train.davis_b_n_per_mps / m, train.davis_c_n_per_mps2 / m


def coast_constants(c0: float, c1: float, c2: float) -> tuple[float, float, float]:
    """Constants (alpha [m/s], beta [m/s], gamma [1/s]) of ACTP n.d., eq. 7 (alpha^2 > 0 case)."""
    a2 = c0 / c2 - c1 * c1 / (4.0 * c2 * c2)
    if a2 <= 0.0:
        raise ValueError("tan form of ACTP n.d., eq. 7 needs c0/c2 > c1^2/(4 c2^2)")
    alpha = float(np.sqrt(a2))
    return alpha, -c1 / (2.0 * c2), c2 * alpha


def coast_speed(t: ArrayLike, t_c: float, v_c: float, c0: float, c1: float,
                c2: float) -> FloatArray:
    """Coasting speed v(t) [m/s] starting at v_c [m/s] at time t_c [s] (ACTP n.d., eq. 7-8).

    ``v(t) = beta + alpha tan(gamma (C_v - t))`` with ``C_v`` from eq. 8; valid until the
    speed reaches zero.
    """
    alpha, beta, gamma = coast_constants(c0, c1, c2)
    c_v = t_c + np.arctan((v_c - beta) / alpha) / gamma  # ACTP n.d., eq. 8
    return beta + alpha * np.tan(gamma * (c_v - np.asarray(t, dtype=float)))


def _coast_x_t(w: FloatArray, d4: FloatArray, c2: float, bp: float
               ) -> tuple[FloatArray, FloatArray]:
    """Closed-form distance X(w) [m] and time T(w) [s] potentials of coasting.

    w = v + c1/(2 c2) = v - beta; d4 = c0/c2 - c1^2/(4 c2^2) (= alpha^2 > 0 or -kappa^2 < 0);
    bp = c1/(2 c2).  With dw/dt = -c2 (w^2 + d4):
    ``T(w) = -atan(w/alpha)/(c2 alpha)`` (ACTP n.d., eq. 8 solved for t), or
    ``ln|(kappa+w)/(kappa-w)|/(2 c2 kappa)`` for d4 < 0, and
    ``X(w) = -ln|w^2 + d4|/(2 c2) - bp T(w)`` (integral of v dt).
    """
    pos = d4 > 0.0
    if np.all(pos):
        a = np.sqrt(d4)
        t = -np.arctan(w / a) / (c2 * a)
        x_log = -0.5 * np.log(w * w + d4) / c2
        return x_log - bp * t, t
    a = np.sqrt(np.where(pos, d4, 1.0))
    k = np.sqrt(np.where(pos, 1.0, -d4))
    t_pos = -np.arctan(w / a) / (c2 * a)
    with np.errstate(divide="ignore", invalid="ignore"):
        t_neg = np.log(np.abs((k + w) / (k - w + _TINY))) / (2.0 * c2 * k)
    t = np.where(pos, t_pos, t_neg)
    x_log = -0.5 * np.log(np.abs(w * w + d4) + _TINY) / c2
    return x_log - bp * t, t


def coast_step(train: TrainParams, e: ArrayLike, h: ArrayOrFloat, fg_n: ArrayLike
               ) -> tuple[FloatArray, FloatArray, BoolArray]:
    """One coasting step of length h [m] from e = v^2/2; returns (e_next, dt [s], stalled).

    Closed form (ACTP n.d., eq. 7-8): the distance covered while the speed goes from v0 to v1 is
    ``X(w1) - X(w0)`` (see :func:`_coast_x_t`); v1 solves ``X(w1) - X(w0) = h`` by a Newton
    step started from an RK4-in-distance estimate, and the step time is ``T(w1) - T(w0)``
    (the coasting term of the running-time integral, ACTP n.d., eq. 13).  ``stalled`` marks
    trajectories that stop within the step.
    """
    c0, c1, c2 = coast_coefficients(train, fg_n)
    e0 = np.maximum(np.asarray(e, dtype=float), 0.0)
    v0 = np.sqrt(2.0 * e0)
    e_guess, stalled = _rk4_coast(e0, h, c0, c1, c2)
    if c2 <= 0.0:  # no quadratic term: RK4 in distance only
        v1 = np.sqrt(2.0 * e_guess)
        with np.errstate(divide="ignore"):
            dt = np.where(v0 + v1 > 0, 2.0 * h / (v0 + v1 + 1e-300), np.inf)
        return e_guess, np.where(stalled, np.inf, dt), stalled
    bp = c1 / (2.0 * c2)
    d4 = c0 / c2 - bp * bp
    d4 = np.where(np.abs(d4) < 1e-9, 1e-9, d4)
    w0 = v0 + bp
    x0, t0 = _coast_x_t(w0, d4, c2, bp)
    w = np.sqrt(2.0 * e_guess) + bp
    x, _ = _coast_x_t(w, d4, c2, bp)
    dxdw = -(w - bp) / (c2 * (w * w + d4))
    ok = ~stalled & (np.abs(dxdw) > _TINY)
    w = np.where(ok, np.maximum(w - (x - x0 - h) / np.where(ok, dxdw, -1.0), bp), w)
    v1 = np.maximum(w - bp, 0.0)
    e1 = np.where(stalled, 0.0, 0.5 * v1 * v1)
    _, t1 = _coast_x_t(np.sqrt(2.0 * e1) + bp, d4, c2, bp)
    dt = t1 - t0
    # guard the ill-conditioned near-equilibrium case with the trapezoid time
    trap = 2.0 * h / np.maximum(v0 + np.sqrt(2.0 * e1), _TINY)
    dt = np.where(np.isfinite(dt) & (dt > 0.0), dt, trap)
    return e1, np.where(stalled, np.inf, dt), stalled


def _rk4_coast(e0: FloatArray, h: ArrayOrFloat, c0: ArrayLike, c1: float, c2: float
               ) -> tuple[FloatArray, BoolArray]:
    """RK4 in distance of de/ds = -(c0 + c1 v + c2 v^2); returns (e1, stalled)."""
    c0a = np.asarray(c0, dtype=float)

    def f(e: FloatArray) -> FloatArray:
        v = np.sqrt(2.0 * np.maximum(e, 0.0))
        return -(c0a + c1 * v + c2 * v * v)

    k1 = f(e0)
    k2 = f(e0 + 0.5 * h * k1)
    k3 = f(e0 + 0.5 * h * k2)
    k4 = f(e0 + h * k3)
    e1 = e0 + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
    stalled = (e1 <= 1e-9) & (c0a > 0.0)
    return np.maximum(e1, 0.0), stalled


# ----------------------------------------------------------------------------- traction
def traction_accel(train: TrainParams, limits: OperatingLimits, v: ArrayLike,
                   fg_n: ArrayLike, delta: ArrayLike) -> FloatArray:
    """Net acceleration [m/s^2] under traction level delta (ACTP n.d., eq. 3-5), capped at a_max.

    v >= 0 [m/s]; the resistance is :func:`metro_atc.core.laws.davis_resistance`.
    """
    va = np.asarray(v, dtype=float)
    f = np.asarray(delta, dtype=float) * max_traction_force(train, va) \
        - on_array(davis_resistance_array, va, train.davis_a_n, train.davis_b_n_per_mps,
                   train.davis_c_n_per_mps2) \
        - np.asarray(fg_n, dtype=float)
    return np.minimum(f / train.effective_mass_kg, limits.accel_max_mps2)


def traction_step(train: TrainParams, limits: OperatingLimits, e: ArrayLike, h: ArrayOrFloat,
                  fg_n: ArrayLike, delta: ArrayLike) -> FloatArray:
    """One traction step of length h [m] (midpoint RK2 in distance on e = v^2/2)."""
    e0 = np.maximum(np.asarray(e, dtype=float), 0.0)
    v0 = np.sqrt(2.0 * e0)
    e_p = np.maximum(e0 + h * traction_accel(train, limits, v0, fg_n, delta), 0.0)
    v_m = 0.5 * (v0 + np.sqrt(2.0 * e_p))
    return np.maximum(e0 + h * traction_accel(train, limits, v_m, fg_n, delta), 0.0)


def strategy_step(train: TrainParams, limits: OperatingLimits, e: ArrayLike, h: ArrayOrFloat,
                  fg_n: ArrayLike, e_cap: ArrayLike, mode: ArrayLike, e_code: ArrayLike,
                  e_hold: ArrayLike, delta: ArrayLike,
                  latch: Optional[NDArray[np.bool_]] = None
                  ) -> tuple[FloatArray, FloatArray, FloatArray, BoolArray]:
    """Advance trajectories by h [m]; returns (e_next, dt [s], traction energy [J], stalled).

    e: state v^2/2; fg_n: mean grade force over the step [N]; e_cap: envelope at the end of
    the step; mode: MODE_* (scalar or array); e_code: speed code as v^2/2 (the train brakes
    at the planning deceleration when above it); e_hold: cruise speed as v^2/2; delta:
    traction level in (0, 1].  latch (optional, updated in place): accelerate-mode
    trajectories that have reached their speed code coast from then on (Ke 2010
    "acceleration mode": accelerate to the code; the section's remainder is coasted).
    """
    e0 = np.maximum(np.asarray(e, dtype=float), 0.0)
    mode_a = np.asarray(mode)
    if latch is not None:
        mode_a = np.where(latch & (mode_a == MODE_ACCEL), MODE_COAST, mode_a)
    scalar_mode = mode_a.ndim == 0
    need_trac = (not scalar_mode) or int(mode_a) in (MODE_ACCEL, MODE_CRUISE)
    need_coast = (not scalar_mode) or int(mode_a) == MODE_COAST
    e_t = traction_step(train, limits, e0, h, fg_n, delta) if need_trac else e0
    if need_coast:
        e_c, dt_c, st_c = coast_step(train, e0, h, fg_n)
    else:
        e_c, dt_c, st_c = e0, np.zeros_like(e0), np.zeros(e0.shape, dtype=bool)
    e_hold_a = np.asarray(e_hold, dtype=float)
    if scalar_mode:
        m = int(mode_a)
        e_m = e_t if m == MODE_ACCEL else (
            np.minimum(e_t, e_hold_a) if m == MODE_CRUISE else e_c)
        is_coast = np.full(e0.shape, m == MODE_COAST)
    else:
        e_m = np.where(mode_a == MODE_ACCEL, e_t,
                       np.where(mode_a == MODE_CRUISE, np.minimum(e_t, e_hold_a), e_c))
        is_coast = mode_a == MODE_COAST
    e_code_cap = np.maximum(np.asarray(e_code, dtype=float), e0 - limits.brake_decel_mps2 * h)
    cap = np.minimum(e_code_cap, np.asarray(e_cap, dtype=float))
    e1 = np.maximum(np.minimum(e_m, cap), 0.0)
    clamped = e_m > cap
    v0 = np.sqrt(2.0 * e0)
    v1 = np.sqrt(2.0 * e1)
    vm = 0.5 * (v0 + v1)
    force = train.effective_mass_kg * (e1 - e0) / h \
        + train.davis_a_n + train.davis_b_n_per_mps * vm + train.davis_c_n_per_mps2 * vm * vm \
        + np.asarray(fg_n, dtype=float)
    energy = np.where(is_coast, 0.0, np.maximum(force, 0.0) * h)
    with np.errstate(divide="ignore"):
        trap = np.where(v0 + v1 > 0.0, 2.0 * h / np.maximum(v0 + v1, 1e-300), np.inf)
    dt = np.where(is_coast & ~clamped, dt_c, trap)
    stalled = (is_coast & ~clamped & st_c) | ((e1 <= 0.0) & (np.asarray(e_cap) > 1e-9))
    dt = np.where(stalled, np.inf, dt)
    if latch is not None:
        latch |= (mode_a == MODE_ACCEL) & (e1 >= np.asarray(e_code, dtype=float) * (1 - 1e-9))
    return e1, dt, energy, stalled
