"""ROS-free glue between a loaded scenario and the node cores (timetable, track, train).

The static line description (:mod:`metro_atc.core.line`) is the single source of truth for
the line geometry and the timetable (Lin 2010a, eq. 10); the ATS, the ATO and the line
simulator build the same deterministic objects from the same scenario file, without the
plant.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from metro_atc.core.atr.lines import SEPARATION_MIN_S, atr_line_for
from metro_atc.core.line.rolling_stock import train_params_for
from metro_atc.core.line.scenario import Scenario
from metro_atc.core.line.service import Timetable, timetable_for
from metro_atc.core.line.vehicle import G_MPS2, TrainParams, Track

if TYPE_CHECKING:
    from metro_atc.core.ato.envelope import OperatingLimits


def train_for(scn: Scenario) -> TrainParams:
    """Train parameters of a scenario (preset plus overrides)."""
    return train_params_for(scn)


def ato_limits_for(train: TrainParams) -> "OperatingLimits":
    """Planning limits of the ATO for a train (used by the ATO node and the energy curves).

    Braking curves at 80 % of the maximum service brake (0.8 m/s^2 for the metro, 0.44 m/s^2
    for the THSR 700T) [m/s^2], net acceleration min(1, a1) [m/s^2] and the train's jerk
    limit [m/s^3] (Ke 2010).
    """
    from metro_atc.core.ato.envelope import OperatingLimits
    return OperatingLimits(accel_max_mps2=min(1.0, train.a1_mps2),
                           brake_decel_mps2=0.8 * train.max_service_brake_mps2,
                           jerk_max_mps3=train.max_jerk_mps3)


def track_for(scn: Scenario) -> Track:
    """Piecewise-constant grades and permanent speed limits of a scenario [SI]."""
    ln = scn.line
    if ln.gradients:
        g_starts = np.array([-1e12] + [g.start_m for g in ln.gradients], dtype=float)
        grades = np.array([0.0] + [g.grade_permille / 1000.0 for g in ln.gradients])
    else:
        g_starts, grades = np.array([-1e12]), np.array([0.0])
    line_v = ln.line_speed_kmh / 3.6
    if ln.speed_limits:
        l_starts = np.array([-1e12] + [s.start_m for s in ln.speed_limits], dtype=float)
        limits = np.array([line_v] + [s.limit_kmh / 3.6 for s in ln.speed_limits])
    else:
        l_starts, limits = np.array([-1e12]), np.array([line_v])
    return Track(g_starts, grades, l_starts, limits)


__all__ = ["G_MPS2", "SEPARATION_MIN_S", "Timetable", "ato_limits_for", "atr_line_for",
           "timetable_for", "track_for", "train_for"]
