"""ATR line models of scenarios: the traffic-model line (seed 000 eq. 1-10) of a scenario.

The geometry and the timetable come from the static line description
(:mod:`metro_atc.core.line.service`), never from the plant; the traffic-model constants the
scenario does not define are the estimates of :mod:`metro_atc.core.atr.blue_line`.
"""

from __future__ import annotations

import numpy as np

from metro_atc.core.atr.blue_line import LineData, Period, small_line, taipei_blue
from metro_atc.core.line.scenario import Scenario, ScenarioError, load_scenario
from metro_atc.core.line.service import Timetable, timetable_for

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


def get_line(name: str) -> LineData:
    """Return an ATR line by name.

    ``blue_line_estimates``: :func:`taipei_blue` (this module's estimates; the seed 000
    Exp. 2 bench); ``smallN``: :func:`small_line`; any other name: the embedded scenario or
    scenario file of that name as the ATS node sees it
    (:func:`atr_line_for`), e.g. ``taipei_blue``.
    """
    if name == "blue_line_estimates":
        return taipei_blue()
    if name.startswith("small") and name[5:].isdigit() and int(name[5:]) >= 2:
        return small_line(int(name[5:]))
    try:
        return atr_line_for(load_scenario(name))
    except ScenarioError as exc:
        raise ValueError(f"unknown ATR line {name!r} (not 'blue_line_estimates', 'small<N>' "
                         f"nor a scenario: {exc})") from None
