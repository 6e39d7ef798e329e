"""Energy meter of a fleet [J]: traction and braking work at the wheels, resistances, grade.

The compiled step adds each period's work to the counters (:func:`.kernel_step.motion`).
Rail braking work is split into electric (regenerated x efficiency x receptivity) and
friction; substation energy = wheel traction / efficiency + auxiliary - regenerated.  The
balance closes to RK4 accuracy (test_plant_energy.py): in a period that ends at rest the
friction brake absorbs what is left (its force drops to the static holding value).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from metro_atc.core.line.vehicle import TrainParams

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]


class EnergyMeter:
    """Per-train energy counters [J]."""

    def __init__(self, n: int, p: TrainParams, regen_receptivity: float,
                 control_period_s: float) -> None:
        """Zero counters for ``n`` trains."""
        self.e_trac = np.zeros(n)
        self.e_elec = np.zeros(n)
        self.e_fric = np.zeros(n)
        self.e_res = np.zeros(n)
        self.e_curve = np.zeros(n)
        self.e_grade = np.zeros(n)
        self.n_in_service = np.zeros(n, dtype=np.int64)  # steps in service (auxiliary load)
        self.e_stop_corr = np.zeros(n)  # |brake work re-assigned in steps ending at rest|
        self.traction_efficiency = p.traction_efficiency
        self.regen_eff = p.regen_efficiency * regen_receptivity
        self.aux_dt = p.aux_power_w * control_period_s

    @property
    def e_brake_rail(self) -> FloatArray:
        """Braking work at the wheels, electric + friction [J] per train."""
        return np.asarray(self.e_elec + self.e_fric)

    @property
    def e_regen(self) -> FloatArray:
        """Regenerated energy returned to the line [J] per train."""
        return np.asarray(self.e_elec * self.regen_eff)

    @property
    def e_aux(self) -> FloatArray:
        """Auxiliary energy drawn while in service [J] per train."""
        return np.asarray(self.n_in_service * self.aux_dt)

    @property
    def e_substation(self) -> FloatArray:
        """Energy drawn from the substations [J] per train (traction, auxiliary, regen).

        Wheel traction / traction efficiency + auxiliary - regenerated.
        """
        return np.asarray(self.e_trac / self.traction_efficiency + self.e_aux - self.e_regen)

    def breakdown(self, kinetic: FloatArray) -> dict[str, FloatArray]:
        """Per-train energy terms [J]; ``kinetic`` the current kinetic energy [J]."""
        return {
            "traction_wheel": self.e_trac.copy(), "brake_rail": self.e_brake_rail.copy(),
            "electric_brake": self.e_elec.copy(), "friction_brake": self.e_fric.copy(),
            "resistance": self.e_res.copy(), "curve": self.e_curve.copy(),
            "grade": self.e_grade.copy(), "aux": self.e_aux.copy(),
            "regen_to_line": self.e_regen.copy(), "stop_correction": self.e_stop_corr.copy(),
            "kinetic": kinetic,
            "substation": self.e_substation,
        }
