"""Train longitudinal model: resistance, traction/brake effort and RK4 integration.

All quantities SI: position [m], speed [m/s], force [N], mass [kg], acceleration [m/s^2].
Functions are vectorised over trains (numpy arrays broadcast).

References
----------
- Running resistance: Davis form ``F_r(v) = A + B v + C v^2`` (ACTP n.d., eq. 1); the
  Taipei MRT deceleration ``phi_r(v) = 0.020084 + 5.04e-4 v + 4.774e-5 v^2`` (ACTP n.d.
  eq. 2, SI, v in m/s).  Eq. 1 is garbled in the extraction; it equals eq. 2 times the train
  mass (the extracted digits are consistent with M ~ 214 t), so we build F_r from eq. 2.
- Traction characteristic (ACTP n.d., eq. 3-5): constant-torque ``phi_1 = a_1``,
  constant-voltage ``phi_2 = a_2 / (v + b_2)``, constant-power ``phi_3 = a_3 / (v + b_3)^2``
  (reconstructed from the garbled extraction; a_2, a_3 follow from continuity at the
  region boundaries v_1, v_2).
- RK4 integration of Newton's law (Li n.d.).
- Accel/decel +-1.0 m/s^2, jerk +-1.0 m/s^3 (Ke 2010).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from metro_atc.core import laws
from metro_atc.core.laws import G_MPS2 as G_MPS2  # re-exported: the one value

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class TrainParams:
    """Parameters of one train (consist).

    Defaults: a Taipei MRT 6-car train (ACTP n.d., eq. 2 resistance; traction figures are
    estimates giving ~1.0 m/s^2 starting acceleration, Ke 2010).
    """

    mass_kg: float = 214_000.0
    """Total mass incl. nominal load [kg] (ACTP n.d., eq. 1/2 consistency, estimate): the
    reference mass at which the traction curve and the brake rates are given (above it
    the motors are force-limited, :func:`metro_atc.core.laws.traction_mass`)."""
    rotary_allowance: float = 0.08
    """Rotating-mass allowance lambda: effective mass = m (1 + lambda) [-] (estimate)."""
    davis_a_n: float = 0.020084 * 214_000.0
    """Davis constant term A [N] (ACTP n.d., eq. 2 times mass)."""
    davis_b_n_per_mps: float = 5.04e-4 * 214_000.0
    """Davis linear term B [N/(m/s)] (ACTP n.d., eq. 2 times mass)."""
    davis_c_n_per_mps2: float = 4.774e-5 * 214_000.0
    """Davis quadratic term C [N/(m/s)^2] (ACTP n.d., eq. 2 times mass)."""
    a1_mps2: float = 1.0
    """Constant-torque acceleration a_1 [m/s^2] (ACTP n.d., eq. 3; Ke 2010 limit 1.0)."""
    v1_mps: float = 36.0 / 3.6
    """End of the constant-torque region [m/s] (estimate)."""
    v2_mps: float = 60.0 / 3.6
    """End of the constant-voltage region [m/s] (estimate)."""
    b2_mps: float = 0.0
    """Constant b_2 of ACTP n.d., eq. 4 [m/s]."""
    b3_mps: float = 0.0
    """Constant b_3 of ACTP n.d., eq. 5 [m/s]."""
    max_service_brake_mps2: float = 1.0
    """Maximum service braking deceleration [m/s^2] (Ke 2010)."""
    emergency_brake_mps2: float = 1.2
    """Guaranteed emergency braking deceleration [m/s^2] (estimate, used by ATP)."""
    max_jerk_mps3: float = 1.0
    """Jerk limit [m/s^3] (Ke 2010)."""
    max_speed_mps: float = 80.0 / 3.6
    """Design maximum speed [m/s]."""
    length_m: float = 141.0
    """Train length [m] (6 cars x ~23.5 m, estimate)."""
    # ---- extensions for the line plant; all have defaults ----
    cars: int = 6
    """Number of cars in the consist [-]."""
    axles_per_car: int = 4
    """Axles per car [-] (two 2-axle bogies)."""
    motored_axle_fraction: float = 0.5
    """Fraction of axles that are motored (electric brake / traction) [-] (estimate)."""
    emergency_brake_actual_mps2: float = 1.4
    """Nominal (not guaranteed) full friction emergency-brake deceleration [m/s^2] on a
    healthy train on dry rail (estimate; ATP only relies on ``emergency_brake_mps2``)."""
    emergency_jerk_mps3: float = 6.0
    """Rate at which the emergency brake builds up [m/s^3] (estimate, ~0.4 s build-up)."""
    max_regen_power_w: float = 2.4e6
    """Maximum electric (regenerative) braking power at the wheel [W] (estimate)."""
    regen_fade_speed_mps: float = 5.0 / 3.6
    """Below this speed the electric brake fades out linearly to zero [m/s] (estimate)."""
    wheel_radius_m: float = 0.43
    """Wheel rolling radius r_w [m] (860 mm wheel, estimate)."""
    wheel_inertia_kgm2: float = 120.0
    """Moment of inertia of one wheelset incl. brake discs J_w [kg m^2] (estimate)."""
    brake_radius_m: float = 0.25
    """Effective disc-pad friction radius R_b [m] (estimate)."""
    pad_mu_nominal: float = 0.35
    """Nominal disk-pad friction coefficient mu_b [-] (estimate; Lin 2010b uses 0.38)."""
    nominal_load_pax: float = 1000.0
    """Passenger load already included in ``mass_kg`` [persons] (estimate)."""
    capacity_pax: float = 1900.0
    """Crush-load capacity [persons] (Taipei C301-class 6-car, estimate)."""
    pax_mass_kg: float = 65.0
    """Mass of one passenger [kg] (estimate)."""
    traction_efficiency: float = 0.85
    """Substation-to-wheel efficiency in traction [-] (estimate)."""
    regen_efficiency: float = 0.80
    """Wheel-to-line efficiency of regenerative braking [-] (estimate)."""
    aux_power_w: float = 150e3
    """Auxiliary (HVAC, lighting) power drawn while in service [W] (estimate)."""
    service_brake_load_pax: float | None = None
    """Load up to which the service brake is load-weighed [persons] (None: ``capacity_pax``,
    crush; estimate: metro brake valves typically compensate up to crush load)."""

    @property
    def tare_mass_kg(self) -> float:
        """Empty mass [kg]: ``mass_kg`` less its nominal load ``nominal_load_pax``."""
        return self.mass_kg - self.nominal_load_pax * self.pax_mass_kg

    def mass_at_load(self, load_pax: Any) -> Any:
        """Mass [kg] with ``load_pax`` passengers on board (float or array of loads).

        ``mass_kg`` includes ``nominal_load_pax`` persons; each one more or less adds or
        removes ``pax_mass_kg``.
        """
        return self.mass_kg + (load_pax - self.nominal_load_pax) * self.pax_mass_kg

    @property
    def effective_mass_kg(self) -> float:
        """Mass including the rotating-mass allowance [kg]."""
        return self.mass_kg * (1.0 + self.rotary_allowance)

    def effective_mass_at(self, mass: Any) -> Any:
        """Effective mass [kg] of the train at ``mass`` [kg] (float or array).

        The rotating parts do not change with the load: ``mass + lambda mass_kg`` (the
        plant's model; equal to :attr:`effective_mass_kg` at ``mass_kg``).
        """
        return mass + self.rotary_allowance * self.mass_kg

    @property
    def service_brake_meff_limit_kg(self) -> float:
        """Effective mass [kg] up to which the service brake is load-weighed.

        At :attr:`service_brake_load_pax` (crush when None); above it the service brake is
        at its maximum force (:func:`metro_atc.core.laws.load_weighed_decel`).
        """
        load = self.capacity_pax if self.service_brake_load_pax is None \
            else self.service_brake_load_pax
        return float(self.effective_mass_at(self.mass_at_load(load)))

    @property
    def emergency_brake_meff_limit_kg(self) -> float:
        """Effective mass [kg] up to which the emergency brake is load-weighed: at crush.

        The emergency brake holds its rate at every load up to ``capacity_pax`` (the ATP's
        guaranteed deceleration relies on it).
        """
        return float(self.effective_mass_at(self.mass_at_load(self.capacity_pax)))

    def at_mass(self, mass: float) -> "TrainParams":
        """The rolling stock as a train of ``mass`` [kg] sees it (the on-board ATO's model).

        ``mass_kg`` is the reference mass m_ref at which the traction curve and the brake
        rates are specified.  The result has ``mass_kg = mass`` and:

        - the traction curve phi scaled by ``min(mass, m_ref) / mass`` (so that its
          ``mass_kg phi`` is the force limit ``phi min(mass, m_ref)``,
          :func:`metro_atc.core.laws.traction_mass`): below m_ref the curve is unchanged
          (load-weighed drive), above it a fuller train accelerates less;
        - the rotating-mass allowance ``lambda m_ref / mass`` (the same rotating mass,
          :meth:`effective_mass_at`);
        - the service and emergency rates at that mass
          (:func:`metro_atc.core.laws.load_weighed_decel` with
          :attr:`service_brake_meff_limit_kg` / :attr:`emergency_brake_meff_limit_kg`);
        - the load ``nominal_load_pax`` that mass carries, the load-weigh limit kept.

        ``at_mass(mass_kg)`` is this object itself.  Call it on the reference stock only
        (the result's ``mass_kg`` is no longer the reference mass).  ValueError for a mass
        that is not positive.
        """
        m_ref = self.mass_kg
        if mass == m_ref:
            return self
        if not (math.isfinite(mass) and mass > 0.0):
            raise ValueError(f"mass: expected a finite mass > 0 kg, got {mass!r}")
        law = laws.plain
        meff = float(self.effective_mass_at(mass))
        over: dict[str, Any] = {
            "mass_kg": float(mass), "rotary_allowance": self.rotary_allowance * m_ref / mass,
            "nominal_load_pax": self.nominal_load_pax + (mass - m_ref) / self.pax_mass_kg,
            "max_service_brake_mps2": law.load_weighed_decel(
                self.max_service_brake_mps2, meff, self.service_brake_meff_limit_kg),
            "emergency_brake_actual_mps2": law.load_weighed_decel(
                self.emergency_brake_actual_mps2, meff, self.emergency_brake_meff_limit_kg),
            "service_brake_load_pax": self.capacity_pax if self.service_brake_load_pax is None
            else self.service_brake_load_pax}
        m_trac = law.traction_mass(mass, m_ref)
        if m_trac != mass:
            over["a1_mps2"] = self.a1_mps2 * (m_trac / mass)
        return dataclasses.replace(self, **over)

    @property
    def a2(self) -> float:
        """Constant a_2 of ACTP n.d., eq. 4 [m^2/s^3], from continuity at v_1."""
        return float(laws.plain.traction_a2(self.a1_mps2, self.v1_mps, self.b2_mps))

    @property
    def a3(self) -> float:
        """Constant a_3 of ACTP n.d., eq. 5 [m^3/s^4], from continuity at v_2."""
        return float(laws.plain.traction_a3(self.a1_mps2, self.v1_mps, self.v2_mps,
                                            self.b2_mps, self.b3_mps))

    @functools.cached_property
    def traction_law(self) -> tuple[float, float, float, float, float, float, float]:
        """(a1, v1, v2, a2, a3, b2, b3): the arguments of :func:`laws.traction_accel`."""
        return (self.a1_mps2, self.v1_mps, self.v2_mps, self.a2, self.a3, self.b2_mps,
                self.b3_mps)


def resistance_force(p: TrainParams, v: ArrayLike) -> FloatArray:
    """Davis running resistance F_r(v) [N] for speed v [m/s] >= 0 (ACTP n.d., eq. 1-2).

    :func:`metro_atc.core.laws.davis_resistance` of each speed.
    """
    return laws.on_array(laws.davis_resistance_array, v, p.davis_a_n, p.davis_b_n_per_mps,
                         p.davis_c_n_per_mps2)


def max_traction_accel(p: TrainParams, v: ArrayLike) -> FloatArray:
    """Maximum tractive acceleration phi_psi(v) [m/s^2] (ACTP n.d., eq. 3-5).

    Acceleration here is tractive force divided by the *static* mass, as in ACTP n.d.:
    :func:`metro_atc.core.laws.traction_accel` of each speed.
    """
    return laws.on_array(laws.traction_accel_array, v, *p.traction_law)


def resistance_force_at(p: TrainParams, v: float) -> float:
    """:func:`resistance_force` for one speed [m/s] (plain floats, the same IEEE result) [N]."""
    return laws.davis_resistance(v, p.davis_a_n, p.davis_b_n_per_mps,  # type: ignore
                                 p.davis_c_n_per_mps2)


def max_traction_accel_at(p: TrainParams, v: float) -> float:
    """:func:`max_traction_accel` for one speed [m/s] (plain floats, the same IEEE result).

    The per-train ATO evaluates it a few times per control step (no 0-d array).
    """
    return laws.traction_accel(v, *p.traction_law)  # type: ignore[no-any-return]


def max_traction_force_at(p: TrainParams, v: float) -> float:
    """:func:`max_traction_force` for one speed [m/s] (plain floats, the same result) [N]."""
    return laws.traction_force(v, p.mass_kg, *p.traction_law)  # type: ignore


def max_traction_force(p: TrainParams, v: ArrayLike) -> FloatArray:
    """Maximum tractive force [N] at speed v [m/s] (ACTP n.d., eq. 3-5 times mass)."""
    return p.mass_kg * max_traction_accel(p, v)


def grade_force(p: TrainParams, grade: ArrayLike) -> FloatArray:
    """Gravity force along the track [N]; grade = rise/run (positive uphill) [-]."""
    return laws.on_array(laws.grade_force_array, grade, p.mass_kg)


def effort_force(p: TrainParams, v: ArrayLike, u: ArrayLike) -> FloatArray:
    """Traction/brake effort [N] for a normalised command u in [-1, 1].

    u > 0: fraction of the maximum tractive force at v; u < 0: fraction of the maximum
    service braking force ``m * max_service_brake``.
    """
    ua = np.asarray(u, dtype=float)
    f_max = np.broadcast_to(max_traction_force(p, v), np.broadcast_shapes(ua.shape, np.shape(v)))
    ua, f_max = np.broadcast_arrays(ua, f_max)
    out = np.array([laws.command_effort(float(a), float(f), p.mass_kg, p.max_service_brake_mps2)
                    for a, f in zip(ua.ravel(), f_max.ravel())]).reshape(ua.shape)
    return out[()] if out.ndim == 0 else out


def net_accel(p: TrainParams, v: ArrayLike, effort_n: ArrayLike,
              grade: ArrayLike) -> FloatArray:
    """Acceleration dv/dt [m/s^2] from effort [N], resistance and grade (Newton's law).

    Resistance always opposes motion; at standstill it cannot exceed the other forces
    (static case handled by the integrator clamping v >= 0).
    """
    va, fe, fg = np.broadcast_arrays(np.asarray(v, dtype=float),
                                     np.asarray(effort_n, dtype=float), grade_force(p, grade))
    out = laws.net_accel_array(np.ascontiguousarray(va).reshape(-1),
                               np.ascontiguousarray(fe).reshape(-1),
                               np.ascontiguousarray(fg).reshape(-1), p.davis_a_n,
                               p.davis_b_n_per_mps, p.davis_c_n_per_mps2,
                               p.effective_mass_kg).reshape(va.shape)
    return out[()] if out.ndim == 0 else out


def rk4_step(p: TrainParams, x: ArrayLike, v: ArrayLike, effort_n: ArrayLike,
             grade: ArrayLike, dt: float) -> tuple[FloatArray, FloatArray]:
    """Advance (x [m], v [m/s]) by dt [s] with RK4 at constant effort and grade (Li n.d.).

    Speed is clamped at zero (a braked/coasting train does not roll backwards here).
    """
    x0 = np.asarray(x, dtype=float)
    v0 = np.asarray(v, dtype=float)

    def f(vv: FloatArray) -> FloatArray:
        return net_accel(p, np.maximum(vv, 0.0), effort_n, grade)

    k1v = f(v0)
    k1x = v0
    k2v = f(v0 + 0.5 * dt * k1v)
    k2x = v0 + 0.5 * dt * k1v
    k3v = f(v0 + 0.5 * dt * k2v)
    k3x = v0 + 0.5 * dt * k2v
    k4v = f(v0 + dt * k3v)
    k4x = v0 + dt * k3v
    v1 = v0 + dt / 6.0 * (k1v + 2 * k2v + 2 * k3v + k4v)
    x1 = x0 + dt / 6.0 * (k1x + 2 * k2x + 2 * k3x + k4x)
    stopped = v1 < 0.0
    v1 = np.where(stopped, 0.0, v1)
    x1 = np.where(stopped, np.maximum(x0, x1), x1)
    return x1, v1


@dataclass(frozen=True)
class Track:
    """Piecewise-constant track properties along the line chainage x [m].

    ``grade_starts_m[i]`` begins a segment of grade ``grades[i]`` (rise/run, +uphill) that
    runs to the next start; same for speed limits [m/s].  The first start must be <= 0.
    """

    grade_starts_m: FloatArray
    grades: FloatArray
    limit_starts_m: FloatArray
    limits_mps: FloatArray

    def grade_at(self, x: ArrayLike) -> FloatArray:
        """Grade [-] at chainage x [m] (vectorised)."""
        i = np.searchsorted(self.grade_starts_m, np.asarray(x, dtype=float), side="right") - 1
        return self.grades[np.clip(i, 0, len(self.grades) - 1)]

    def limit_at(self, x: ArrayLike) -> FloatArray:
        """Permanent speed limit [m/s] at chainage x [m] (vectorised)."""
        i = np.searchsorted(self.limit_starts_m, np.asarray(x, dtype=float), side="right") - 1
        return self.limits_mps[np.clip(i, 0, len(self.limits_mps) - 1)]

    @staticmethod
    def flat(limit_mps: float) -> "Track":
        """A level track with one speed limit [m/s]."""
        return Track(np.array([-1e12]), np.array([0.0]),
                     np.array([-1e12]), np.array([float(limit_mps)]))


TAIPEI_MRT_6CAR = TrainParams()
"""Taipei MRT 6-car train (ACTP n.d., eq. 2 resistance; traction/brake per Ke 2010; estimates
as documented on :class:`TrainParams`)."""

_THSR_MASS_KG = 576_000.0
_THSR_POWER_W = 10_260_000.0
_THSR_ACCEL_MPS2 = 2.0 / 3.6

THSR_700T = TrainParams(
    mass_kg=_THSR_MASS_KG,  # Li n.d., Table 4: 576 t loaded
    rotary_allowance=0.04,  # estimate (not in Li n.d.)
    davis_a_n=0.0012 * _THSR_MASS_KG * G_MPS2,  # estimate: 1.2 N/kN rolling resistance
    davis_b_n_per_mps=0.0,  # not given in Li n.d.
    davis_c_n_per_mps2=0.5 * 1.17 * 0.31 * 64.0,  # Li n.d.: F_D 0.31, 64 m^2, 1.17 kg/m^3
    a1_mps2=_THSR_ACCEL_MPS2,  # Li n.d., Table 4: max accel 2 km/h/s
    v1_mps=_THSR_POWER_W / (_THSR_MASS_KG * _THSR_ACCEL_MPS2),  # constant power beyond
    v2_mps=1e9,  # Li n.d. gives one constant-power region (10 260 kW) up to 300 km/h
    max_service_brake_mps2=_THSR_ACCEL_MPS2,  # Li n.d.: same limit for deceleration
    emergency_brake_mps2=0.9,  # estimate
    max_jerk_mps3=1.0,
    max_speed_mps=300.0 / 3.6,  # Li n.d., Table 4
    length_m=304.0,  # 12 cars (estimate from car length ~25 m)
    cars=12,  # Li n.d. text: 12-car trainset
    motored_axle_fraction=0.75,  # 700T: 9 motor cars of 12 (estimate from public data)
    emergency_brake_actual_mps2=1.1,  # estimate
    max_regen_power_w=10_260_000.0,  # assume regen up to the rated traction power
    wheel_radius_m=0.43,  # estimate
    wheel_inertia_kgm2=150.0,  # estimate
    brake_radius_m=0.24,  # estimate
    nominal_load_pax=989.0,  # Li n.d. text: 989 seats; 576 t is the loaded mass
    capacity_pax=1200.0,  # estimate (seats + standees)
    pax_mass_kg=73.812,  # Li n.d., Table 4
    aux_power_w=400e3,  # estimate
)
"""THSR 700T 12-car trainset (Li n.d., Table 4; estimates marked)."""

PRESETS: dict[str, TrainParams] = {"taipei_mrt_6car": TAIPEI_MRT_6CAR, "thsr_700t": THSR_700T}
"""Rolling-stock presets by scenario name (``trains.preset``)."""


STOCK_KEYS = (
    "mass_kg", "tare_mass_kg", "mass_load_pax", "pax_mass_kg", "rotating_allowance",
    "length_m", "cars", "max_speed_kmh",
    "davis_a_n", "davis_b_n_per_mps", "davis_c_n_per_mps2",
    "traction_force_kn", "traction_power_kw", "accel_max_mps2",
    "service_brake_mps2", "service_brake_load_pax", "regen_force_kn", "regen_power_kw",
    "friction_brake_force_kn",
    "emergency_brake_mps2", "emergency_brake_actual_mps2", "jerk_max_mps3",
    "emergency_jerk_mps3", "regen_fade_speed_kmh", "axles_per_car", "motored_axle_fraction",
    "wheel_radius_m", "wheel_inertia_kgm2", "brake_radius_m", "pad_mu_nominal",
    "capacity_pax", "traction_efficiency", "regen_efficiency", "aux_power_kw",
)
"""Keys accepted by :func:`train_params_from_data` (units in the suffix, km/h, kN, kW)."""


def train_params_from_data(base: TrainParams, data: dict[str, float | int | None]
                           ) -> TrainParams:
    """Rolling stock described by data, on top of a preset ``base`` (None = keep the preset).

    Keys (:data:`STOCK_KEYS`, SI unless the suffix says km/h, kN or kW):

    - ``mass_kg``: mass with ``mass_load_pax`` persons on board (default: the preset's
      ``nominal_load_pax``), or ``tare_mass_kg`` (empty) instead; ``pax_mass_kg`` per
      person.  The empty mass must be positive (ValueError).  Without explicit Davis
      terms, A and B scale with the mass
      (rolling / mechanical resistance is proportional to the weight) and C (aerodynamic)
      is kept; without an explicit traction force the preset's tractive *force* is kept
      (a1 scales with 1/mass), so a heavier train accelerates less.
    - ``rotating_allowance`` lambda (effective mass m (1 + lambda)), ``length_m``, ``cars``,
      ``max_speed_kmh``, ``capacity_pax``;
    - ``davis_a_n`` [N], ``davis_b_n_per_mps`` [N/(m/s)], ``davis_c_n_per_mps2`` [N/(m/s)^2];
    - ``traction_force_kn`` and ``traction_power_kw``: constant force up to
      v_1 = P / F, constant power above (ACTP n.d., eq. 3 and 5 with a_2 region collapsed:
      v_2 -> infinity); ``accel_max_mps2`` caps the starting acceleration F / m (the force
      below v_1 = P / (m a_max) is then m a_max);
    - ``service_brake_mps2``, or brake forces ``regen_force_kn`` + ``friction_brake_force_kn``
      divided by the mass (the smaller of the two when both are given);
      ``regen_power_kw``: electric brake power limit; ``service_brake_load_pax``: the load
      up to which the service brake is load-weighed (default: ``capacity_pax``, crush);
    - ``emergency_brake_mps2`` (guaranteed, used by ATP), ``emergency_brake_actual_mps2``
      (nominal), ``jerk_max_mps3``, ``emergency_jerk_mps3`` (build-up rate);
    - ``regen_fade_speed_kmh``, ``axles_per_car``, ``motored_axle_fraction``,
      ``wheel_radius_m``, ``wheel_inertia_kgm2``, ``brake_radius_m``, ``pad_mu_nominal``;
    - ``traction_efficiency``, ``regen_efficiency`` [-], ``aux_power_kw``.

    Every key left None keeps the preset's value, so ``train_params_from_data(p, {})`` is
    ``p`` itself.  Raises ValueError whose message starts with the key at fault on an
    unknown key or an inconsistent set (emergency
    deceleration below the service brake's guaranteed part is allowed; a non-positive value is
    not).
    """
    unknown = set(data) - set(STOCK_KEYS)
    if unknown:
        raise ValueError(f"unknown rolling-stock keys {sorted(unknown)}")
    d = {k: v for k, v in data.items() if v is not None}
    if not d:
        return base
    for k, v in d.items():
        if not (isinstance(v, (int, float)) and np.isfinite(v) and v >= 0.0):
            raise ValueError(f"{k}: expected a finite number >= 0, got {v!r}")
    over: dict[str, Any] = {}
    m0 = base.mass_kg
    m = _loaded_mass(base, d, over)
    if m != m0:
        over["mass_kg"] = m
        over["davis_a_n"] = base.davis_a_n * m / m0
        over["davis_b_n_per_mps"] = base.davis_b_n_per_mps * m / m0
        over["a1_mps2"] = base.a1_mps2 * m0 / m
    simple = {"rotating_allowance": "rotary_allowance", "length_m": "length_m", "cars": "cars",
              "davis_a_n": "davis_a_n", "davis_b_n_per_mps": "davis_b_n_per_mps",
              "davis_c_n_per_mps2": "davis_c_n_per_mps2",
              "emergency_brake_mps2": "emergency_brake_mps2",
              "emergency_brake_actual_mps2": "emergency_brake_actual_mps2",
              "jerk_max_mps3": "max_jerk_mps3", "capacity_pax": "capacity_pax",
              "emergency_jerk_mps3": "emergency_jerk_mps3", "axles_per_car": "axles_per_car",
              "motored_axle_fraction": "motored_axle_fraction",
              "wheel_radius_m": "wheel_radius_m", "wheel_inertia_kgm2": "wheel_inertia_kgm2",
              "brake_radius_m": "brake_radius_m", "pad_mu_nominal": "pad_mu_nominal",
              "traction_efficiency": "traction_efficiency",
              "regen_efficiency": "regen_efficiency",
              "service_brake_load_pax": "service_brake_load_pax"}
    for key, attr in simple.items():
        if key in d:
            over[attr] = int(d[key]) if attr in ("cars", "axles_per_car") else float(d[key])
    if "max_speed_kmh" in d:
        over["max_speed_mps"] = float(d["max_speed_kmh"]) / 3.6
    if "regen_fade_speed_kmh" in d:
        over["regen_fade_speed_mps"] = float(d["regen_fade_speed_kmh"]) / 3.6
    if "aux_power_kw" in d:
        over["aux_power_w"] = float(d["aux_power_kw"]) * 1e3
    if "traction_force_kn" in d or "traction_power_kw" in d or "accel_max_mps2" in d:
        f = float(d.get("traction_force_kn", m * over.get("a1_mps2", base.a1_mps2) / 1e3)) * 1e3
        a1 = f / m
        if "accel_max_mps2" in d:
            a1 = min(a1, float(d["accel_max_mps2"]))
        if a1 <= 0.0:
            raise ValueError("traction_force_kn: traction force / acceleration must be > 0")
        over["a1_mps2"] = a1
        if "traction_power_kw" in d:
            p_w = float(d["traction_power_kw"]) * 1e3
            if p_w <= 0.0:
                raise ValueError("traction_power_kw: expected > 0")
            over["v1_mps"] = p_w / (m * a1)
            over["v2_mps"] = 1e9
            over["b2_mps"] = 0.0
            over["b3_mps"] = 0.0
    brake: list[float] = []
    if "service_brake_mps2" in d:
        brake.append(float(d["service_brake_mps2"]))
    if "regen_force_kn" in d or "friction_brake_force_kn" in d:
        brake.append((float(d.get("regen_force_kn", 0.0))
                      + float(d.get("friction_brake_force_kn", 0.0))) * 1e3 / m)
    if brake:
        b = min(brake)
        if b <= 0.0:
            raise ValueError("service_brake_mps2: service brake deceleration must be > 0")
        over["max_service_brake_mps2"] = b
    if "regen_power_kw" in d:
        over["max_regen_power_w"] = float(d["regen_power_kw"]) * 1e3
    return dataclasses.replace(base, **over) if over else base


def _loaded_mass(base: TrainParams, d: dict[str, float | int], over: dict[str, Any]
                 ) -> float:
    """Mass incl. its nominal load [kg] from ``mass_kg`` or ``tare_mass_kg`` (module doc).

    ``mass_load_pax`` (the persons ``mass_kg`` includes; the preset's nominal load when
    absent) and ``pax_mass_kg`` go into ``over``; raises ValueError naming the key when the
    empty mass would not be positive.
    """
    if "mass_kg" in d and "tare_mass_kg" in d:
        raise ValueError("tare_mass_kg: give mass_kg (with mass_load_pax) or tare_mass_kg, "
                         "not both")
    if "mass_load_pax" in d and "mass_kg" not in d and "tare_mass_kg" not in d:
        raise ValueError("mass_load_pax: the load mass_kg includes needs mass_kg or "
                         "tare_mass_kg with it")
    pax = float(d.get("pax_mass_kg", base.pax_mass_kg))
    load = float(d.get("mass_load_pax", base.nominal_load_pax))
    if "pax_mass_kg" in d:
        over["pax_mass_kg"] = pax
    if "mass_load_pax" in d:
        over["nominal_load_pax"] = load
    if "tare_mass_kg" in d:
        tare = float(d["tare_mass_kg"])
        if tare <= 0.0:
            raise ValueError(f"tare_mass_kg: expected > 0, got {tare:g}")
        return tare + load * pax
    m = float(d.get("mass_kg", base.mass_kg))
    if m - load * pax <= 0.0:
        key = "mass_kg" if "mass_kg" in d else "pax_mass_kg"
        raise ValueError(f"{key}: empty mass mass_kg - mass_load_pax x pax_mass_kg = "
                         f"{m:g} - {load:g} x {pax:g} = {m - load * pax:g} kg, expected > 0 "
                         f"(mass_load_pax: the load mass_kg includes; or give tare_mass_kg)")
    return m


def train_params_from_spec(base: TrainParams, trains: Any, energy: Any) -> TrainParams:
    """Rolling stock of a scenario: ``base`` preset with its ``trains`` / ``energy`` data.

    ``trains`` is the scenario's ``trains`` section (mass_kg, length_m, max_speed_kmh,
    capacity_pax and the ``stock`` mapping), ``energy`` its ``energy`` section (efficiencies,
    auxiliary power); see :func:`train_params_from_data` for the semantics.
    """
    return train_params_from_data(base, stock_data_of_spec(trains, energy))


def train_params_of_section(trains: Any, energy: Any) -> TrainParams:
    """Rolling stock of a scenario's ``trains`` section (its ``preset`` with the data)."""
    return train_params_from_spec(PRESETS[trains.preset], trains, energy)


def stock_data_of_spec(trains: Any, energy: Any) -> dict[str, float | int | None]:
    """Rolling-stock data of a scenario's ``trains`` and ``energy`` sections.

    One entry per :data:`STOCK_KEYS` key; None = not given.
    """
    data: dict[str, float | int | None] = {
        "mass_kg": trains.mass_kg, "tare_mass_kg": trains.tare_mass_kg,
        "mass_load_pax": trains.mass_load_pax, "pax_mass_kg": trains.pax_mass_kg,
        "length_m": trains.length_m,
        "max_speed_kmh": trains.max_speed_kmh, "capacity_pax": trains.capacity_pax,
        "traction_efficiency": energy.traction_efficiency,
        "regen_efficiency": energy.regen_efficiency, "aux_power_kw": energy.aux_power_kw,
    }
    stock = trains.stock
    for f in dataclasses.fields(stock):
        data[f.name] = getattr(stock, f.name)
    return data
