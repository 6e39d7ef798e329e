"""ROS-free glue between a loaded scenario and the node cores (timetable, track, train).

The line simulator is the single source of truth for the line geometry and the timetable
(seed 000 eq. 10); the ATS and ATO nodes build the same deterministic objects from the same
scenario file.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from metro_atc.core.plant.line import LineSim, train_params_for
from metro_atc.core.line.scenario import Scenario
from metro_atc.core.line.vehicle import G_MPS2, TrainParams, Track

if TYPE_CHECKING:
    from metro_atc.core.ato.envelope import OperatingLimits
    from metro_atc.core.atr.blue_line import LineData


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


def ato_limits_for(train: TrainParams) -> "OperatingLimits":
    """Planning limits of the ATO for a train (used by the ATO node and the energy curves).

    Braking curves at 80 % of the maximum service brake (0.8 m/s^2 for the metro, 0.44 m/s^2
    for the THSR 700T) [m/s^2], net acceleration min(1, a1) [m/s^2] and the train's jerk
    limit [m/s^3] (seed 001).
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


SEPARATION_MIN_S = 40.0
"""Shortest time from a departure until the follower arrives at the same platform [s]:
39-40 s measured at the intermediate stations of ``taipei_blue_delay`` (a follower held by
moving-block ATP behind its leader, 50 m safety margin, 140 m trains); the ATR estimate of
60 s (a fixed-block figure) made the trained regulators hold followers the plant would not
have delayed."""


def atr_line_for(scn: Scenario, tt: Timetable | None = None) -> "LineData":
    """The ATR traffic-model line (seed 000 eq. 1-10) of a scenario.

    Geometry, scheduled and minimum running times come from the scenario timetable (the
    simulator's); passenger rates, boarding time and headway from its peak period; the
    remaining traffic-model constants (maximum running time +15 %, holding limit 60 s,
    crowding) are the ATR estimates of :func:`metro_atc.core.atr.blue_line.taipei_blue`,
    except the platform re-occupation time: ``SEPARATION_MIN_S`` as measured in the graph.
    """
    from metro_atc.core.atr.blue_line import LineData, Period, taipei_blue

    tt = tt if tt is not None else timetable_for(scn)
    est = taipei_blue()
    st = scn.line.stations
    n = len(st)
    periods = scn.timetable.periods
    peak = min(range(len(periods)), key=lambda k: periods[k].headway_s)
    pax = scn.passengers
    board = np.asarray(periods[peak].boarding_pph, dtype=float)
    fixed = np.full(n, float(pax.door_overhead_s))
    ends = [p.start_s for p in periods[1:]] + [float(scn.sim.duration_s)]
    peak_rate = max(float(board.sum()), 1e-9)
    return LineData(
        name=scn.name,
        station_codes=tuple(s.code or f"S{j:02d}" for j, s in enumerate(st)),
        station_names=tuple(s.name for s in st),
        distance_m=np.diff(tt.station_positions_m),
        run_s=np.asarray(tt.running_s, dtype=float),
        run_min_s=np.asarray(tt.min_running_s, dtype=float),
        run_max_s=np.asarray(tt.min_running_s, dtype=float) * 1.15,
        dwell_fixed_s=fixed,
        dwell_fixed_min_s=np.minimum(fixed, float(pax.min_dwell_s)),
        hold_max_s=est.hold_max_s,
        boarding_pax_h=board,
        t_board_s=float(pax.boarding_s_per_pax),
        headway_s=float(periods[peak].headway_s),
        separation_min_s=SEPARATION_MIN_S,
        disturbance_mean_s=float(scn.disturbances.departure_delay_mean_s
                                 * scn.disturbances.departure_delay_prob),
        crowding_gain=est.crowding_gain,
        board_max_s=est.board_max_s,
        periods=tuple(Period(p.start_s, e, p.headway_s,
                             float(np.sum(p.boarding_pph)) / peak_rate)
                      for p, e in zip(periods, ends)),
    )


__all__ = ["G_MPS2", "Timetable", "ato_limits_for", "atr_line_for", "timetable_for",
           "track_for", "train_for"]
