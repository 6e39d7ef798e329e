"""ROS-free glue between a loaded scenario and the node cores (timetable, track, train).

The line simulator is the single source of truth for the line geometry and the timetable
(seed 000 eq. 10); the ATS and ATO nodes build the same deterministic objects from the same
scenario file.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from metro_atc.core.plant.line import LineSim, train_params_for
from metro_atc.core.plant.scenario import Scenario
from metro_atc.core.plant.vehicle import G_MPS2, TrainParams, Track


@dataclass(frozen=True)
class Timetable:
    """The scenario's timetable; times are simulation seconds.

    ``departure_s[i, j]``/``arrival_s[i, j]``: scheduled departure/arrival of train i at
    station j; ``running_s[j]``: scheduled running time from station j to j+1;
    ``dwell_s[i, j]`` scheduled dwell; ``min_running_s[j]`` flat-out
    running time.
    """

    train_ids: list[str]
    station_names: list[str]
    station_positions_m: NDArray[np.float64]
    departure_s: NDArray[np.float64]
    arrival_s: NDArray[np.float64]
    running_s: NDArray[np.float64]
    min_running_s: NDArray[np.float64]
    dwell_s: NDArray[np.float64]


def timetable_for(scn: Scenario) -> Timetable:
    """Scheduled departures, running and dwell times of a scenario (seed 000 eq. 10)."""
    sim = LineSim(scn, seed=0)
    dep = np.asarray(sim.sched_dep, dtype=float)
    arr = np.asarray(sim.sched_arr, dtype=float)
    dwell = np.where(np.isfinite(dep - arr), dep - arr, 0.0)
    return Timetable(list(sim.train_ids), list(sim.station_names),
                     np.asarray(sim.station_positions_m, dtype=float),
                     dep, arr,
                     np.asarray(sim.sched_running_s, dtype=float),
                     np.asarray(sim.min_running_s, dtype=float), dwell)


def train_for(scn: Scenario) -> TrainParams:
    """Train parameters of a scenario (preset plus overrides)."""
    return train_params_for(scn)


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


__all__ = ["G_MPS2", "Timetable", "timetable_for", "track_for", "train_for"]
