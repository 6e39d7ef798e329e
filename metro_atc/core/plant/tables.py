"""Speed tables of the rolling stock and the inverse adhesion curve (built once per run)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from metro_atc.core import laws
from metro_atc.core.line.adhesion import AdhesionCurve
from metro_atc.core.line.vehicle import TrainParams, max_traction_accel

FloatArray = NDArray[np.float64]


class VehicleTables:
    """Traction phi(v) [m/s^2] (ACTP n.d., eq. 3-5), max electric brake [N], mu -> slip.

    Each table is its law of :mod:`metro_atc.core.laws` at the table's points.

    ``v`` spans 0 .. 1.2 v_max + 5 m/s in 4001 points; ``slip``/``mu`` the stable branch
    of the slip-adhesion curve (400 points) for ``np.interp(mu, tables.mu, tables.slip)``.
    """

    def __init__(self, p: TrainParams, curve: AdhesionCurve) -> None:
        """Tabulate for the rolling stock ``p`` on the rail condition ``curve``."""
        self.v = np.linspace(0.0, p.max_speed_mps * 1.2 + 5.0, 4001)
        self.phi = max_traction_accel(p, self.v)
        self.ebrake = laws.electric_brake_force_max_array(
            self.v, p.mass_kg, p.max_service_brake_mps2, p.max_regen_power_w,
            p.regen_fade_speed_mps)
        self.slip = np.linspace(0.0, curve.slip_peak, 400)
        self.mu = curve.mu(self.slip)
