"""The paper's vehicle: truth plant, vehicle-tyre reference model and UKF observer.

Seed 000, second paper ("Active Safety Diagnosis of Brake-by-Wire Systems with
Unscented Kalman Filter", Lin & Tang).  The extraction lost eq. 1-3 and garbled
eq. 4, 6 and 10; what is reconstructed is said so below.

Sign convention (REP-103 body frame): x forward, y left, z up; wheel i = 1 FL, 2 FR,
3 RL, 4 RR.  ``F_xi`` is the longitudinal force of the road on tyre i along the wheel
heading (negative while braking) and ``F_yi`` the lateral one (tyre frame).

Model pieces
------------
* Vehicle (Lin 2010b, eq. 1-3, reconstructed as the standard 7-DOF two-track model the
  nomenclature of the paper describes; lateral forces enter as axle means, eq. 5):
  ``m (dVx/dt - Vy r) = (Fx1 + Fx2) cos d - 2 Fyf sin d + Fx3 + Fx4``,
  ``m (dVy/dt + Vx r) = (Fx1 + Fx2) sin d + 2 Fyf cos d + 2 Fyr``,
  ``Iz dr/dt = lf ((Fx1 + Fx2) sin d + 2 Fyf cos d) - 2 lr Fyr + tf (Fx2 - Fx1) cos d
  + tr (Fx4 - Fx3)``.
* Wheel (Lin 2010b, eq. 4): ``Jw dw_i/dt = -2 mu_b R_b F_ci - r_w F_xi``.  The paper writes
  ``+ r_w F_xi``, i.e. its F_x is the force of the tyre on the road; with our sign
  (force on the vehicle) the term is negative.  Table I swaps the labels of the wheel
  radius and of the disk-pad effective radius; we use r_w = 0.39445 m (a 255/55 R18
  class tyre) and R_b = 0.29 m as the physically consistent assignment.
* Tyres: eq. 6 is the "similarity" scaling of a tyre table measured on a surface with
  tractive coefficient ``mu_bar`` to a road with ``mu``:
  ``F = (mu / mu_bar) F_table(F_z, slip * mu_bar / mu)`` (reconstructed; it keeps the slip
  stiffness and scales the peak, as in CarSim's tyre tables).  The truth plant uses a
  Magic-Formula tyre with load sensitivity, combined slip (normalised-slip similarity
  method) and relaxation lengths; the reference model ("vehicle-tire model" of Fig. 3)
  uses pure-slip 2-D tables with linear interpolation, exactly as eq. 6 describes.
* Observer (eq. 7-10): state ``[Vx, Vy, r, w1..w4, mu_b, (F, dF, ddF) for Fx1..Fx4,
  Fyf, Fyr]`` of dimension 26 (7 + 1 + 12 + 6, the paper's count); mu_b is constant
  (eq. 9, plus a tiny documented random walk), each force is a triple integrator
  driven by white noise (eq. 10); measured ``a_x, a_y, r, w1..w4`` (eq. 8), inputs the
  steering angle and the measured clamp forces.

Vehicle data: Table I.  Values not in Table I are estimates and marked as such.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from metro_atc.core import laws
from metro_atc.core.brake.ukf import UKF, BatchUKF

G = 9.80665
"""Standard gravity [m/s^2]."""

FloatArray = np.ndarray

MANEUVERS = ("straight_brake", "cornering", "lane_change")
"""Driver signals of Table II: A1 straight path and brake, A2 cornering, A3 lane change."""
ROAD_MU = (0.85, 0.3)
"""Road friction coefficients of Table II (B1, B2)."""
FAULTS = ("none", "pad", "tyre")
"""Cases: 1 normal, 2 abnormal brake pad (mu_b = 0.1), 3 abnormal front-right tyre."""


@dataclass(frozen=True)
class PaperVehicleParams:
    """Vehicle data of Lin 2010b, Table I plus documented estimates."""

    mass: float = 1862.0
    """Vehicle mass M [kg] (Table I)."""
    iz: float = 2888.0
    """Yaw inertia I_zz [kg m^2] (Table I)."""
    lf: float = 1.18
    """Front axle to mass centre [m] (Table I)."""
    wheelbase: float = 2.776
    """l_f + l_r [m] (Table I)."""
    tf: float = 0.7875
    """Half front track [m] (Table I)."""
    tr: float = 0.7875
    """Half rear track [m] (Table I)."""
    r_w: float = 0.39445
    """Wheel radius [m] (Table I, label swapped in the extraction)."""
    r_b: float = 0.29
    """Disk-pad effective radius [m] (Table I, label swapped in the extraction)."""
    j_w: float = 1.1
    """Wheel moment of inertia [kg m^2] (Table I)."""
    mu_b: float = 0.38
    """Nominal disk-pad friction coefficient [-] (Table I)."""
    h_cg: float = 0.72
    """Mass-centre height [m] (estimate for an E-class SUV)."""
    roll_share_front: float = 0.55
    """Front share of the lateral load transfer [-] (estimate)."""
    brake_share_front: float = 0.65
    """Front share of the brake torque in the brake-by-wire allocation [-] (estimate)."""
    cda: float = 0.85
    """Drag area C_d A [m^2] (estimate; only in the truth and reference models)."""
    mu_bar: float = 1.0
    """Tractive coefficient of the tyre measurement surface [-] (eq. 6, estimate)."""
    fz0: float = 4500.0
    """Nominal tyre load of the Magic-Formula tyre [N] (estimate)."""
    relax_x: float = 0.25
    """Longitudinal relaxation length [m] (estimate)."""
    relax_y: float = 0.5
    """Lateral relaxation length [m] (estimate)."""
    tau_act: float = 0.03
    """Clamp-force actuator time constant [s] (estimate)."""
    abs_slip: float = 0.08
    """ABS target slip magnitude [-] (estimate)."""
    abs_gain: float = 200.0
    """ABS integral gain on the slip error [1/s] (estimate)."""
    w_eps: float = 0.5
    """Smoothing speed of the brake-torque sign, tanh(w / w_eps) [rad/s]."""

    @property
    def lr(self) -> float:
        """Rear axle to mass centre [m]."""
        return self.wheelbase - self.lf

    def static_loads(self) -> FloatArray:
        """Static vertical loads F_z of the four wheels [N]."""
        zf = self.mass * G * self.lr / (2.0 * self.wheelbase)
        zr = self.mass * G * self.lf / (2.0 * self.wheelbase)
        return np.array([zf, zf, zr, zr])

    def wheel_xy(self) -> tuple[FloatArray, FloatArray]:
        """Wheel-centre positions (x_i, y_i) in the body frame [m]."""
        x = np.array([self.lf, self.lf, -self.lr, -self.lr])
        y = np.array([self.tf, -self.tf, self.tr, -self.tr])
        return x, y


# ----------------------------------------------------------------------------------------
# Tyres
# ----------------------------------------------------------------------------------------

_CX, _EX, _KX = 1.65, 0.0, 18.0     # MF shape, curvature, slip stiffness / load (estimates)
_CY, _EY = 1.35, -0.3               # lateral MF shape and curvature (estimates)
_CA1, _CA2 = 16.0, 1.6              # cornering stiffness Fz0 * c1 * sin(2 atan(Fz/(c2 Fz0)))
_LOAD_SENS = 0.08                   # friction drop per unit relative load (estimate)


def _mf(b: FloatArray, c: float, d: FloatArray, e: float, s: FloatArray) -> FloatArray:
    bs = b * s
    return d * np.sin(c * np.arctan(bs - e * (bs - np.arctan(bs))))


def mf_long(kappa: FloatArray, fz: FloatArray, p: PaperVehicleParams,
            stiff_scale: FloatArray | float = 1.0) -> FloatArray:
    """Pure longitudinal Magic-Formula force at the tyre-test surface mu_bar [N].

    Args:
        kappa: longitudinal slip ratio [-].
        fz: vertical load [N].
        p: vehicle parameters.
        stiff_scale: multiplier of the slip stiffness (tyre fault model).
    """
    fz = np.maximum(fz, 1.0)
    mu = p.mu_bar * (1.0 - _LOAD_SENS * (fz / p.fz0 - 1.0))
    d = mu * fz
    b = _KX * fz * stiff_scale / (_CX * d)
    return _mf(b, _CX, d, _EX, kappa)


def mf_lat(alpha: FloatArray, fz: FloatArray, p: PaperVehicleParams,
           stiff_scale: FloatArray | float = 1.0) -> FloatArray:
    """Pure lateral Magic-Formula force at the tyre-test surface mu_bar [N] (alpha in rad)."""
    fz = np.maximum(fz, 1.0)
    mu = p.mu_bar * (1.0 - _LOAD_SENS * (fz / p.fz0 - 1.0))
    d = mu * fz
    c_alpha = p.fz0 * _CA1 * np.sin(2.0 * np.arctan(fz / (_CA2 * p.fz0)))
    b = c_alpha * stiff_scale / (_CY * d)
    return _mf(b, _CY, d, _EY, alpha)


_KAPPA_N, _ALPHA_N = 0.12, 0.12     # slip normalisers of the combined-slip similarity


def tyre_truth(kappa: FloatArray, alpha: FloatArray, fz: FloatArray, mu: FloatArray,
               p: PaperVehicleParams, grip: FloatArray | float = 1.0,
               stiff: FloatArray | float = 1.0) -> tuple[FloatArray, FloatArray]:
    """Steady-state combined-slip tyre forces of the truth plant [N].

    Similarity scaling to the road (eq. 6, reconstructed) and the normalised-slip
    combination ``s = |(kappa/k_n, tan(alpha)/a_n)|``.

    Args:
        kappa: slip ratio [-]; alpha: slip angle [rad]; fz: load [N]; mu: road mu [-].
        p: vehicle parameters.
        grip: tyre grip multiplier (fault model), stiff: slip-stiffness multiplier.

    Returns:
        (F_x, F_y) in the tyre frame [N].
    """
    mu_eff = np.maximum(mu * grip, 1e-3)
    sc = p.mu_bar / mu_eff
    sx = kappa / _KAPPA_N
    sy = np.tan(alpha) / _ALPHA_N
    s = np.sqrt(sx * sx + sy * sy) + 1e-9
    fx0 = mf_long(s * _KAPPA_N * sc, fz, p, stiff) / sc
    fy0 = mf_lat(np.arctan(s * _ALPHA_N) * sc, fz, p, stiff) / sc
    return fx0 * sx / s, fy0 * sy / s


class TyreTable:
    """2-D tyre tables F_x(F_z, kappa) and F_y(F_z, alpha) with bilinear interpolation.

    The tables are "measured" (sampled from the nominal pure-slip Magic Formula) on
    the test surface ``mu_bar`` and scaled to the road by eq. 6 (Lin 2010b).
    """

    def __init__(self, p: PaperVehicleParams, n_fz: int = 13, n_slip: int = 81) -> None:
        """Sample the tables on a load grid and a sinh-spaced slip grid."""
        self.p = p
        self.fz = np.linspace(0.0, 12000.0, n_fz)
        u = np.linspace(-1.0, 1.0, n_slip)
        self.kappa = np.sinh(4.0 * u) / np.sinh(4.0)            # [-1, 1], dense near 0
        self.alpha = 0.6 * np.sinh(4.0 * u) / np.sinh(4.0)      # [-0.6, 0.6] rad
        fzg = self.fz[:, None]
        self.tab_x = mf_long(self.kappa[None, :], fzg, p)
        self.tab_y = mf_lat(self.alpha[None, :], fzg, p)
        self.tab_x[0] = 0.0
        self.tab_y[0] = 0.0

    @staticmethod
    def _interp2(gz: FloatArray, gs: FloatArray, tab: FloatArray, z: FloatArray,
                 s: FloatArray) -> FloatArray:
        z = np.clip(z, gz[0], gz[-1])
        s = np.clip(s, gs[0], gs[-1])
        iz = np.clip(np.searchsorted(gz, z) - 1, 0, gz.size - 2)
        js = np.clip(np.searchsorted(gs, s) - 1, 0, gs.size - 2)
        tz = (z - gz[iz]) / (gz[iz + 1] - gz[iz])
        ts = (s - gs[js]) / (gs[js + 1] - gs[js])
        f00 = tab[iz, js]
        f01 = tab[iz, js + 1]
        f10 = tab[iz + 1, js]
        f11 = tab[iz + 1, js + 1]
        return (1 - tz) * ((1 - ts) * f00 + ts * f01) + tz * ((1 - ts) * f10 + ts * f11)

    def forces(self, kappa: FloatArray, alpha: FloatArray, fz: FloatArray,
               mu: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Pure-slip table forces on a road with friction ``mu`` (Lin 2010b, eq. 6) [N]."""
        sc = self.p.mu_bar / np.maximum(mu, 1e-3)
        fx = self._interp2(self.fz, self.kappa, self.tab_x, fz, kappa * sc) / sc
        fy = self._interp2(self.fz, self.alpha, self.tab_y, fz, alpha * sc) / sc
        return fx, fy


# ----------------------------------------------------------------------------------------
# Driver signals (Table II) and the brake-by-wire allocation
# ----------------------------------------------------------------------------------------

BRAKE_ONSET_S = 0.5
"""Start of the brake application in every manoeuvre [s]."""


def driver_signals(maneuver: FloatArray, t: float) -> tuple[FloatArray, FloatArray]:
    """Road-wheel steering angle [rad] and requested deceleration [m/s^2] at time t.

    Table II gives only the names of the driver signals; the shapes are ours.  Every
    manoeuvre brakes from ``BRAKE_ONSET_S`` on (mu_b is unobservable without clamp
    force).  A1 requests 4 m/s^2: beyond the grip of the 0.3 road, so that the ABS is
    certainly active there (a request right at the adhesion limit makes ABS engagement
    depend on the vehicle's dispersion, which the open-loop reference model cannot
    follow); A2 (steady steer 0.012 rad) and A3 (one 3 s sine of 0.012 rad) brake at
    1.5 m/s^2 while steering.

    Args:
        maneuver: integer codes 0 = straight brake, 1 = cornering, 2 = lane change.
        t: time [s].
    """
    m = np.asarray(maneuver)
    ramp = float(np.clip((t - BRAKE_ONSET_S) / 0.3, 0.0, 1.0))
    a_req = np.where(m == 0, 4.0, 1.5) * ramp
    corner = 0.012 * float(np.clip(t / 0.5, 0.0, 1.0))
    tl = t - 0.5
    lane = 0.012 * np.sin(2.0 * np.pi * tl / 3.0) if 0.0 <= tl <= 3.0 else 0.0
    delta = np.where(m == 1, corner, np.where(m == 2, lane, 0.0))
    return delta.astype(float), a_req.astype(float)


def clamp_command(p: PaperVehicleParams, a_req: FloatArray) -> FloatArray:
    """Clamp-force command per wheel [N] for a requested deceleration (nominal mu_b).

    Brake torque per wheel = 2 mu_b R_b F_c (Lin 2010b, eq. 4), allocated front/rear
    with ``brake_share_front``.

    Args:
        p: vehicle parameters.
        a_req: requested deceleration [m/s^2], shape (B,).

    Returns:
        Array (B, 4).
    """
    torque = p.mass * a_req * p.r_w
    share = np.array([p.brake_share_front, p.brake_share_front,
                      1 - p.brake_share_front, 1 - p.brake_share_front]) / 2.0
    return np.asarray(laws.clamp_force_for_torque(torque[:, None] * share[None, :], p.mu_b,
                                                  p.r_b))


# ----------------------------------------------------------------------------------------
# Batched plant simulation (truth and reference model)
# ----------------------------------------------------------------------------------------

@dataclass
class Scenario:
    """One plant run: manoeuvre code, road mu, fault and parameter dispersion.

    Attributes:
        maneuver: 0 straight brake (A1), 1 cornering (A2), 2 lane change (A3).
        mu: road friction coefficient (B1 0.85 / B2 0.3).
        fault: "none", "pad" (mu_b = 0.1) or "tyre" (abnormal front-right tyre).
        mu_b: true disk-pad friction; None = 0.1 for "pad", Table I value otherwise.
        mass_scale: true mass / nominal mass (load dispersion).
        mu_scale: true road mu / nominal road mu (surface dispersion).
    """

    maneuver: int
    mu: float
    fault: str = "none"
    mu_b: Optional[float] = None
    mass_scale: float = 1.0
    mu_scale: float = 1.0

    def true_mu_b(self, p: PaperVehicleParams) -> float:
        """Disk-pad friction of the run [-] (0.1 for the pad fault, Table I value else)."""
        if self.mu_b is not None:
            return self.mu_b
        return 0.1 if self.fault == "pad" else p.mu_b


TYRE_FAULT_GRIP = 0.3
"""Grip multiplier of the abnormal front-right tyre (fault model, our choice: a tyre
with tread separation / severe under-inflation).  A force residual can only see a tyre
defect when the tyre is asked for more than it can give (braking force is set by the
brake torque otherwise); with grip x 0.4 the straight-braking case is not detectable."""
TYRE_FAULT_STIFF = 0.4
"""Slip-stiffness multiplier of the abnormal front-right tyre (fault model, our choice)."""


@dataclass
class PlantLog:
    """Sampled signals of a batch of plant runs; arrays are (B, n_t[, 4])."""

    t: FloatArray
    vx: FloatArray
    vy: FloatArray
    r: FloatArray
    omega: FloatArray
    fx: FloatArray
    fy: FloatArray
    fc: FloatArray
    ax: FloatArray
    ay: FloatArray
    delta: FloatArray
    extra: dict[str, FloatArray] = field(default_factory=dict)

    def targets(self) -> FloatArray:
        """Forces as the observer reports them: (B, n_t, 6) = Fx1..Fx4, Fyf, Fyr [N]."""
        fyf = 0.5 * (self.fy[..., 0] + self.fy[..., 1])
        fyr = 0.5 * (self.fy[..., 2] + self.fy[..., 3])
        return np.concatenate((self.fx, fyf[..., None], fyr[..., None]), axis=-1)


def simulate(p: PaperVehicleParams, scenarios: list[Scenario], t_end: float = 5.0,
             dt: float = 2e-3, sample_dt: float = 0.01, v0: float = 80.0 / 3.6,
             reference: bool = False, mu_b_in: Optional[FloatArray] = None) -> PlantLog:
    """Simulate a batch of runs of the vehicle with RK4 (23 states per run).

    Both modes contain the 7-DOF body, load transfer, relaxation-length tyre lags, the
    brake-by-wire allocation (nominal mu_b) with a slip-limiting ABS (integral gain on
    the slip error) and a first-order clamp-force actuator, driven by the driver signals
    of Table II.

    * Truth (``reference=False``): Magic-Formula combined-slip tyres, the fault and the
      dispersion of each scenario (true mu_b, mass, road mu, abnormal tyre).
    * Reference (``reference=True``): the "vehicle-tire model" of the paper's Fig. 3
      that "calculates target values of tire forces for the driver signals": nominal
      vehicle (Table I), nominal road mu, pure-slip 2-D tyre tables (eq. 6).  With
      ``mu_b_in`` the disk-pad friction of the model follows the observer's estimate
      (held between samples), so that force residuals isolate tyre faults from the
      pad friction (which has its own requirement, mu_b >= 0.2); our design choice.

    Args:
        p: vehicle parameters.
        scenarios: runs to simulate (batched).
        t_end: duration [s]; dt: RK4 step [s]; sample_dt: output period [s].
        v0: initial speed [m/s].
        reference: see above.
        mu_b_in: estimated mu_b per run and sample (B, n_samples), reference only.

    Returns:
        The sampled log (samples at k * sample_dt, k = 0..n).
    """
    nb = len(scenarios)
    man = np.array([s.maneuver for s in scenarios])
    mu = np.array([s.mu * (1.0 if reference else s.mu_scale) for s in scenarios])[:, None]
    mub = np.array([p.mu_b if reference else s.true_mu_b(p) for s in scenarios])[:, None]
    mass = np.array([p.mass * (1.0 if reference else s.mass_scale) for s in scenarios])
    iz = p.iz * mass / p.mass
    grip = np.ones((nb, 4))
    stiff = np.ones((nb, 4))
    if not reference:
        for b, s in enumerate(scenarios):
            if s.fault == "tyre":
                grip[b, 1] = TYRE_FAULT_GRIP
                stiff[b, 1] = TYRE_FAULT_STIFF
    table = TyreTable(p) if reference else None
    xw, yw = p.wheel_xy()
    front = np.array([1.0, 1.0, 0.0, 0.0])
    fz_static = p.static_loads()[None, :] * (mass / p.mass)[:, None]
    lat_share = np.array([p.roll_share_front / p.tf, p.roll_share_front / p.tf,
                          (1 - p.roll_share_front) / p.tr, (1 - p.roll_share_front) / p.tr])
    side = np.array([-1.0, 1.0, -1.0, 1.0])          # right wheels gain load when a_y > 0
    long_share = np.array([-0.5, -0.5, 0.5, 0.5]) / p.wheelbase

    # state layout: 0 vx, 1 vy, 2 r, 3:7 omega, 7:11 Fx, 11:15 Fy, 15:19 ABS gain, 19:23 Fc
    x = np.zeros((nb, 23))
    x[:, 0] = v0
    x[:, 3:7] = v0 / p.r_w
    x[:, 15:19] = 1.0

    def deriv(x: FloatArray, delta: FloatArray, fc_cmd: FloatArray
              ) -> tuple[FloatArray, FloatArray, FloatArray]:
        vx, vy, r = x[:, 0:1], x[:, 1:2], x[:, 2:3]
        om, fx, fy, g, fc = x[:, 3:7], x[:, 7:11], x[:, 11:15], x[:, 15:19], x[:, 19:23]
        dl = delta[:, None] * front
        cd, sd = np.cos(dl), np.sin(dl)
        fxb = fx * cd - fy * sd
        fyb = fx * sd + fy * cd
        drag = 0.5 * 1.2 * p.cda * vx[:, 0] * np.abs(vx[:, 0])
        ax = (fxb.sum(1) - drag) / mass
        ay = fyb.sum(1) / mass
        fz = (fz_static + long_share * (mass * ax * p.h_cg)[:, None]
              + side * lat_share * (mass * ay * p.h_cg)[:, None] / 2.0)
        fz = np.maximum(fz, 50.0)
        u = vx - r * yw
        w = vy + r * xw
        vwx = u * cd + w * sd
        vwy = -u * sd + w * cd
        den = np.maximum(np.abs(vwx), 0.5)
        kappa = (p.r_w * om - vwx) / den
        alpha = -np.arctan2(vwy, den)
        if table is not None:
            fxs, fys = table.forces(kappa, alpha, fz, mu)
        else:
            fxs, fys = tyre_truth(kappa, alpha, fz, mu, p, grip, stiff)
        dx = np.empty_like(x)
        dx[:, 0] = ax + vy[:, 0] * r[:, 0]
        dx[:, 1] = ay - vx[:, 0] * r[:, 0]
        dx[:, 2] = (xw * fyb - yw * fxb).sum(1) / iz
        tb = laws.pad_torque(fc, mub, p.r_b) * np.tanh(om / p.w_eps)
        dx[:, 3:7] = (-tb - p.r_w * fx) / p.j_w
        vrel = np.abs(vwx) + 0.5
        dx[:, 7:11] = vrel / p.relax_x * (fxs - fx)
        dx[:, 11:15] = vrel / p.relax_y * (fys - fy)
        dg = p.abs_gain * (p.abs_slip - np.abs(kappa))
        dg = np.where((g >= 1.0) & (dg > 0), 0.0, dg)
        dg = np.where((g <= 0.0) & (dg < 0), 0.0, dg)
        dx[:, 15:19] = dg
        dx[:, 19:23] = (np.clip(g, 0.0, 1.0) * fc_cmd - fc) / p.tau_act
        return dx, ax, ay

    n_sub = int(round(sample_dt / dt))
    n_s = int(round(t_end / sample_dt)) + 1
    logs = {k: np.zeros((nb, n_s)) for k in ("vx", "vy", "r", "ax", "ay", "delta")}
    logs4 = {k: np.zeros((nb, n_s, 4)) for k in ("omega", "fx", "fy", "fc")}
    t = 0.0
    for k in range(n_s):
        if reference and mu_b_in is not None:
            mub = np.clip(mu_b_in[:, k:k + 1], 0.0, 1.0)
        delta, a_req = driver_signals(man, k * sample_dt)
        fc_cmd = clamp_command(p, a_req)
        _, ax, ay = deriv(x, delta, fc_cmd)
        logs["vx"][:, k], logs["vy"][:, k], logs["r"][:, k] = x[:, 0], x[:, 1], x[:, 2]
        logs["ax"][:, k], logs["ay"][:, k], logs["delta"][:, k] = ax, ay, delta
        logs4["omega"][:, k], logs4["fx"][:, k] = x[:, 3:7], x[:, 7:11]
        logs4["fy"][:, k], logs4["fc"][:, k] = x[:, 11:15], x[:, 19:23]
        if k == n_s - 1:
            break
        for j in range(n_sub):
            t = k * sample_dt + j * dt
            delta, a_req = driver_signals(man, t + 0.5 * dt)
            fc_cmd = clamp_command(p, a_req)
            k1, _, _ = deriv(x, delta, fc_cmd)
            k2, _, _ = deriv(x + 0.5 * dt * k1, delta, fc_cmd)
            k3, _, _ = deriv(x + 0.5 * dt * k2, delta, fc_cmd)
            k4, _, _ = deriv(x + dt * k3, delta, fc_cmd)
            x = x + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
            x[:, 15:19] = np.clip(x[:, 15:19], 0.0, 1.0)
    tt = np.arange(n_s) * sample_dt
    return PlantLog(t=np.broadcast_to(tt, (nb, n_s)).copy(), vx=logs["vx"], vy=logs["vy"],
                    r=logs["r"], omega=logs4["omega"], fx=logs4["fx"], fy=logs4["fy"],
                    fc=logs4["fc"], ax=logs["ax"], ay=logs["ay"], delta=logs["delta"])


# ----------------------------------------------------------------------------------------
# Sensors
# ----------------------------------------------------------------------------------------

@dataclass(frozen=True)
class PaperSensorNoise:
    """Standard deviations of the sensors (estimates for automotive-grade sensors)."""

    ax: float = 0.05
    """Longitudinal accelerometer [m/s^2]."""
    ay: float = 0.05
    """Lateral accelerometer [m/s^2]."""
    r: float = 0.003
    """Yaw-rate gyro [rad/s]."""
    omega: float = 0.1
    """Wheel-speed sensor [rad/s]."""
    fc_rel: float = 0.01
    """Clamp-force sensor, relative part [-]."""
    fc_abs: float = 20.0
    """Clamp-force sensor, absolute part [N]."""
    delta: float = 2e-4
    """Steering-angle sensor (road-wheel angle) [rad]."""


def measure(log: PlantLog, noise: PaperSensorNoise, rng: np.random.Generator
            ) -> dict[str, FloatArray]:
    """Noisy sensor samples of a plant log (Lin 2010b, eq. 8 outputs plus inputs).

    Returns:
        dict with ``y`` (B, n_t, 7) = a_x, a_y, r, w1..w4, ``fc`` (B, n_t, 4) and
        ``delta`` (B, n_t).
    """
    nb, nt = log.ax.shape
    y = np.concatenate((log.ax[..., None], log.ay[..., None], log.r[..., None], log.omega),
                       axis=-1)
    sig = np.array([noise.ax, noise.ay, noise.r] + [noise.omega] * 4)
    y = y + rng.standard_normal(y.shape) * sig
    fc = log.fc + rng.standard_normal(log.fc.shape) * (noise.fc_abs + noise.fc_rel * log.fc)
    delta = log.delta + rng.standard_normal(log.delta.shape) * noise.delta
    return {"y": y, "fc": fc, "delta": delta}


# ----------------------------------------------------------------------------------------
# Observer (Lin 2010b, eq. 7-10)
# ----------------------------------------------------------------------------------------

N_X = 26
"""Observer state dimension L (Lin 2010b: 7 + 1 + 12 + 6 = 26)."""
N_Y = 7
"""Measured outputs: a_x, a_y, r, w1..w4."""
I_VX, I_VY, I_R = 0, 1, 2
I_W = slice(3, 7)
I_MUB = 7
I_FX = np.array([8, 11, 14, 17])
"""Indices of F_x1..F_x4 (each followed by its first and second derivative)."""
I_FYF, I_FYR = 20, 23
I_FORCES = np.array([8, 11, 14, 17, 20, 23])
"""Indices of the six diagnosed forces Fx1..Fx4, Fyf, Fyr."""


@dataclass(frozen=True)
class PaperObserverTuning:
    """Noise tuning of the paper observer (our choice; the paper gives none)."""

    q_v: float = 0.02
    """Process noise std of V_x, V_y per step [m/s]."""
    q_r: float = 0.002
    """Process noise std of r per step [rad/s]."""
    q_w: float = 0.05
    """Process noise std of the wheel speeds per step [rad/s]."""
    q_mub: float = 2e-4
    """Random walk std of mu_b per step [-] (eq. 9 says constant; tiny value keeps it
    adaptive)."""
    q_f: tuple[float, float, float] = (20.0, 400.0, 3.0e4)
    """Std per step of (F, dF/dt, d2F/dt2) of each force chain [N, N/s, N/s^2] (eq. 10)."""
    p0_mub: float = 0.1
    """Initial std of mu_b [-]."""
    p0_f: float = 300.0
    """Initial std of the forces [N]."""


def _chain_matrix(dt: float) -> FloatArray:
    return np.array([[1.0, dt, 0.5 * dt * dt], [0.0, 1.0, dt], [0.0, 0.0, 1.0]])


def observer_transition(p: PaperVehicleParams, dt: float) -> FloatArray:
    """Linear part of the discretised observer model (identity + force chains), (26, 26)."""
    a = np.eye(N_X)
    ch = _chain_matrix(dt)
    for i0 in I_FORCES:
        a[i0:i0 + 3, i0:i0 + 3] = ch
    return a


def make_fx(p: PaperVehicleParams, dt_nominal: float):  # type: ignore[no-untyped-def]
    """Vectorised observer transition f(X, u, dt) (Lin 2010b, eq. 1-4, 9, 10; Euler step).

    ``X``: (..., N, 26) sigma points, ``u``: (..., 5) = steering [rad], F_c1..F_c4 [N].
    """
    a_nom = observer_transition(p, dt_nominal).T
    k_w = 2.0 * p.r_b / p.j_w
    k_drag = 0.5 * 1.2 * p.cda

    def fx(xs: FloatArray, u: FloatArray, dt: float) -> FloatArray:
        a = a_nom if dt == dt_nominal else observer_transition(p, dt).T
        out = xs @ a
        delta = u[..., 0:1]
        fc = u[..., None, 1:5]
        cd, sd = np.cos(delta), np.sin(delta)
        f1, f2, f3, f4 = xs[..., 8], xs[..., 11], xs[..., 14], xs[..., 17]
        fyf, fyr = xs[..., 20], xs[..., 23]
        vx, vy, r = xs[..., 0], xs[..., 1], xs[..., 2]
        fxf = f1 + f2
        drag = k_drag * vx * np.abs(vx)
        fxb = fxf * cd - 2.0 * fyf * sd + f3 + f4 - drag
        fyb_f = fxf * sd + 2.0 * fyf * cd
        fyb = fyb_f + 2.0 * fyr
        mz = (p.lf * fyb_f - 2.0 * p.lr * fyr + p.tf * (f2 - f1) * cd + p.tr * (f4 - f3))
        out[..., 0] += dt * (fxb / p.mass + vy * r)
        out[..., 1] += dt * (fyb / p.mass - vx * r)
        out[..., 2] += dt * mz / p.iz
        om = xs[..., 3:7]
        tb = k_w * xs[..., 7:8] * fc * np.tanh(om / p.w_eps)
        out[..., 3:7] -= dt * (tb + (p.r_w / p.j_w) * xs[..., I_FX])
        return out

    return fx


def make_hx(p: PaperVehicleParams):  # type: ignore[no-untyped-def]
    """Vectorised observer output h(X, u) = (a_x, a_y, r, w1..w4) (Lin 2010b, eq. 8).

    The accelerometer measures the specific force, including the aerodynamic drag
    ``0.5 rho C_d A V_x^2`` (an addition to the paper's model; rho = 1.2 kg/m^3).
    """
    k_drag = 0.5 * 1.2 * p.cda

    def hx(xs: FloatArray, u: FloatArray) -> FloatArray:
        delta = u[..., 0:1]
        cd, sd = np.cos(delta), np.sin(delta)
        f1, f2, f3, f4 = xs[..., 8], xs[..., 11], xs[..., 14], xs[..., 17]
        fyf, fyr = xs[..., 20], xs[..., 23]
        fxf = f1 + f2
        drag = k_drag * xs[..., 0] * np.abs(xs[..., 0])
        ax = (fxf * cd - 2.0 * fyf * sd + f3 + f4 - drag) / p.mass
        ay = (fxf * sd + 2.0 * fyf * cd + 2.0 * fyr) / p.mass
        return np.concatenate((ax[..., None], ay[..., None], xs[..., 2:7]), axis=-1)

    return hx


def observer_noise(p: PaperVehicleParams, tuning: PaperObserverTuning,
                   noise: PaperSensorNoise) -> tuple[FloatArray, FloatArray]:
    """Process (per step) and measurement noise covariances (Q (26, 26), R (7, 7))."""
    q = np.zeros(N_X)
    q[[I_VX, I_VY]] = tuning.q_v ** 2
    q[I_R] = tuning.q_r ** 2
    q[I_W] = tuning.q_w ** 2
    q[I_MUB] = tuning.q_mub ** 2
    for i0 in I_FORCES:
        q[i0:i0 + 3] = np.square(tuning.q_f)
    r = np.diag([noise.ax ** 2, noise.ay ** 2, noise.r ** 2] + [noise.omega ** 2] * 4)
    return np.diag(q), r


def initial_state(p: PaperVehicleParams, tuning: PaperObserverTuning, v0: float,
                  omega0: Optional[FloatArray] = None) -> tuple[FloatArray, FloatArray]:
    """Observer prior: known initial speed, nominal mu_b, zero forces."""
    x0 = np.zeros(N_X)
    x0[I_VX] = v0
    x0[I_W] = v0 / p.r_w if omega0 is None else omega0
    x0[I_MUB] = p.mu_b
    p0 = np.zeros(N_X)
    p0[[I_VX, I_VY]] = [0.5 ** 2, 0.1 ** 2]
    p0[I_R] = 0.01 ** 2
    p0[I_W] = 0.2 ** 2
    p0[I_MUB] = tuning.p0_mub ** 2
    for i0 in I_FORCES:
        p0[i0:i0 + 3] = [tuning.p0_f ** 2, 3000.0 ** 2, 3.0e4 ** 2]
    return x0, np.diag(p0)


def make_observer(p: PaperVehicleParams, dt: float = 0.01, v0: float = 80.0 / 3.6,
                  tuning: Optional[PaperObserverTuning] = None,
                  noise: Optional[PaperSensorNoise] = None) -> UKF:
    """The paper's diagnostic observer as a single UKF (alpha 0.5, beta 2, kappa 3 - L)."""
    tuning = tuning or PaperObserverTuning()
    noise = noise or PaperSensorNoise()
    q, r = observer_noise(p, tuning, noise)
    x0, p0 = initial_state(p, tuning, v0)
    return UKF(make_fx(p, dt), make_hx(p), x0, p0, q, r)


def make_batch_observer(p: PaperVehicleParams, n_batch: int, dt: float = 0.01,
                        v0: float = 80.0 / 3.6, tuning: Optional[PaperObserverTuning] = None,
                        noise: Optional[PaperSensorNoise] = None) -> BatchUKF:
    """``n_batch`` independent copies of the paper observer run in lockstep."""
    tuning = tuning or PaperObserverTuning()
    noise = noise or PaperSensorNoise()
    q, r = observer_noise(p, tuning, noise)
    x0, p0 = initial_state(p, tuning, v0)
    return BatchUKF(make_fx(p, dt), make_hx(p), np.tile(x0, (n_batch, 1)),
                    np.tile(p0, (n_batch, 1, 1)), q, r)


def run_observer(p: PaperVehicleParams, meas: dict[str, FloatArray], dt: float = 0.01,
                 v0: float = 80.0 / 3.6, tuning: Optional[PaperObserverTuning] = None,
                 noise: Optional[PaperSensorNoise] = None) -> dict[str, FloatArray]:
    """Run the batched observer over measured sequences.

    Args:
        p: vehicle parameters.
        meas: output of :func:`measure` (arrays (B, n_t, ...)).
        dt: sample period [s]; v0: initial speed [m/s].

    Returns:
        dict with ``x`` (B, n_t, 26) posterior means, ``std`` (B, n_t, 26) posterior
        standard deviations, ``forces`` (B, n_t, 6) and ``mu_b`` (B, n_t).
    """
    y, fc, delta = meas["y"], meas["fc"], meas["delta"]
    nb, nt, _ = y.shape
    obs = make_batch_observer(p, nb, dt, v0, tuning, noise)
    xs = np.zeros((nb, nt, N_X))
    sd = np.zeros((nb, nt, N_X))
    u = np.concatenate((delta[..., None], np.maximum(fc, 0.0)), axis=-1)
    for k in range(nt):
        if k > 0:
            obs.predict(u[:, k - 1], dt)
        obs.update(y[:, k], u[:, k])
        xs[:, k] = obs.x
        sd[:, k] = np.sqrt(np.maximum(np.diagonal(obs.p, axis1=1, axis2=2), 0.0))
    return {"x": xs, "std": sd, "forces": xs[..., I_FORCES], "mu_b": xs[..., I_MUB]}
