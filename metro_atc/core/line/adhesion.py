"""Wheel-rail slip-adhesion curve (:func:`metro_atc.core.laws.burckhardt_mu`).

Adhesion follows the Burckhardt form ``mu(s) = c1 (1 - exp(-c2 s)) - c3 s`` of the slip
ratio ``s = (v - omega r_w) / v`` (braking, s in [0, 1]).  The coefficients are estimates
chosen for steel wheel on steel rail: dry peak ~0.31 at ~4 % slip falling to 0.24 at lock;
wet peak ~0.12 at ~6 % slip falling to 0.085 at lock, so heavy braking on wet rail slides.

Per-axle wheel dynamics (Lin 2010b, eq. 4, the axle as the lumped "wheel")::

    J_w d(omega)/dt = -2 mu_b R_b F_c + r_w F_x

with F_c the clamp force, mu_b the disk-pad friction coefficient, R_b the effective pad
radius, r_w the wheel radius and F_x the rail force on the wheel (positive forward); the pad
torque ``2 mu_b R_b F_c`` is :func:`metro_atc.core.laws.pad_torque`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from metro_atc.core import laws

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class AdhesionCurve:
    """Burckhardt slip-adhesion curve ``mu(s) = c1 (1 - exp(-c2 s)) - c3 s`` (estimates)."""

    c1: float
    c2: float
    c3: float

    def mu(self, s: ArrayLike) -> FloatArray:
        """Adhesion coefficient [-] at slip ratio s in [0, 1]."""
        return np.asarray(laws.on_array(laws.burckhardt_mu_array, s, self.c1, self.c2,
                                        self.c3))

    @property
    def slip_peak(self) -> float:
        """Slip ratio of the adhesion peak [-] (d mu / d s = 0)."""
        return float(np.log(self.c1 * self.c2 / self.c3) / self.c2)

    @property
    def mu_peak(self) -> float:
        """Peak adhesion coefficient [-] (the law uncompiled: read at load time)."""
        return float(laws.plain.burckhardt_mu(self.slip_peak, self.c1, self.c2, self.c3))

    @property
    def mu_slide(self) -> float:
        """Adhesion coefficient of a locked wheel (s = 1) [-] (uncompiled, as ``mu_peak``)."""
        return float(laws.plain.burckhardt_mu(1.0, self.c1, self.c2, self.c3))

    def slip_for(self, mu_demand: ArrayLike) -> FloatArray:
        """Slip on the stable (rising) branch giving ``mu_demand`` (clipped to the peak).

        Solved with 3 Newton steps from the exponential-only inverse (vectorised).
        """
        m = np.clip(np.asarray(mu_demand, dtype=float), 0.0, self.mu_peak * (1 - 1e-9))
        s = -np.log(np.maximum(1.0 - m / self.c1, 1e-12)) / self.c2
        s = np.minimum(s, self.slip_peak)
        for _ in range(3):
            e = np.exp(-self.c2 * s)
            g = self.c1 * (1.0 - e) - self.c3 * s - m
            dg = self.c1 * self.c2 * e - self.c3
            s = np.clip(s - g / np.maximum(dg, 1e-9), 0.0, self.slip_peak)
        return np.asarray(s)


DRY = AdhesionCurve(c1=0.32, c2=150.0, c3=0.08)
"""Dry rail (estimate): peak ~0.31, locked wheel 0.24."""
WET = AdhesionCurve(c1=0.125, c2=80.0, c3=0.04)
"""Wet rail (estimate): peak ~0.12, locked wheel ~0.085."""

CURVES = {"dry": DRY, "wet": WET}
"""Adhesion curves by rail condition name."""
