"""Guaranteed emergency deceleration of a train on level track (ATP braking model).

Used by the ATP constants (:mod:`metro_atc.core.line.atp_constants`) and by the scenario
loader, which refuses a nominal emergency brake weaker than this guarantee.  SI units.
"""

from __future__ import annotations

from metro_atc.core import laws
from metro_atc.core.line.adhesion import AdhesionCurve
from metro_atc.core.line.vehicle import TrainParams


def level_guaranteed_decel(given_mps2: float | None, p: TrainParams,
                           curve: AdhesionCurve) -> float:
    """Guaranteed emergency deceleration on level track [m/s^2].

    ``given_mps2`` (``signalling.guaranteed_decel_mps2``) when not None, else the rolling
    stock's guaranteed rate limited by the locked-wheel adhesion of ``curve`` with a 10 %
    margin, for the empty train (the smallest adhesion mass relative to the rotating
    allowance; the scenario loader refuses a non-positive empty mass).
    """
    if given_mps2 is not None:
        return float(given_mps2)
    m_rot = p.rotary_allowance * p.mass_kg
    tare = p.tare_mass_kg
    return float(min(p.emergency_brake_mps2,
                     laws.plain.adhesion_guaranteed_decel(curve.mu_slide, tare, m_rot)))
