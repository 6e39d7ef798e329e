"""AtsDispatcher (the ats_regulator node's core): timetable and regulated commands."""

from __future__ import annotations

import math

import numpy as np
import pytest

from metro_atc.core.atr.dispatch import AtsDispatcher, make_dispatcher
from metro_atc.core.bridge import timetable_for
from metro_atc.core.line.scenario import load_scenario

SCN = load_scenario("mini")
TT = timetable_for(SCN)
MIN_DWELL = float(SCN.passengers.min_dwell_s)


def _dispatcher(regulator: str) -> AtsDispatcher:
    return make_dispatcher(SCN, regulator, tt=TT)


def _run_to(d: AtsDispatcher, i: int, j: int, delay_s: float):
    """Feed train i's events up to its arrival at station j, ``delay_s`` late throughout."""
    tid = TT.train_ids[i]
    out = None
    for s in range(j + 1):
        out = d.on_event(tid, s, "arrival", float(TT.arrival_s[i, s]) + delay_s)
        if s < j:
            d.on_event(tid, s, "departure", float(TT.departure_s[i, s]) + delay_s)
    return out


def test_timetable_commands() -> None:
    """``none``: scheduled departure and running time, never a dwell cut, whatever the delay."""
    d = _dispatcher("none")
    first = d.initial()
    assert [c.station for c in first] == [0] * len(TT.train_ids)
    assert first[1].departure_s == pytest.approx(TT.departure_s[1, 0])
    c = _run_to(d, 0, 1, delay_s=200.0)
    assert c is not None and c.station == 1
    assert c.departure_s == pytest.approx(TT.departure_s[0, 1])
    assert c.running_s == pytest.approx(TT.running_s[1])
    assert math.isnan(c.dwell_limit_s)
    assert d.on_event("train_01", 1, "departure", float(TT.departure_s[0, 1]) + 230.0) is None


def test_regulated_late_train_gets_a_dwell_cut_and_a_short_run() -> None:
    """A late train: dwell cut towards the minimum, running target not above the timetable."""
    d = _dispatcher("lqr")
    c = _run_to(d, 0, 1, delay_s=200.0)
    assert c is not None
    # u_j for a 200 s delay is strongly negative: the cut saturates at the minimum dwell
    assert c.adjustment_s == pytest.approx(MIN_DWELL - TT.dwell_s[0, 1])
    assert c.dwell_limit_s == pytest.approx(MIN_DWELL)
    assert c.departure_s == pytest.approx(TT.departure_s[0, 1])   # no hold beyond it
    assert TT.min_running_s[1] - 1e-9 <= c.running_s <= TT.running_s[1] + 1e-9
    assert c.running_s < TT.running_s[1] - 1.0


def test_slightly_late_train_keeps_its_passengers() -> None:
    """A train within the tolerance is not cut: the doors stay open at least until then."""
    d = _dispatcher("lqr")
    c = _run_to(d, 0, 1, delay_s=10.0)
    assert c is not None and c.adjustment_s < 0.0            # the regulator wants it faster
    arrival = float(TT.arrival_s[0, 1]) + 10.0
    assert arrival + c.dwell_limit_s >= TT.departure_s[0, 1] + d.cut_tolerance_s - 1e-9


def test_regulated_on_time_train_is_not_cut() -> None:
    """An on-time train without delayed neighbours keeps (about) the timetable."""
    d = _dispatcher("lqr")
    c = _run_to(d, 0, 1, delay_s=0.0)
    assert c is not None
    assert abs(c.adjustment_s) < 1.0
    assert c.departure_s >= TT.departure_s[0, 1] - 1e-9
    assert c.running_s == pytest.approx(TT.running_s[1], abs=1.0)


def test_bad_events_raise_clear_errors_and_leave_state() -> None:
    """Unknown train, bad station, NaN, out of order: ValueError naming it; state unchanged."""
    d = _dispatcher("lqr")
    d.on_event("train_01", 0, "arrival", 10.0)
    with pytest.raises(ValueError, match="train_99"):
        d.on_event("train_99", 0, "arrival", 11.0)
    with pytest.raises(ValueError, match="station index 9"):
        d.on_event("train_01", 9, "arrival", 11.0)
    with pytest.raises(ValueError, match="not finite"):
        d.on_event("train_01", 1, "arrival", math.nan)
    with pytest.raises(ValueError, match="out of order"):
        d.on_event("train_01", 0, "arrival", 12.0)
    with pytest.raises(ValueError, match="kind"):
        d.on_event("train_01", 0, "passing", 12.0)
    assert np.isnan(d.arrival_s[0, 1]) and d.arrival_s[0, 0] == 10.0


@pytest.mark.parametrize("regulator", ["none", "lqr"])
def test_replay_gives_the_same_commands(regulator: str) -> None:
    """A restarted ATS fed the same event history decides exactly the same commands."""
    events = []
    for i in range(len(TT.train_ids)):
        for s in range(len(TT.station_names)):
            events.append((float(TT.arrival_s[i, s]) + 40.0 * i, TT.train_ids[i], s, "arrival"))
            events.append((float(TT.departure_s[i, s]) + 40.0 * i, TT.train_ids[i], s,
                           "departure"))
    events.sort()
    a, b = _dispatcher(regulator), _dispatcher(regulator)
    out_a = [a.on_event(tid, s, k, t) for t, tid, s, k in events]
    out_b = [b.on_event(tid, s, k, t) for t, tid, s, k in events]
    assert out_a == out_b or all(
        (x is None and y is None) or (x is not None and y is not None and x.station == y.station
                                      and x.departure_s == y.departure_s
                                      and x.running_s == y.running_s)
        for x, y in zip(out_a, out_b))
    # one command per arrival at stations 1..N-2 (station 0 keeps its start-up command)
    assert sum(c is not None for c in out_a) == len(TT.train_ids) * (len(TT.station_names) - 2)


def test_energy_aware_regulator_stretches_punctual_runs() -> None:
    """``elqr`` (Sheu 2011 option): an on-time train gets a running target above the LQR's."""
    lqr, elqr = _dispatcher("lqr"), _dispatcher("elqr")
    c_lqr, c_e = _run_to(lqr, 0, 1, delay_s=0.0), _run_to(elqr, 0, 1, delay_s=0.0)
    assert c_lqr is not None and c_e is not None
    assert c_e.running_s > c_lqr.running_s + 0.1
    assert c_e.running_s <= TT.running_s[1] * 1.15 / 1.07 + 1e-6     # within run_max


def test_unknown_regulator_is_a_clear_error() -> None:
    """A bad regulator name names the choices."""
    with pytest.raises(ValueError, match="none, lqr, dhp, aoc, elqr"):
        make_dispatcher(SCN, "pid")
