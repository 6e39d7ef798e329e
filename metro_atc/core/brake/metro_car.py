"""Metro variant of the brake-by-wire diagnosis: one 4-axle car, wheel-rail adhesion.

The Lin 2010b observer transferred to a metro car whose friction brake is
brake-by-wire per axle (one axle-mounted disc, two pads, clamp force F_cj measured):

* car:    ``M dv/dt = sum_j F_j - M phi_r(v) - M g sin(theta)``
  (phi_r: Davis deceleration of ACTP n.d., eq. 2, theta: gradient);
* axle j: ``J dw_j/dt = T_dj - 2 mu_b R_b F_cj tanh(w_j / w_eps) - r_w F_j``
  (Lin 2010b, eq. 4; ``T_dj`` = motor torque, >0 traction, <0 electric brake, known
  to the brake control unit; ``F_j`` = longitudinal wheel-rail force on the car,
  negative while braking);
* wheel-rail adhesion instead of tyre forces:
  ``F_j = N_j mu_a(s_j)``, creep ``s_j = (r_w w_j - v) / max(v, v_min)``,
  ``mu_a(s) = mu_max (2/pi) atan(k_s s) ((1 - A) exp(-B |s|) + A)``
  (a creep-force curve with a falling branch; the shape and numbers are estimates).

Observer (UKF, alpha 0.5, beta 2, kappa 3 - L): state
``[v, w_1..w_4, mu_b, sin(theta), (F_j, dF_j/dt, d2F_j/dt2) j = 1..4]`` (L = 19; mu_b
constant, eq. 9, with a small random walk so that a pad fault occurring in service is
tracked; the gradient is a slow random walk; each axle force is the triple integrator
of eq. 10); measured ``w_1..w_4, a_x`` (specific force) and the reference speed ``v``
(eq. 8); inputs the clamp forces and motor torques.

Residual generator: estimated axle force minus the adhesion model evaluated at the
estimated creep (the "target"), divided by the axle's adhesion capacity
``N_j mu_rail`` so that one dimensionless threshold serves dry and wet rail (the
creep-curve uncertainty makes force residuals scale with the adhesion level);
decision logic: :mod:`metro_atc.core.brake.diagnosis`.

Parameters are estimates for a Taipei-MRT-class car (aligned with the line plant's
``TrainParams``: 214 t / 6 cars, r_w 0.43 m, J 120 kg m^2, R_b 0.25 m, mu_b 0.35).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any, Callable, Optional, Sequence

import numpy as np
from numpy.typing import ArrayLike

from metro_atc.core import laws
from metro_atc.core.brake import diagnosis as dg
from metro_atc.core.brake.metro_kernel import MetroUKF
from metro_atc.core.brake.ukf import UKF, BatchUKF, symmetrize
from metro_atc.core.line.adhesion import AdhesionCurve

G = 9.80665
"""Standard gravity [m/s^2]."""
FloatArray = np.ndarray
N_AX = 4
"""Axles per car."""


@dataclass(frozen=True)
class MetroCarParams:
    """Metro car data (all estimates, documented)."""

    mass: float = 214_000.0 / 6.0
    """Car mass incl. nominal load [kg] (line plant TrainParams 214 t / 6 cars)."""
    r_w: float = 0.43
    """Wheel rolling radius [m] (860 mm wheel)."""
    j_w: float = 120.0
    """Wheelset moment of inertia incl. brake disc [kg m^2]."""
    r_b: float = 0.25
    """Disc-pad effective friction radius [m]."""
    mu_b: float = 0.35
    """Nominal disc-pad friction coefficient [-]."""
    mu_b_min: float = 0.2
    """Safety requirement on mu_b [-] (Lin 2010b)."""
    davis: tuple[float, float, float] = (0.020084, 5.04e-4, 4.774e-5)
    """Davis deceleration phi_r(v) = a + b v + c v^2 [m/s^2] (ACTP n.d., eq. 2)."""
    adh_k: float = 300.0
    """Initial slope factor k_s of the creep curve [-]."""
    adh_a: float = 0.4
    """Asymptotic fraction A of the falling branch [-]."""
    adh_b: float = 5.0
    """Decay rate B of the falling branch [-]."""
    mu_rail: float = 0.3
    """Adhesion limit of the rail condition assumed by the target model [-] (dry)."""
    tau_act: float = 0.25
    """Clamp-force actuator time constant [s]."""
    wsp_slip: float = 0.05
    """Wheel-slide-protection creep threshold [-]."""
    wsp_gain: float = 60.0
    """WSP integral gain on the creep error [1/s]."""
    w_eps: float = 0.5
    """Smoothing speed of the brake-torque sign [rad/s]."""
    v_min: float = 2.0
    """Speed floor of the creep definition [m/s]."""

    def davis_decel(self, v: FloatArray) -> FloatArray:
        """Running-resistance deceleration phi_r(v) [m/s^2] (ACTP n.d., eq. 2), v [m/s]."""
        a, b, c = self.davis
        return np.asarray(laws.on_array(laws.davis_resistance_array, v, a, b, c)
                          * np.sign(v))

    def clamp_for_decel(self, a_req: FloatArray) -> FloatArray:
        """Per-axle clamp force [N] giving deceleration ``a_req`` with nominal mu_b.

        Brake torque per axle ``2 mu_b R_b F_c`` (Lin 2010b, eq. 4), equal shares.
        """
        return np.asarray(a_req) * self.mass * self.r_w / (
            N_AX * laws.pad_torque(1.0, self.mu_b, self.r_b))


def from_train_params(tp: object) -> MetroCarParams:
    """Build car parameters from a line-plant ``TrainParams``-like object (duck-typed).

    Uses ``mass_kg / cars``, ``wheel_radius_m``, ``wheel_inertia_kgm2``,
    ``brake_radius_m`` and ``pad_mu_nominal`` when present.
    """
    p = MetroCarParams()
    kw: dict[str, Any] = {}
    cars = float(getattr(tp, "cars", 6))
    if hasattr(tp, "mass_kg"):
        kw["mass"] = float(getattr(tp, "mass_kg")) / cars
    for src, dst in (("wheel_radius_m", "r_w"), ("wheel_inertia_kgm2", "j_w"),
                     ("brake_radius_m", "r_b"), ("pad_mu_nominal", "mu_b")):
        if hasattr(tp, src):
            kw[dst] = float(getattr(tp, src))
    return replace(p, **kw)


def adhesion(s: FloatArray, mu_max: FloatArray | float, p: MetroCarParams,
             k_scale: FloatArray | float = 1.0) -> FloatArray:
    """Adhesion coefficient mu_a(s) of the creep ``s`` [-] (odd in s)."""
    fall = (1.0 - p.adh_a) * np.exp(-p.adh_b * np.abs(s)) + p.adh_a
    return mu_max * (2.0 / np.pi) * np.arctan(p.adh_k * k_scale * s) * fall


# ----------------------------------------------------------------------------------------
# Truth plant
# ----------------------------------------------------------------------------------------

METRO_MANEUVERS = ("service_brake", "ato_steps")
"""Metro driver signals: constant 1.0 m/s^2 service brake; ATO brake steps 0.6/1.1/0.8."""
METRO_RAILS = (0.30, 0.15)
"""Rail adhesion limits: dry, wet (estimates)."""
METRO_FAULTS = ("none", "pad", "wheel")
"""Cases: normal, pads mu_b = 0.1 on every axle, defective wheel(set) on axle 2."""
WHEEL_FAULT_AXLE = 1
"""Index (0-based) of the axle with the defective wheelset."""
WHEEL_FAULT_SCALE = 0.35
"""Adhesion-limit and creep-slope multiplier of the defective wheelset (tread damage /
contamination; our fault model)."""
METRO_BRAKE_ONSET_S = 0.5
"""Start of the brake application [s]."""


def metro_brake_demand(maneuver: FloatArray, t: float) -> FloatArray:
    """Requested friction-brake deceleration [m/s^2] (jerk-limited to 2 m/s^3)."""
    m = np.asarray(maneuver)
    tb = t - METRO_BRAKE_ONSET_S
    ramp = float(np.clip(tb / 0.5, 0.0, 1.0))
    steps = 0.6 if tb < 2.5 else (1.1 if tb < 5.0 else 0.8)
    return np.where(m == 0, 1.0 * ramp, steps * ramp).astype(float)


@dataclass
class MetroScenario:
    """One run of the car: manoeuvre, rail, fault and dispersion.

    Attributes:
        maneuver: 0 service brake, 1 ATO steps.
        mu_rail: adhesion limit of the rail [-].
        fault: "none", "pad" or "wheel".
        mu_b: true mu_b (None: 0.1 for "pad", nominal else).
        mass_scale: true mass / nominal [-].
        adh_scale: true creep-curve scale (mu_max and slope) / nominal [-].
        grade: sin of the gradient [-] (positive uphill).
        fault_time: time at which the fault appears [s].
    """

    maneuver: int
    mu_rail: float
    fault: str = "none"
    mu_b: Optional[float] = None
    mass_scale: float = 1.0
    adh_scale: float = 1.0
    grade: float = 0.0
    fault_time: float = 0.0


@dataclass
class MetroLog:
    """Sampled truth of a batch of metro runs, arrays (B, n_t[, 4])."""

    t: FloatArray
    v: FloatArray
    omega: FloatArray
    force: FloatArray
    fc: FloatArray
    ax: FloatArray
    mu_b: FloatArray
    mass: FloatArray


def simulate_metro(p: MetroCarParams, scenarios: Sequence[MetroScenario], t_end: float = 8.0,
                   dt: float = 1e-3, sample_dt: float = 0.02,
                   v0: float = 80.0 / 3.6) -> MetroLog:
    """Simulate a batch of car runs with RK4 (state: v, w_1..4, WSP gains, F_c).

    The brake control unit converts the demand into clamp forces with the nominal
    mu_b; wheel-slide protection reduces an axle's clamp force (integral action)
    while its creep exceeds ``wsp_slip``; the actuator is first order.  The creep
    dynamics are stiff: the explicit step needs roughly
    ``dt < 2.5 J max(v, v_min) / (r_w^2 N dmu_a/ds)`` (about 1 ms above 5 m/s with
    the default data); the runs here stay above 10 m/s.  A line simulator reusing
    this model for the sensor topic should sub-step accordingly.

    Returns:
        Samples every ``sample_dt`` (``ax`` is the accelerometer's specific force).
    """
    nb = len(scenarios)
    man = np.array([s.maneuver for s in scenarios])
    mass = p.mass * np.array([s.mass_scale for s in scenarios])
    grade = np.array([s.grade for s in scenarios])
    mub_ok = np.array([s.mu_b if (s.mu_b is not None and s.fault != "pad") else p.mu_b
                       for s in scenarios])
    mub_bad = np.array([0.1 if s.mu_b is None else s.mu_b for s in scenarios])
    is_pad = np.array([s.fault == "pad" for s in scenarios])
    t_fault = np.array([s.fault_time for s in scenarios])
    mu_max = np.array([s.mu_rail * s.adh_scale for s in scenarios])[:, None] * np.ones(N_AX)
    kscale = np.array([s.adh_scale for s in scenarios])[:, None] * np.ones(N_AX)
    wheel_bad = np.array([s.fault == "wheel" for s in scenarios])
    nload = (mass * G / N_AX)[:, None]

    x = np.zeros((nb, 13))        # v, w(4), wsp gain(4), fc(4)
    x[:, 0] = v0
    x[:, 1:5] = v0 / p.r_w
    x[:, 5:9] = 1.0

    def deriv(x: FloatArray, fc_cmd: FloatArray, mub: FloatArray, mmax: FloatArray,
              ks: FloatArray) -> tuple[FloatArray, FloatArray]:
        v = x[:, 0]
        om, g, fc = x[:, 1:5], x[:, 5:9], x[:, 9:13]
        den = np.maximum(np.abs(v), p.v_min)[:, None]
        s = (p.r_w * om - v[:, None]) / den
        f = nload * adhesion(s, mmax, p, ks)
        dx = np.empty_like(x)
        spec = f.sum(1) / mass - p.davis_decel(v)
        dx[:, 0] = spec - G * grade
        tb = laws.pad_torque(fc, mub[:, None], p.r_b) * np.tanh(om / p.w_eps)
        dx[:, 1:5] = (-tb - p.r_w * f) / p.j_w
        dg_ = p.wsp_gain * (p.wsp_slip - np.abs(s))
        dg_ = np.where((g >= 1.0) & (dg_ > 0), 0.0, dg_)
        dg_ = np.where((g <= 0.0) & (dg_ < 0), 0.0, dg_)
        dx[:, 5:9] = dg_
        dx[:, 9:13] = (np.clip(g, 0.0, 1.0) * fc_cmd - fc) / p.tau_act
        return dx, np.concatenate((f, spec[:, None]), axis=1)

    n_sub = int(round(sample_dt / dt))
    n_s = int(round(t_end / sample_dt)) + 1
    out = {k: np.zeros((nb, n_s)) for k in ("v", "ax", "mu_b")}
    out4 = {k: np.zeros((nb, n_s, N_AX)) for k in ("omega", "force", "fc")}
    for k in range(n_s):
        for j in range(n_sub if k < n_s - 1 else 1):
            t = k * sample_dt + j * dt
            active = t >= t_fault
            mub = np.where(is_pad & active, mub_bad, mub_ok)
            mmax = mu_max.copy()
            ks = kscale.copy()
            wb = wheel_bad & active
            mmax[wb, WHEEL_FAULT_AXLE] *= WHEEL_FAULT_SCALE
            ks[wb, WHEEL_FAULT_AXLE] *= WHEEL_FAULT_SCALE
            fc_cmd = (p.clamp_for_decel(metro_brake_demand(man, t + 0.5 * dt))[:, None]
                      * np.ones(N_AX))
            if j == 0:
                _, fo = deriv(x, fc_cmd, mub, mmax, ks)
                out["v"][:, k], out["ax"][:, k], out["mu_b"][:, k] = x[:, 0], fo[:, 4], mub
                out4["omega"][:, k], out4["force"][:, k] = x[:, 1:5], fo[:, :4]
                out4["fc"][:, k] = x[:, 9:13]
                if k == n_s - 1:
                    break
            k1, _ = deriv(x, fc_cmd, mub, mmax, ks)
            k2, _ = deriv(x + 0.5 * dt * k1, fc_cmd, mub, mmax, ks)
            k3, _ = deriv(x + 0.5 * dt * k2, fc_cmd, mub, mmax, ks)
            k4, _ = deriv(x + dt * k3, fc_cmd, mub, mmax, ks)
            x = x + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
            x[:, 5:9] = np.clip(x[:, 5:9], 0.0, 1.0)
    tt = np.arange(n_s) * sample_dt
    return MetroLog(t=np.broadcast_to(tt, (nb, n_s)).copy(), v=out["v"], omega=out4["omega"],
                    force=out4["force"], fc=out4["fc"], ax=out["ax"], mu_b=out["mu_b"],
                    mass=mass)


@dataclass(frozen=True)
class MetroSensorNoise:
    """Sensor noise standard deviations (estimates)."""

    omega: float = 0.05
    """Axle speed (tachometer) [rad/s]."""
    ax: float = 0.03
    """Longitudinal accelerometer [m/s^2]."""
    v_ref: float = 0.05
    """Reference speed (Doppler radar / ATP odometry) [m/s]."""
    fc_rel: float = 0.01
    """Clamp-force sensor, relative [-]."""
    fc_abs: float = 100.0
    """Clamp-force sensor, absolute [N]."""


def measure_metro(log: MetroLog, noise: MetroSensorNoise, rng: np.random.Generator
                  ) -> dict[str, FloatArray]:
    """Noisy samples: ``y`` (B, n_t, 6) = w_1..w_4, a_x, v_ref; ``fc`` (B, n_t, 4)."""
    y = np.concatenate((log.omega, log.ax[..., None], log.v[..., None]), axis=-1)
    sig = np.array([noise.omega] * N_AX + [noise.ax, noise.v_ref])
    y = y + rng.standard_normal(y.shape) * sig
    fc = log.fc + rng.standard_normal(log.fc.shape) * (noise.fc_abs + noise.fc_rel * log.fc)
    return {"y": y, "fc": fc}


# ----------------------------------------------------------------------------------------
# Observer
# ----------------------------------------------------------------------------------------

M_NX = 19
"""Metro observer state dimension."""
M_NY = 6
"""Measured outputs: w_1..w_4, a_x, v_ref."""
M_IV, M_IMUB, M_IGRADE = 0, 5, 6
M_IW = slice(1, 5)
M_IF = np.array([7, 10, 13, 16])
"""Indices of the axle forces F_1..F_4 (each followed by two derivatives)."""


@dataclass(frozen=True)
class MetroObserverTuning:
    """Observer noise tuning (our choice)."""

    q_v: float = 0.005
    """Process noise std of v per step [m/s]."""
    q_w: float = 0.05
    """Process noise std of the axle speeds per step [rad/s]."""
    q_mub: float = 1e-3
    """Random-walk std of mu_b per step [-] (lets a pad fault in service be tracked)."""
    q_grade: float = 2e-4
    """Random-walk std of sin(theta) per step [-]."""
    q_f: tuple[float, float, float] = (100.0, 2000.0, 2.0e4)
    """Std per step of (F, dF/dt, d2F/dt2) [N, N/s, N/s^2] (Lin 2010b, eq. 10)."""
    p0_mub: float = 0.1
    """Initial std of mu_b [-]."""
    p0_f: float = 3000.0
    """Initial std of the axle forces [N]."""
    p0_grade: float = 0.02
    """Initial std of sin(theta) [-]."""


def metro_transition(dt: float) -> FloatArray:
    """Linear part of the discretised metro observer (19 x 19).

    Identity, the force chains of eq. 10, ``v -= dt g sin(theta)`` and
    ``w_j -= dt r_w F_j / J`` (the latter needs the car parameters: see
    :func:`metro_linear_part`).
    """
    a = np.eye(M_NX)
    ch = np.array([[1.0, dt, 0.5 * dt * dt], [0.0, 1.0, dt], [0.0, 0.0, 1.0]])
    for i0 in M_IF:
        a[i0:i0 + 3, i0:i0 + 3] = ch
    return a


def metro_linear_part(p: MetroCarParams, dt: float) -> FloatArray:
    """Matrix A with ``x' = A x + (nonlinear terms)`` for the metro observer (19 x 19)."""
    a = metro_transition(dt)
    a[M_IV, M_IGRADE] = -dt * G
    for j, i0 in enumerate(M_IF):
        a[1 + j, i0] = -dt * p.r_w / p.j_w
    return a


def make_metro_fx(p: MetroCarParams, dt_nominal: float):  # type: ignore[no-untyped-def]
    """Vectorised observer transition f(X, u, dt) (Lin 2010b, eq. 4, 9, 10; Euler step).

    ``u`` = (F_c1..4 [N], T_d1..4 [N m], M [kg]); X (..., N, 19).  Written as a linear
    map plus the nonlinear terms (pad torque ``mu_b F_c tanh(w)``, resistance, 1/M) to
    keep the number of array operations per step small.
    """
    k_w = 2.0 * p.r_b / p.j_w
    inv_eps = 1.0 / p.w_eps
    da, db, dc = p.davis
    cache: dict[float, FloatArray] = {dt_nominal: metro_linear_part(p, dt_nominal).T}

    def fx(xs: FloatArray, u: FloatArray, dt: float) -> FloatArray:
        a = cache.get(dt)
        if a is None:  # time stamps jitter by round-off: key the cache on microseconds
            key = round(dt * 1e6) * 1e-6
            a = cache.get(key)
            if a is None:
                a = metro_linear_part(p, key).T
                if len(cache) < 256:
                    cache[key] = a
        out = xs @ a
        v = xs[..., 0]
        acc = xs[..., 7:19:3].sum(-1) / u[..., 8:9]
        acc -= laws.on_array(laws.davis_odd_array, v, da, db, dc)
        out[..., 0] += dt * acc
        brake = np.tanh(xs[..., 1:5] * inv_eps)
        brake *= xs[..., 5:6]
        brake *= u[..., None, 0:4]
        brake *= -dt * k_w
        brake += (dt / p.j_w) * u[..., None, 4:8]
        out[..., 1:5] += brake
        return out

    return fx


def make_metro_hx(p: MetroCarParams):  # type: ignore[no-untyped-def]
    """Vectorised observer output h(X, u) = (w_1..w_4, a_x, v) (Lin 2010b, eq. 8).

    ``a_x`` is the accelerometer's specific force ``sum F / M - phi_r(v)``.
    """
    da, db, dc = p.davis
    sel = np.zeros((M_NX, M_NY))
    for j in range(N_AX):
        sel[1 + j, j] = 1.0
    sel[M_IV, 5] = 1.0

    def hx(xs: FloatArray, u: FloatArray) -> FloatArray:
        out = xs @ sel
        v = xs[..., 0]
        out[..., 4] = xs[..., 7:19:3].sum(-1) / u[..., 8:9]
        out[..., 4] -= laws.on_array(laws.davis_odd_array, v, da, db, dc)
        return out

    return hx


def metro_noise(tuning: MetroObserverTuning, noise: MetroSensorNoise
                ) -> tuple[FloatArray, FloatArray]:
    """Process (per step) and measurement noise covariances (19 x 19, 6 x 6)."""
    q = np.zeros(M_NX)
    q[M_IV] = tuning.q_v ** 2
    q[M_IW] = tuning.q_w ** 2
    q[M_IMUB] = tuning.q_mub ** 2
    q[M_IGRADE] = tuning.q_grade ** 2
    for i0 in M_IF:
        q[i0:i0 + 3] = np.square(tuning.q_f)
    r = np.diag([noise.omega ** 2] * N_AX + [noise.ax ** 2, noise.v_ref ** 2])
    return np.diag(q), r


def metro_prior(p: MetroCarParams, tuning: MetroObserverTuning, v0: float,
                omega0: Optional[FloatArray] = None) -> tuple[FloatArray, FloatArray]:
    """Observer prior: measured speed, nominal mu_b, level track, zero forces."""
    x0 = np.zeros(M_NX)
    x0[M_IV] = v0
    x0[M_IW] = v0 / p.r_w if omega0 is None else omega0
    x0[M_IMUB] = p.mu_b
    d = np.zeros(M_NX)
    d[M_IV] = 0.2 ** 2
    d[M_IW] = 0.2 ** 2
    d[M_IMUB] = tuning.p0_mub ** 2
    d[M_IGRADE] = tuning.p0_grade ** 2
    for i0 in M_IF:
        d[i0:i0 + 3] = [tuning.p0_f ** 2, 1.0e4 ** 2, 1.0e5 ** 2]
    return x0, np.diag(d)


def make_metro_ukf(p: MetroCarParams, dt: float = 0.02, v0: float = 0.0,
                   tuning: Optional[MetroObserverTuning] = None,
                   noise: Optional[MetroSensorNoise] = None,
                   omega0: Optional[FloatArray] = None) -> UKF:
    """Single metro observer UKF (alpha 0.5, beta 2, kappa 3 - L = -16)."""
    tuning = tuning or MetroObserverTuning()
    noise = noise or MetroSensorNoise()
    q, r = metro_noise(tuning, noise)
    x0, p0 = metro_prior(p, tuning, v0, omega0)
    return UKF(make_metro_fx(p, dt), make_metro_hx(p), x0, p0, q, r,
               p_max_diag=metro_variance_caps())


def make_metro_ukf_compiled(p: MetroCarParams, dt: float = 0.02, v0: float = 0.0,
                            tuning: Optional[MetroObserverTuning] = None,
                            noise: Optional[MetroSensorNoise] = None,
                            omega0: Optional[FloatArray] = None) -> UKF:
    """:func:`make_metro_ukf` with its steps done by the compiled kernels.

    :class:`metro_atc.core.brake.metro_kernel.MetroUKF`: the same filter to round-off.
    """
    base = make_metro_ukf(p, dt, v0, tuning, noise, omega0)
    return MetroUKF(base, lambda step: metro_linear_part(p, step), dt,
                    np.array([2.0 * p.r_b / p.j_w, 1.0 / p.w_eps, p.j_w, *p.davis]))


def precompile_metro_kernels() -> int:
    """Compile the observer's numba kernels now (or load them from their disk cache).

    One prediction and two measurement updates (all rows, some rows) of a
    :func:`make_metro_ukf_compiled` filter: the argument types the observer passes, so
    the kernels' on-disk cache (``cache=True``, next to the installed module or, where
    that is read-only, numba's user cache / ``NUMBA_CACHE_DIR``) holds everything a
    brake node needs.  ``scripts/install.sh`` runs it after each build: a node's first
    braked sample then loads the compiled code (~0.3 s of CPU) instead of compiling it
    (~6 s).  Returns the number of kernel steps done (3; fewer means the numpy path ran).
    """
    p = MetroCarParams()
    f = make_metro_ukf_compiled(p, 0.05, 10.0)
    u = np.r_[np.full(N_AX, 5e3), np.zeros(N_AX), 35_000.0]
    f.predict(u, 0.05)
    z = np.r_[f.x[M_IW], -0.5, f.x[M_IV]]
    f.update(z, u)
    rows = np.flatnonzero(np.arange(z.size) != 2)
    f.update(z[rows], u, rows)
    return int(getattr(f, "kernel_steps", 0))


def metro_variance_caps() -> FloatArray:
    """Upper bounds of the observer variances (bounded growth while predicting only)."""
    cap = np.empty(M_NX)
    cap[M_IV] = 10.0 ** 2
    cap[M_IW] = 20.0 ** 2
    cap[M_IMUB] = 0.25 ** 2
    cap[M_IGRADE] = 0.1 ** 2
    for i0 in M_IF:
        cap[i0:i0 + 3] = [1.0e5 ** 2, 1.0e6 ** 2, 1.0e7 ** 2]
    return cap


def adhesion_target(v: FloatArray, omega: FloatArray, mass: FloatArray | float,
                    p: MetroCarParams, mu_rail: FloatArray | float) -> FloatArray:
    """Target axle forces from the adhesion model at the estimated creep [N].

    Args:
        v: car speed [m/s], shape (...).
        omega: axle speeds [rad/s], shape (..., 4).
        mass: car mass [kg]; mu_rail: adhesion limit of the rail [-].
    """
    v = np.asarray(v)[..., None]
    s = (p.r_w * omega - v) / np.maximum(np.abs(v), p.v_min)
    nload = np.asarray(mass)[..., None] * G / N_AX if np.ndim(mass) else mass * G / N_AX
    mu_r = np.asarray(mu_rail)[..., None] if np.ndim(mu_rail) else mu_rail
    return nload * adhesion(s, mu_r, p)


def normalised_residual(forces: FloatArray, target: FloatArray, mass: FloatArray | float,
                        mu_rail: FloatArray | float) -> FloatArray:
    """Force residual as a fraction of the axle's adhesion capacity ``N_j mu_rail`` [-].

    Args:
        forces, target: (..., 4) [N]; mass [kg] and mu_rail [-] broadcast against (...).
    """
    cap = np.asarray(mass, dtype=float) * (G / N_AX) * np.asarray(mu_rail, dtype=float)
    return (np.asarray(forces) - np.asarray(target)) / np.asarray(cap)[..., None]


def run_metro_batch(p: MetroCarParams, meas: dict[str, FloatArray], mass: FloatArray,
                    mu_rail: FloatArray, dt: float = 0.02, v0: float = 80.0 / 3.6,
                    tuning: Optional[MetroObserverTuning] = None,
                    noise: Optional[MetroSensorNoise] = None) -> dict[str, FloatArray]:
    """Run B metro observers in lockstep (benchmark path).

    The mass (load-weigh signal) of each run is known to its observer, as in service.

    Returns:
        ``x``/``std`` (B, n_t, 19), ``forces`` (B, n_t, 4), ``mu_b`` (B, n_t),
        ``target`` (B, n_t, 4) adhesion targets at the estimated creep [N] and
        ``res_norm`` (B, n_t, 4) normalised residuals [-].
    """
    tuning = tuning or MetroObserverTuning()
    noise = noise or MetroSensorNoise()
    y, fc = meas["y"], meas["fc"]
    nb, nt, _ = y.shape
    q, r = metro_noise(tuning, noise)
    x0, p0 = metro_prior(p, tuning, v0)
    mass_b = np.asarray(mass, dtype=float)
    obs = BatchUKF(make_metro_fx(p, dt), make_metro_hx(p), np.tile(x0, (nb, 1)),
                   np.tile(p0, (nb, 1, 1)), q, r)
    obs.x[:, M_IV] = y[:, 0, 5]
    obs.x[:, M_IW] = y[:, 0, 0:4]
    u = np.concatenate((np.maximum(fc, 0.0), np.zeros_like(fc),
                        np.broadcast_to(mass_b[:, None, None], (nb, nt, 1))), axis=-1)
    xs = np.zeros((nb, nt, M_NX))
    sd = np.zeros((nb, nt, M_NX))
    for k in range(nt):
        if k > 0:
            obs.predict(u[:, k - 1], dt)
        obs.update(y[:, k], u[:, k])
        xs[:, k] = obs.x
        sd[:, k] = np.sqrt(np.maximum(np.diagonal(obs.p, axis1=1, axis2=2), 0.0))
    mu_r = np.asarray(mu_rail, dtype=float)[:, None]
    target = adhesion_target(xs[..., M_IV], xs[..., M_IW], mass_b[:, None], p, mu_r)
    return {"x": xs, "std": sd, "forces": xs[..., M_IF], "mu_b": xs[..., M_IMUB],
            "target": target,
            "res_norm": normalised_residual(xs[..., M_IF], target, mass_b[:, None], mu_r)}


# ----------------------------------------------------------------------------------------
# Online observer for the ROS node
# ----------------------------------------------------------------------------------------

DEFAULT_METRO_THRESHOLD = 0.35
"""Default threshold on the normalised residual [-] (fraction of N_j mu_rail).

From ``python -m metro_atc.bench.ukf``: 1.5 x the largest residual level sustained for
0.5 s (after a 0.3 s low-pass) over 80 normal calibration runs (dry/wet rail, service
brake / ATO steps, mass +-, mu_b 0.31-0.39, creep curve +-15 %, gradient +-3 %), which
was 0.23; the bench re-derives it on every run and prints it."""


def default_metro_decision(p: Optional[MetroCarParams] = None,
                           threshold: float = DEFAULT_METRO_THRESHOLD) -> dg.DecisionConfig:
    """Decision config of the metro observer (thresholds on normalised residuals)."""
    p = p or MetroCarParams()
    return dg.DecisionConfig(thresholds=np.full(N_AX, threshold), mu_b_min=p.mu_b_min,
                             mu_b_warn=p.mu_b_min + 0.05, mu_b_std_max=0.05,
                             persistence_s=0.5, gate_s=0.5, filter_tau_s=0.3)


@dataclass
class DiagnosisResult:
    """Output of one :meth:`MetroBrakeObserver.update` call (SI units).

    Attributes:
        t: sample time [s].
        mu_b: estimated disc-pad friction [-]; mu_b_std: its std [-].
        forces: estimated axle forces F_1..F_4 [N] (negative = braking).
        force_std: their std [N].
        target_forces: adhesion-model targets at the estimated creep [N].
        residual_forces: forces minus targets [N] (raw).
        residuals: normalised residuals, low-pass filtered as the decision uses them
            [-] (fraction of the axle's adhesion capacity N_j mu_rail).
        creep: estimated creep per axle [-].
        speed: estimated car speed [m/s]; grade: estimated sin(gradient) [-].
        pad_flaw: mu_b requirement violated (announced).
        wheel_flaw: per-axle force-residual flaw (announced) (4,).
        level: 0 OK, 1 WARN, 2 ERROR (diagnostic_msgs/DiagnosticStatus values).
        message: short human-readable summary.
        measurement_used: True if a measurement update (full or partial) was applied.
        skipped_reason: "" or what was abnormal about this sample (dropped channels,
            held clamp force, predict only, rejected time stamp, ...).
    """

    t: float
    mu_b: float
    mu_b_std: float
    forces: FloatArray
    force_std: FloatArray
    target_forces: FloatArray
    residual_forces: FloatArray
    residuals: FloatArray
    creep: FloatArray
    speed: float
    grade: float
    pad_flaw: bool
    wheel_flaw: FloatArray
    level: int
    message: str
    measurement_used: bool
    skipped_reason: str = ""


@dataclass
class _Counters:
    updates: int = 0
    predict_only: int = 0
    rejected_time: int = 0
    resets: int = 0
    reasons: dict[str, int] = field(default_factory=dict)


class MetroBrakeObserver:
    """Stateful brake diagnosis of one metro car (UKF + residuals + decision logic).

    Robustness contract: non-finite or masked channels are dropped from the
    measurement update (predict only if none is left); a time stamp that is not
    newer than the last one is ignored; gaps longer than ``max_gap_s`` re-initialise
    the filter from the measurements; a numerically failed step restores the last
    good state.  No output is ever NaN.

    Args:
        params: car parameters.
        dt: nominal sensor period [s].
        mu_rail: rail adhesion limit assumed by the target model [-]; also the scale
            of the normalised residual ``(F - F_target) / (N_j mu_rail)``.
        decision: decision config (thresholds on the normalised residual, per axle);
            default :func:`default_metro_decision`.
        tuning, noise: observer tuning and sensor noise.
        mass: car mass from the load-weigh signal [kg] (default ``params.mass``).
        min_brake_clamp: clamp force above which an axle counts as braked [N]; force
            residuals are only judged on braked axles of a moving car.
        max_gap_s: a data gap longer than this re-initialises the filter [s].
        adhesion_fn: optional adhesion curve ``mu(|s|)`` of the creep magnitude to use
            as the target model instead of :func:`adhesion` (e.g. the line plant's
            ``AdhesionCurve(...).mu`` for the rail condition it simulates); the target
            is then ``sign(s) N_j mu(|s|)``.
    """

    def __init__(self, params: Optional[MetroCarParams] = None, dt: float = 0.02,
                 mu_rail: Optional[float] = None, decision: Optional[dg.DecisionConfig] = None,
                 tuning: Optional[MetroObserverTuning] = None,
                 noise: Optional[MetroSensorNoise] = None, mass: Optional[float] = None,
                 min_brake_clamp: float = 2000.0, max_gap_s: float = 2.0,
                 adhesion_fn: Optional[Callable[[FloatArray], FloatArray]] = None) -> None:
        """Create the observer (see class docstring).

        The filter's steps run in the compiled kernels (:func:`make_metro_ukf_compiled`;
        the numpy UKF takes the steps they decline).
        """
        self.p = params or MetroCarParams()
        self.dt = float(dt)
        self.mu_rail = self.p.mu_rail if mu_rail is None else float(mu_rail)
        self.cfg = decision or default_metro_decision(self.p)
        self.tuning = tuning or MetroObserverTuning()
        self.noise = noise or MetroSensorNoise()
        self.mass = self.p.mass if mass is None else float(mass)
        self.min_brake_clamp = float(min_brake_clamp)
        self.max_gap_s = float(max_gap_s)
        self.adhesion_fn = adhesion_fn
        self.mu_b_std_floor: Optional[Callable[[MetroBrakeObserver, FloatArray], float]] = None
        """Optional lower bound of the mu_b std the decision uses, ``f(observer, u)``
        evaluated after each filter update (e.g. an information bound of the data)."""
        self.counters = _Counters()
        self.decision = dg.OnlineDecision(self.cfg, dt_first=self.dt)
        self.ukf: Optional[UKF] = None
        self._ukf_template: Optional[UKF] = None
        """The filter of the first initialisation: later ones restart from its models."""
        self.t_last: Optional[float] = None
        self._u_last = np.zeros(2 * N_AX + 1)
        self._u_last[-1] = self.mass
        self._last: Optional[DiagnosisResult] = None
        self._p0: Optional[FloatArray] = None
        """The prior covariance of :func:`metro_prior` (the same at every restart)."""
        owner = getattr(adhesion_fn, "__self__", None)
        self._curve = ((owner.c1, owner.c2, owner.c3)
                       if isinstance(owner, AdhesionCurve)
                       and getattr(adhesion_fn, "__func__", None) is AdhesionCurve.mu else None)
        """(c1, c2, c3) when ``adhesion_fn`` is an :meth:`AdhesionCurve.mu` (evaluated
        with plain floats by :meth:`_diagnose`), else None."""

    # -- helpers -----------------------------------------------------------------------
    def _init_filter(self, v0: float, omega0: Optional[FloatArray]) -> None:
        if self._ukf_template is None:
            self.ukf = self._ukf_template = make_metro_ukf_compiled(
                self.p, self.dt, v0, self.tuning, self.noise, omega0)
        else:  # the same filter as make_metro_ukf builds, its models and weights reused
            if self._p0 is None:  # (symmetrised once: restarted takes it as it is)
                self._p0 = symmetrize(metro_prior(self.p, self.tuning, v0, omega0)[1])
            x0 = np.zeros(M_NX)  # metro_prior's mean (its covariance does not change)
            x0[M_IV] = v0
            x0[M_IW] = v0 / self.p.r_w if omega0 is None else omega0
            x0[M_IMUB] = self.p.mu_b
            self.ukf = self._ukf_template.restarted(x0, self._p0, symmetric=True)
        self.decision.restart()
        self.counters.resets += 1

    def _skip(self, reason: str) -> None:
        self.counters.reasons[reason] = self.counters.reasons.get(reason, 0) + 1

    def reset_flaws(self) -> None:
        """Clear latched flaws (after maintenance)."""
        self.decision.reset()

    def set_mass(self, mass: float) -> None:
        """Update the car mass (load-weigh signal) [kg]; keeps the filter state."""
        if math.isfinite(mass) and mass > 0:
            self.mass = float(mass)

    # -- main entry --------------------------------------------------------------------
    def update(self, t: float, wheel_omega: ArrayLike, clamp_force: ArrayLike,
               accel_x: float, ref_speed: float, valid_mask: Optional[ArrayLike] = None,
               drive_torque: Optional[ArrayLike] = None) -> DiagnosisResult:
        """Process one sensor sample.

        Args:
            t: sample time [s] (sim time).
            wheel_omega: axle angular speeds w_1..w_4 [rad/s].
            clamp_force: measured clamp forces F_c1..F_c4 [N].
            accel_x: longitudinal specific force [m/s^2].
            ref_speed: reference speed [m/s].
            valid_mask: validity of the 6 measurement channels (w_1..w_4, a_x, v_ref)
                (default all valid); invalid or non-finite channels are not used.
            drive_torque: motor torque per axle [N m] (traction > 0, electric brake < 0),
                default zero.

        Returns:
            The diagnosis after this sample (never NaN).
        """
        self.counters.updates += 1
        t = float(t)
        try:
            z = np.empty(M_NY)
            z[:N_AX] = np.asarray(wheel_omega, dtype=float).reshape(N_AX)
            z[N_AX] = float(accel_x)
            z[N_AX + 1] = float(ref_speed)
            fc = np.asarray(clamp_force, dtype=float).reshape(N_AX)
            td = (None if drive_torque is None
                  else np.asarray(drive_torque, dtype=float).reshape(N_AX).tolist())
            okl = [math.isfinite(v) for v in z.tolist()]
            if valid_mask is not None:
                okl = [a and bool(b) for a, b in
                       zip(okl, np.asarray(valid_mask, dtype=bool).reshape(M_NY).tolist())]
        except (TypeError, ValueError):
            self._skip("malformed sample")
            return self._result_or_default(self.t_last or 0.0, "malformed sample")
        if not math.isfinite(t):
            self.counters.rejected_time += 1
            self._skip("non-finite time")
            return self._result_or_default(self.t_last or 0.0, "non-finite time")
        # the input vector (clamp forces held when invalid, np.maximum(fc, 0) as plain
        # floats: a few numpy calls on 9 numbers cost more than the loop)
        ul = self._u_last.tolist()
        fcl = fc.tolist()
        fc_all = True
        for j in range(N_AX):
            f = fcl[j]
            if math.isfinite(f):
                ul[j] = f if f > 0.0 else 0.0
            else:
                fc_all = False
        if td is not None:
            for j in range(N_AX):
                if math.isfinite(td[j]):
                    ul[N_AX + j] = td[j]
        ul[-1] = self.mass
        u = np.array(ul)
        reason = ""
        if self.ukf is None or (self.t_last is not None and t - self.t_last > self.max_gap_s):
            if not (okl[5] and all(okl[:N_AX])):
                self._skip("no valid data to initialise")
                return self._result_or_default(t, "waiting for valid speed data")
            self._init_filter(float(z[5]), z[:N_AX])
        elif self.t_last is None or t <= self.t_last:
            self.counters.rejected_time += 1
            self._skip("out-of-order time stamp")
            return self._result_or_default(t, "out-of-order time stamp")
        else:
            dt_tot = t - self.t_last
            n_sub = max(int(math.ceil(dt_tot / self.dt - 1e-6)), 1)
            for _ in range(n_sub):
                self.ukf.predict(self._u_last, dt_tot / n_sub)
        ukf = self.ukf
        assert ukf is not None
        self.t_last = t
        self._u_last = u
        x_prev, p_prev = ukf.x.copy(), ukf.p.copy()
        if not fc_all:
            reason = "clamp force invalid (held)"
        used = False
        if any(okl):
            rows = None if all(okl) else np.flatnonzero(okl)
            used = ukf.update(z if rows is None else z[rows], u, rows)
            if not used:
                reason = "update rejected"
            elif rows is not None:
                reason = reason or "partial measurement"
        else:
            reason = "no valid measurement (predict only)"
            self.counters.predict_only += 1
        if not math.isfinite(float(ukf.x.sum() + ukf.p.sum())):
            ukf.x, ukf.p = x_prev, p_prev
            used = False
            reason = "numerical failure (state restored)"
        if reason:
            self._skip(reason)
        return self._diagnose(t, u, used, reason)

    # -- outputs -----------------------------------------------------------------------
    def _diagnose(self, t: float, u: FloatArray, used: bool, reason: str) -> DiagnosisResult:
        """Residuals, decision and result after an update (plain floats per axle).

        The arithmetic is the array expressions' element by element, in their order
        (``math.exp`` and ``math.sqrt`` give numpy's values: checked by
        ``test/test_brake_replay.py`` against results recorded before this rewrite).
        """
        assert self.ukf is not None
        p = self.p
        xl = self.ukf.x.tolist()
        pm = self.ukf.p
        v = xl[M_IV]
        forces = xl[7:19:3]
        den = max(abs(v), p.v_min)
        creep = [(p.r_w * w - v) / den for w in xl[1:5]]
        cap = self.mass * (G / N_AX) * self.mu_rail
        curve = self._curve
        if curve is not None:  # sign(s) mu(clip(|s|, 0, 1)) of AdhesionCurve.mu
            c1, c2, c3 = curve
            mu_t = []
            for s in creep:
                sa = min(abs(s), 1.0)
                m = laws.burckhardt_mu(sa, c1, c2, c3)
                mu_t.append(m if s > 0.0 else (-m if s < 0.0 else 0.0 * m))
        elif self.adhesion_fn is None:
            mu_t = adhesion(np.array(creep), self.mu_rail, p).tolist()
        else:
            ca = np.array(creep)
            mu_t = (np.sign(ca) * np.asarray(self.adhesion_fn(np.abs(ca)), dtype=float)).tolist()
        load = self.mass * (G / N_AX)
        target = [load * m for m in mu_t]
        res_force = [f - g for f, g in zip(forces, target)]
        mu_std = math.sqrt(max(float(pm[M_IMUB, M_IMUB]), 0.0))
        if self.mu_b_std_floor is not None:
            floor = float(self.mu_b_std_floor(self, u))
            if math.isfinite(floor):
                mu_std = max(mu_std, floor)
        moving = abs(v) > 2.0 * p.v_min
        ul = u.tolist()
        active = [moving and ul[j] > self.min_brake_clamp for j in range(N_AX)]
        mu_b = xl[M_IMUB]
        level = self.decision.update(t, mu_b, mu_std, [r / cap for r in res_force], active)
        if level == dg.LEVEL_OK:
            message = "ok"
        else:
            msgs = []
            if self.decision.pad_flaw:
                msgs.append(f"brake pad friction {mu_b:.2f} < {self.cfg.mu_b_min:.2f}")
            for j in np.flatnonzero(self.decision.force_flaw):
                msgs.append(f"axle {j + 1} wheel-rail force residual")
            message = "; ".join(msgs) if msgs else "violation in progress"
        result = DiagnosisResult(
            t=t, mu_b=mu_b, mu_b_std=mu_std, forces=np.array(forces),
            force_std=np.array([math.sqrt(max(float(pm[i, i]), 0.0)) for i in (7, 10, 13, 16)]),
            target_forces=np.array(target), residual_forces=np.array(res_force),
            residuals=self.decision.res_f.copy(), creep=np.array(creep), speed=v,
            grade=xl[M_IGRADE], pad_flaw=bool(self.decision.pad_flaw),
            wheel_flaw=self.decision.force_flaw.copy(), level=int(level), message=message,
            measurement_used=used, skipped_reason=reason)
        self._last = result
        return result

    def _result_or_default(self, t: float, reason: str) -> DiagnosisResult:
        if self._last is not None:
            return replace(self._last, measurement_used=False, skipped_reason=reason)
        z4 = np.zeros(N_AX)
        return DiagnosisResult(t=float(t), mu_b=self.p.mu_b, mu_b_std=self.tuning.p0_mub,
                               forces=z4.copy(), force_std=np.full(N_AX, self.tuning.p0_f),
                               target_forces=z4.copy(), residual_forces=z4.copy(),
                               residuals=z4.copy(), creep=z4.copy(),
                               speed=0.0, grade=0.0, pad_flaw=False,
                               wheel_flaw=np.zeros(N_AX, dtype=bool), level=dg.LEVEL_WARN,
                               message=reason, measurement_used=False, skipped_reason=reason)
