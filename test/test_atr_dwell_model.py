"""The ATR traffic model of a scenario predicts the plant's dwells.

The regulators (LQR, DHP, AOC) are built on the traffic model of
:func:`metro_atc.core.atr.lines.atr_line_for` (Lin 2010a, eq. 5).  These tests check it against
what the plant does, computed here from the plant's own dwell law
(:func:`metro_atc.core.line.timetable.required_dwell`, called by
:meth:`metro_atc.core.plant.stations.Stations.set_release` with the passengers waiting since
the previous departure, the train held to the timetable) on several generated lines and on
``taipei_blue``:

- punctual operation: the model's steady dwell ``S_j + c_j H`` is the timetable's dwell
  (which the plant holds a punctual train to) within 1 ms;
- a late train: arriving ``d`` late at station j (0 <= d <= 180 s, its leader left on time,
  no control), the model's departure deviation (the traffic model's step with its
  nonlinearities off, i.e. Lin 2010a, eq. 5) is within ``ABS_TOL_S + slack_j + REL_TOL * d``
  of the plant's at every intermediate station, and within ``RMS_TOL_S`` in RMS over the
  stations and delays of a line.  The tolerances are what a linear model cannot do better
  than by construction: the plant's departure deviation is piecewise linear in d (absorbed
  by the hold to the timetable up to its slack_j = timetable dwell minus the exchange a
  punctual train needs, then slope 1 while the minimum dwell binds, then slope
  ``1 / (1 - c_j)`` with boarding), so a line through the origin misses the kinks by up to
  the slack plus ``c_j / (1 - c_j)`` times the delay at which the minimum dwell stops
  binding (3 % of d for c_j <= 0.03).  The traffic model before this fix (door overhead as
  ``S_j``, ``t_b q_j`` at every station) was off by up to 12.8 s (RMS 5.2 s) on these lines.
"""

from __future__ import annotations

import numpy as np
import pytest

from metro_atc.core.atr.lines import atr_line_for
from metro_atc.core.atr.traffic import truth_step_dev
from metro_atc.core.line.rolling_stock import train_params_for
from metro_atc.core.line.scenario import Scenario, load_scenario
from metro_atc.core.line.service import timetable_for
from metro_atc.core.line.timetable import required_dwell
from metro_atc.core.linegen import load_generated

ABS_TOL_S = 2.0
REL_TOL = 0.03
RMS_TOL_S = 1.5
DELAYS_S = np.linspace(0.0, 180.0, 19)
SEEDS = (1, 2, 3, 6, 7, 8)


def _scenarios() -> list[Scenario]:
    return [load_generated(s) for s in SEEDS] + [load_scenario("taipei_blue")]


def _peak(scn: Scenario) -> int:
    per = scn.timetable.periods
    return min(range(len(per)), key=lambda k: per[k].headway_s)


def plant_departure_deviation(scn: Scenario, j: int, delay_s: float) -> tuple[float, float]:
    """Plant departure deviation [s] at station j of a train arriving ``delay_s`` late.

    The leader left j on time; the timetable dwell and the load come from a punctual run of
    the peak (every train alike): waiting passengers = demand x (time since the leader's
    departure), then :func:`required_dwell`; doors close at max(timetable, exchange done).
    Returns (deviation, slack): slack = timetable dwell minus the exchange a punctual train
    needs [s] (a delay up to it is absorbed by the hold to the timetable).
    """
    per = scn.timetable.periods[_peak(scn)]
    h = float(per.headway_s)
    q = np.asarray(per.boarding_pph, dtype=float) / 3600.0
    ps = scn.passengers
    frac = np.asarray(ps.alight_fraction, dtype=float).copy()
    frac[-1] = 1.0
    cap = float(train_params_for(scn).capacity_pax)
    load = float(scn.trains.initial_load_pax)
    sched = 0.0
    for i in range(j + 1):  # punctual peak train up to station j
        alight = load * frac[i]
        room = cap - (load - alight)
        sched, board = required_dwell(q[i] * h, float(q[i]), alight, room,
                                      ps.boarding_s_per_pax, ps.alighting_s_per_pax,
                                      ps.door_overhead_s, ps.min_dwell_s)
        if i < j:
            load = load - alight + board
    alight = load * frac[j]
    room = cap - (load - alight)

    def dwell(d: float) -> float:
        waiting = q[j] * max(h - sched + d, 0.0)
        return required_dwell(waiting, float(q[j]), alight, room, ps.boarding_s_per_pax,
                              ps.alighting_s_per_pax, ps.door_overhead_s, ps.min_dwell_s)[0]
    return max(delay_s + dwell(delay_s) - sched, 0.0), sched - dwell(0.0)


@pytest.mark.parametrize("scn", _scenarios(), ids=lambda s: s.name)
def test_model_dwell_is_the_timetable_dwell(scn: Scenario) -> None:
    """Punctual trains: model steady dwell S + cH == the timetable dwell of the peak."""
    line = atr_line_for(scn)
    tt = timetable_for(scn)
    k = _peak(scn)
    per = scn.timetable.periods
    end = per[k + 1].start_s if k + 1 < len(per) else np.inf
    model = line.dwell_fixed_s + line.c() * line.headway_s
    # trains arriving at station j within the peak dwell the peak's timetable dwell
    inside = (tt.arrival_s >= per[k].start_s) & (tt.arrival_s < end)
    for j in range(line.n_stations - 1):
        assert inside[:, j].any()
        np.testing.assert_allclose(model[j], tt.dwell_s[inside[:, j], j], atol=1e-3)
    # the dwell can be cut to the minimum dwell, never below
    lo = line.dwell_fixed_min_s + line.c() * line.headway_s
    assert np.all(lo >= scn.passengers.min_dwell_s - 1e-6)


@pytest.mark.parametrize("scn", _scenarios(), ids=lambda s: s.name)
def test_model_predicts_a_late_trains_departure(scn: Scenario) -> None:
    """Late train, leader on time: model vs plant departure deviation (module docstring)."""
    line = atr_line_for(scn)
    n = line.n_stations
    errs = []
    for j in range(1, n - 1):
        for d in DELAYS_S:
            x = np.zeros(n)
            x[j - 1] = d  # left j-1 d late, scheduled run: arrives d late at j
            model = float(truth_step_dev(line, x, np.zeros(n), saturation=False,
                                         knock_on=False, crowding=False)[j])
            plant, slack = plant_departure_deviation(scn, j, float(d))
            tol = ABS_TOL_S + slack + REL_TOL * d
            assert abs(model - plant) <= tol, (scn.name, j, d, model, plant, slack)
            errs.append(model - plant)
    assert float(np.sqrt(np.mean(np.square(errs)))) <= RMS_TOL_S
