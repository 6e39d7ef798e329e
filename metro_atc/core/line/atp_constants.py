"""ATP constants of a scenario (Ke 2010, Fig. 1): a pure function of the scenario and train.

The plant's :class:`metro_atc.core.plant.atp.AtpSupervisor` supervises with them and the ATO
(:func:`metro_atc.core.ato.onboard.atp_model_for`) plans inside the same envelope; neither
derives them on its own.  SI units; the formulas are those of :mod:`metro_atc.core.laws`.
"""

from __future__ import annotations

import dataclasses
import math

from metro_atc.core import laws
from metro_atc.core.line.adhesion import CURVES, AdhesionCurve
from metro_atc.core.line.geometry import LineGeometry
from metro_atc.core.line.guarantee import level_guaranteed_decel
from metro_atc.core.line.scenario import Scenario
from metro_atc.core.line.vehicle import TrainParams

SBI_OFFSET_MPS = 0.3
"""The service-brake intervention speed lies this far below the speed of the SBI braking
curve (``v_sbi = min(sbi_static, v_sbi(MA)) - SBI_OFFSET_MPS``) [m/s]."""


@dataclasses.dataclass(frozen=True)
class AtpConstants:
    """Worst-case assumptions of the ATP braking curves.

    ``b_guar_level`` guaranteed emergency deceleration on level track [m/s^2], ``b_g`` the
    same on the steepest downhill grade [m/s^2], ``a_w`` worst-case acceleration during the
    response time at standstill [m/s^2], ``g_down`` the steepest downhill grade's
    acceleration [m/s^2], ``t_r`` response time [s], ``t_sbi`` service-brake intervention
    lead [s], ``margin_m`` safety margin behind the train ahead [m], ``tsr_notice_s`` time
    ATP knows a TSR before it applies [s], ``fixed_block`` signalling mode, ``n_resp`` /
    ``n_sbi`` grid cells covered at the design speed during the response time / SBI lead.
    """

    b_guar_level: float
    b_g: float
    a_w: float
    g_down: float
    t_r: float
    t_sbi: float
    margin_m: float
    tsr_notice_s: float
    fixed_block: bool
    n_resp: int
    n_sbi: int


def atp_constants(scn: Scenario, p: TrainParams, geom: LineGeometry,
                  curve: AdhesionCurve | None = None) -> AtpConstants:
    """The ATP constants of a scenario (``curve``: its adhesion curve by default).

    Raises ``ValueError`` when the guaranteed emergency deceleration is not positive on the
    steepest downhill grade.
    """
    sg = scn.signalling
    b_lvl = level_guaranteed_decel(sg.guaranteed_decel_mps2, p,
                                   CURVES[scn.line.adhesion] if curve is None else curve)
    b_g = float(laws.guaranteed_decel_on_grade(b_lvl, geom.max_down))
    if b_g <= 0.05:
        raise ValueError("guaranteed emergency braking is not positive on the steepest "
                         "downhill grade")
    a_w = float(laws.response_accel(p.a1_mps2, geom.max_down))
    t_r = float(sg.response_time_s)
    t_sbi = float(sg.sbi_lead_s)
    d_r = laws.response_distance(p.max_speed_mps, a_w, t_r)
    return AtpConstants(
        b_guar_level=float(b_lvl), b_g=b_g, a_w=a_w,
        g_down=float(laws.downhill_accel(geom.max_down)), t_r=t_r,
        t_sbi=t_sbi, margin_m=float(sg.safety_margin_m), tsr_notice_s=float(sg.tsr_notice_s),
        fixed_block=sg.mode == "fixed_block",
        n_resp=int(math.ceil(d_r / geom.dx)) + 1,
        n_sbi=int(math.ceil(p.max_speed_mps * t_sbi / geom.dx)) + 1)
