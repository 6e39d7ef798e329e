"""Regulation across the turnback: the link, the traffic-model hook, the dispatcher hook."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from metro_atc.core.atr.blue_line import small_line, taipei_blue
from metro_atc.core.atr.dispatch import make_dispatcher
from metro_atc.core.atr.evaluation import incident_scenario, simulate, simulate_linked
from metro_atc.core.atr.regulators import Regulator, make_regulator
from metro_atc.core.atr.traffic import (control_bounds, timetable_state,
                                        truth_arrivals_departures, truth_step)
from metro_atc.core.bridge import timetable_for
from metro_atc.core.line.scenario import load_scenario
from metro_atc.core.service.circulation import Block, Trip, propagate_block
from metro_atc.core.service.planned import directed_line
from metro_atc.core.service.regulation import leg, turnback_experiment
from metro_atc.core.service.turnback import link, turnback_link


@pytest.mark.parametrize("delay, buffer, inherited", [
    (0.0, 210.0, 0.0), (104.0, 210.0, 0.0), (210.0, 210.0, 0.0), (180.0, 100.0, 80.0),
    (300.0, 210.0, 90.0), (-30.0, 50.0, 0.0), (50.0, 0.0, 50.0)])
def test_link_known_answers(delay: float, buffer: float, inherited: float) -> None:
    """delay <= buffer: nothing carried; delay > buffer: carried = delay - buffer."""
    lk = link("BL23", "down001", 1000.0, 1000.0 + 150.0 + buffer, 150.0, delay)
    assert lk.buffer_s == pytest.approx(buffer)
    assert lk.inherited_delay_s == pytest.approx(inherited)
    assert lk.earliest_dep_s == pytest.approx(1000.0 + delay + 150.0)
    assert lk.departure_s == pytest.approx(1000.0 + 150.0 + buffer + inherited)


def test_link_refuses_bad_input() -> None:
    """Non-finite values, a negative turnback, a layover below the minimum: one line."""
    for args in ((math.nan, 400.0, 150.0, 0.0), (0.0, 400.0, -1.0, 0.0),
                 (0.0, 100.0, 150.0, 0.0), (0.0, 400.0, 150.0, math.inf)):
        with pytest.raises(ValueError) as ei:
            link("BL23", "x", *args)
        assert "\n" not in str(ei.value) and "BL23" in str(ei.value)


def test_block_link_matches_propagate_block() -> None:
    """Along a block the links give propagate_block's delays; nothing past the pull-in."""
    trips = (Trip("u0", "A", "B", 0.0, 1000.0), Trip("d0", "B", "A", 1300.0, 2300.0),
             Trip("u1", "A", "B", 2500.0, 3500.0))
    blk = Block("train_01", trips)
    tb = {"A": 150.0, "B": 200.0}
    ref = propagate_block(blk, tb, 0, 250.0)
    d = 250.0
    got = []
    for k in range(2):
        lk = turnback_link(blk, k, d, tb)
        assert lk is not None
        got.append(lk.inherited_delay_s)
        d = lk.inherited_delay_s      # trips run to time
    assert got == pytest.approx(ref)
    assert got == pytest.approx([150.0, 100.0])
    assert turnback_link(blk, 2, 500.0, tb) is None
    with pytest.raises(ValueError):
        turnback_link(blk, 3, 0.0, tb)


def test_truth_step_is_the_departures_of_the_split() -> None:
    """truth_step returns exactly the departures of truth_arrivals_departures."""
    line = taipei_blue()
    rng = np.random.default_rng(1)
    t0 = timetable_state(line, 0) + rng.uniform(-20, 200, line.n_stations)
    u = rng.uniform(-30, 30, line.n_stations)
    rng2 = np.random.default_rng(7)
    w = rng2.exponential(1.0, 23)
    a, d = truth_arrivals_departures(line, t0, u, 5.0, w_dep=w)
    assert np.array_equal(d, truth_step(line, t0, u, 5.0, w_dep=w))
    assert a[0] >= 5.0 and np.all(a <= d)   # knock-on may delay the arrival at station 0


def test_simulate_arrivals_are_zero_on_time() -> None:
    """No delay, no disturbance: every arrival deviation is 0 (reference arrivals)."""
    line = small_line(5)
    tr = simulate(line, make_regulator("none", line), np.zeros(5), np.zeros((8, 5)), 8)
    assert np.allclose(tr["arr"][1:], 0.0, atol=1e-9) and np.all(np.isnan(tr["arr"][0]))
    assert np.allclose(tr["x"], 0.0, atol=1e-9)


class _Early(Regulator):
    """Commands the earliest departures the operating rules allow (lower control bound)."""

    def __init__(self, lo: np.ndarray) -> None:
        super().__init__(lo.size)
        self.lo = lo

    def decide(self, x_s: np.ndarray, step: int = 0) -> np.ndarray:
        return self.lo.copy()


def test_no_regulator_dispatches_before_the_turnback() -> None:
    """With the link a train never departs its first station before it can have turned back.

    Without the link (same regulator) it leaves earlier: the test can fail.
    """
    # no boarding: a dwell cut would otherwise be hidden by the passengers of the wait
    line = dataclasses.replace(small_line(4), boarding_pax_h=np.zeros(4))
    lo, _ = control_bounds(line)
    steps = 6
    ready = np.array([120.0, 0.0, 35.0, 0.0, 0.0, 0.0])
    for reg in (_Early(lo), make_regulator("none", line), make_regulator("lqr", line)):
        tr = simulate_linked(line, reg, np.zeros(4), np.zeros((steps, 4)), steps, ready)
        assert np.all(tr["x"][1:, 0] >= ready - 1e-9)
        assert tr["arr"][1, 0] == pytest.approx(120.0)
    free = simulate(line, _Early(lo), np.zeros(4), np.zeros((steps, 4)), steps)
    assert free["x"][1, 0] < 0.0   # the early regulator leaves before the timetable
    with pytest.raises(ValueError):
        simulate_linked(line, _Early(lo), np.zeros(4), np.zeros((steps, 4)), steps,
                        np.zeros(3))


def test_experiment_inherits_delay_minus_buffer() -> None:
    """Leg 1 terminal delay d; the next trip inherits max(0, d - buffer) and leaves no earlier."""
    line = small_line(5)
    down = directed_line(line, "down")
    regs = {"none": make_regulator("none", line), "lqr": make_regulator("lqr", line)}
    dregs = {"none": make_regulator("none", down), "lqr": None}
    res = turnback_experiment(regs, line, dregs, down, 150.0, (0.0, 1000.0), 400.0, seed=3)
    for name, row in res["methods"].items():
        d = row["terminal_arrival_delay_s"]
        assert d > 0.0
        for key, buf in (("210", 210.0), ("0", 0.0), ("1000", 1000.0)):
            tb = row["turnback"][key]
            assert tb["inherited_delay_s"] == pytest.approx(max(0.0, d - buf))
            assert tb["absorbed"] == (d <= buf)
    nxt = res["methods"]["none"]["next_trip"]
    assert nxt["first_departure_delay_s"] >= nxt["inherited_delay_s"] > 0.0
    assert res["methods"]["lqr"]["next_trip"] is None


def test_leg_tracks_the_delayed_train() -> None:
    """Leg 1 follows train -1 of the initial state: 180 s late at the first station."""
    line = taipei_blue()
    sc = incident_scenario(line, 180.0, 0, 30, disturbances=False)
    one = leg(line, make_regulator("none", line), sc["x0"], sc["w"], 30)
    assert one["first_departure_dev_s"] == 180.0
    assert one["terminal_arrival_dev_s"] >= 180.0   # no regulation: the delay grows


def test_dispatcher_first_departure_respects_the_link() -> None:
    """The station-0 command is max(timetable, earliest turnback departure)."""
    scn = load_scenario("mini")
    tt = timetable_for(scn)
    d = make_dispatcher(scn, "none", tt=tt)
    tid = tt.train_ids[1]
    sched = float(tt.departure_s[1, 0])
    assert d.first_departure(tid, sched - 50.0).departure_s == sched
    late = d.first_departure(tid, sched + 77.0)
    assert late.departure_s == sched + 77.0 and late.station == 0 and late.train == 1
    with pytest.raises(ValueError):
        d.first_departure(tid, math.nan)
    with pytest.raises(ValueError):
        d.first_departure("nobody", sched)
