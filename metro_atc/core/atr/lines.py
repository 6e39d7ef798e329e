"""ATR line models of scenarios: the traffic-model line (Lin 2010a, eq. 1-10) of a scenario.

The geometry and the timetable come from the static line description
(:mod:`metro_atc.core.line.service`), never from the plant; the traffic-model constants the
scenario does not define are the estimates of :mod:`metro_atc.core.atr.blue_line`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from metro_atc.core.atr.blue_line import LineData, Period, small_line, taipei_blue
from metro_atc.core.line.rolling_stock import train_params_for
from metro_atc.core.line.scenario import Scenario, ScenarioError, load_scenario
from metro_atc.core.line.service import Timetable, timetable_for
from metro_atc.core.line.timetable import PassengerFlow, nominal_dwells, required_dwell

SEPARATION_MIN_S = 40.0
"""Shortest time from a departure until the follower arrives at the same platform [s]:
39-40 s measured at the intermediate stations of ``taipei_blue_delay`` (a follower held by
moving-block ATP behind its leader, 50 m safety margin, 140 m trains); the ATR estimate of
60 s (a fixed-block figure) made the trained regulators hold followers the plant would not
have delayed."""

DWELL_FIT_RANGE_S = 180.0
"""Arrival delays over which the dwell-effective boarding coefficient is fitted [s]: the
delays the regulators are built for (Lin 2010a, Exp. 2's 180 s initial delay, the validation
delay of :mod:`metro_atc.core.atr.weights_store`)."""
DWELL_FIT_POINTS = 61
"""Arrival delays 0, 3, ..., 180 s of the fit."""


@dataclass(frozen=True)
class DwellModel:
    """The plant's peak dwell law of a scenario as the traffic model needs it (SI).

    Arrays are per station j.  ``scheduled_s``: the timetable's peak dwell (what the plant
    holds a punctual train to); ``delays_s`` (M,): arrival delays of a train whose leader
    left on time; ``departure_dev_s`` (M, N): the plant's departure deviation at j for each
    of them (the dwell law of :mod:`metro_atc.core.plant.stations`: passenger exchange
    :func:`~metro_atc.core.line.timetable.required_dwell` with the waiting passengers of
    the longer gap, alighting, minimum dwell and capacity, never before the timetable);
    ``c_j``: the scenario's boarding coefficient ``t_b q_j``; ``c_eff``: the
    dwell-effective coefficient (:func:`plant_dwell_model`).
    """

    scheduled_s: np.ndarray
    delays_s: np.ndarray
    departure_dev_s: np.ndarray
    c: np.ndarray
    c_eff: np.ndarray


def plant_dwell_model(scn: Scenario) -> DwellModel:
    """The plant's peak dwell law of a scenario and its linear fit.

    A train arriving ``d`` late at station j (its leader left on time) departs
    ``x_j(d) = max(d + dwell(d) - S_j, 0)`` late in the plant, with ``dwell(d)`` the
    passenger exchange of the plant (door overhead, alighting, boarding of the passengers
    who came during the longer gap and during the dwell, at least the minimum dwell, at most
    a full train) and ``S_j`` the timetable's dwell.  The traffic model (Lin 2010a, eq. 5)
    predicts ``d / (1 - c_j)``.  ``c_eff_j`` is the least-squares fit of that line to
    ``x_j`` over ``d`` in [0, ``DWELL_FIT_RANGE_S``], within [0, c_j]: 0 where the dwell
    sits at the minimum dwell (or the train is full) for every delay of the range, close to
    ``c_j`` where boarding sets the dwell.
    """
    periods = scn.timetable.periods
    peak = min(range(len(periods)), key=lambda k: periods[k].headway_s)
    h = float(periods[peak].headway_s)
    board = np.asarray(periods[peak].boarding_pph, dtype=float)
    pax = scn.passengers
    t_b, t_a = float(pax.boarding_s_per_pax), float(pax.alighting_s_per_pax)
    over, d_min = float(pax.door_overhead_s), float(pax.min_dwell_s)
    n = board.size
    frac = np.asarray(pax.alight_fraction, dtype=float).copy()
    frac[-1] = 1.0
    cap = float(train_params_for(scn).capacity_pax)
    load0 = float(scn.trains.initial_load_pax)
    sched, load_out = nominal_dwells(PassengerFlow([0.0], board[None, :]), [h], frac, cap,
                                     load0, t_b, t_a, over, d_min)
    sched = sched[0].astype(float)
    load_in = np.concatenate(([load0], load_out[0, :-1]))
    q = board / 3600.0
    q[-1] = 0.0  # nobody boards at the terminus
    c = t_b * q
    delays = np.linspace(0.0, DWELL_FIT_RANGE_S, DWELL_FIT_POINTS)
    dev = np.zeros((delays.size, n))
    c_eff = np.zeros(n)
    for j in range(n):
        alight = load_in[j] * frac[j]
        room = cap - (load_in[j] - alight)
        for a, d in enumerate(delays):
            waiting = q[j] * max(h - sched[j] + d, 0.0)
            dwell, _ = required_dwell(waiting, float(q[j]), alight, room, t_b, t_a, over, d_min)
            dev[a, j] = max(d + dwell - sched[j], 0.0)
        slope = float(delays @ dev[:, j] / (delays @ delays))
        c_eff[j] = float(np.clip(1.0 - 1.0 / max(slope, 1.0), 0.0, c[j]))
    return DwellModel(sched, delays, dev, c, c_eff)


def atr_line_for(scn: Scenario, tt: Timetable | None = None) -> "LineData":
    """The ATR traffic-model line (Lin 2010a, eq. 1-10) of a scenario.

    Geometry, scheduled and minimum running times come from the scenario timetable (the
    simulator's); headway from its peak period; the dwell from the plant's dwell law at the
    peak (:func:`plant_dwell_model`):

    - the model's steady dwell ``S_j + c_j H`` is the timetable's dwell (door overhead,
      alighting and boarding time, at least the minimum dwell): ``S_j`` = scheduled dwell
      minus ``c_j H``;
    - ``c_j`` (through ``boarding_pax_h``, the *dwell-effective* boarding rate) is fitted
      to how the plant's dwell grows with a late train's arrival delay (``c_eff`` of
      :func:`plant_dwell_model`): 0 where the dwell stays at the minimum dwell, close to
      the scenario's ``t_b q_j`` where boarding sets the dwell (the earlier model took
      ``t_b q_j`` everywhere and the door overhead as ``S_j``: dwells 1-8 s shorter than
      the timetable's and delays growing where the plant's do not);
    - the dwell can be cut down to the minimum dwell: ``dwell_fixed_min_s = min_dwell -
      c_j H`` (>= 0).

    The remaining traffic-model constants (maximum running time +15 %, holding limit 60 s,
    crowding) are the ATR estimates of :func:`metro_atc.core.atr.blue_line.taipei_blue`,
    except the platform re-occupation time: ``SEPARATION_MIN_S`` as measured in the graph.
    """
    tt = tt if tt is not None else timetable_for(scn)
    est = taipei_blue()
    st = scn.line.stations
    periods = scn.timetable.periods
    peak = min(range(len(periods)), key=lambda k: periods[k].headway_s)
    pax = scn.passengers
    h = float(periods[peak].headway_s)
    dm = plant_dwell_model(scn)
    t_b = float(pax.boarding_s_per_pax)
    board = dm.c_eff * 3600.0 / t_b if t_b > 0.0 else np.zeros_like(dm.c_eff)
    fixed = dm.scheduled_s - dm.c_eff * h
    fixed_min = np.minimum(np.maximum(float(pax.min_dwell_s) - dm.c_eff * h, 0.0), fixed)
    ends = [p.start_s for p in periods[1:]] + [float(scn.sim.duration_s)]
    peak_rate = max(float(np.sum(periods[peak].boarding_pph)), 1e-9)
    return LineData(
        name=scn.name,
        station_codes=tuple(s.code or f"S{j:02d}" for j, s in enumerate(st)),
        station_names=tuple(s.name for s in st),
        distance_m=np.diff(tt.station_positions_m),
        run_s=np.asarray(tt.running_s, dtype=float),
        run_min_s=np.asarray(tt.min_running_s, dtype=float),
        run_max_s=np.asarray(tt.min_running_s, dtype=float) * 1.15,
        dwell_fixed_s=fixed,
        dwell_fixed_min_s=fixed_min,
        hold_max_s=est.hold_max_s,
        boarding_pax_h=board,
        t_board_s=t_b,
        headway_s=h,
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

    ``blue_line_estimates``: :func:`taipei_blue` (this module's estimates; the Lin 2010a
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
