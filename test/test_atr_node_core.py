"""AtsRegulatorCore: event validation, restart from history, departure commands."""

import math

import numpy as np
import pytest

from metro_atc.core.atr.blue_line import small_line, taipei_blue
from metro_atc.core.atr.cost import CostWeights
from metro_atc.core.atr.node_core import AtsRegulatorCore

IDS = [f"train_{i:02d}" for i in range(6)]


def _core(reg="none", line=None):
    return AtsRegulatorCore(line or small_line(4), reg, cost=CostWeights(), train_ids=IDS)


def test_rejects_bad_events_with_clear_messages():
    core = _core()
    core.on_event("train_00", 0, "arrival", 0.0)
    with pytest.raises(ValueError, match="unknown train id 'train_99'"):
        core.on_event("train_99", 0, "arrival", 1.0)
    with pytest.raises(ValueError, match="finite"):
        core.on_event("train_00", 0, "departure", math.nan)
    with pytest.raises(ValueError, match="finite"):
        core.on_event("train_00", 0, "departure", math.inf)
    with pytest.raises(ValueError, match="number"):
        core.on_event("train_00", 0, "departure", "soon")
    with pytest.raises(ValueError, match="kind"):
        core.on_event("train_00", 0, "passing", 10.0)
    with pytest.raises(ValueError, match="station index"):
        core.on_event("train_00", 7, "departure", 10.0)
    with pytest.raises(ValueError, match="station index"):
        core.on_event("train_00", 1.5, "departure", 10.0)
    core.on_event("train_00", 0, "departure", 26.0)
    with pytest.raises(ValueError, match="out-of-order"):
        core.on_event("train_00", 0, "departure", 27.0)     # duplicate
    with pytest.raises(ValueError, match="out-of-order"):
        core.on_event("train_00", 0, "arrival", 27.0)       # going back
    with pytest.raises(ValueError, match="before its previous event"):
        core.on_event("train_00", 1, "arrival", 20.0)       # time going back
    core.on_event("train_00", 2, "arrival", 200.0)          # a skipped event is accepted
    assert [e.kind for e in core.history] == ["arrival", "departure", "arrival"]
    with pytest.raises(ValueError, match="already"):
        core.departure_command("train_00", 1)
    with pytest.raises(ValueError, match="unknown train"):
        core.departure_command("ghost", 1)


def test_on_time_train_gets_the_timetable():
    core = _core("none")
    sched = core.scheduled(2, 0, "departure")
    core.on_event("train_02", 0, "departure", sched)
    cmd = core.departure_command("train_02", 1)
    assert cmd.target_running_time_s == pytest.approx(80.0)
    assert cmd.target_dwell_s == pytest.approx(20.0 + 0.05 * 120.0)
    assert cmd.departure_time_s == pytest.approx(core.scheduled(2, 1, "departure"))
    assert cmd.adjustment_s == 0.0


def test_delayed_train_is_regulated_within_limits():
    line = taipei_blue()
    ids = [f"t{i}" for i in range(30)]
    core = AtsRegulatorCore(line, "lqr", train_ids=ids)
    none = AtsRegulatorCore(line, "none", train_ids=ids)
    for c in (core, none):
        c.on_event("t10", 0, "departure", c.scheduled(10, 0, "departure") + 180.0)
    reg = core.departure_command("t10", 1)
    free = none.departure_command("t10", 1)
    assert reg.departure_time_s < free.departure_time_s        # LQR recovers time
    assert reg.target_running_time_s >= line.run_min_s[0] - 1e-9
    assert reg.target_dwell_s >= line.dwell_fixed_min_s[1] - 1e-9
    assert reg.adjustment_s < 0.0
    # knock-on: the follower may not arrive before the leader left + separation
    core.on_event("t10", 1, "departure", reg.departure_time_s)
    core.on_event("t11", 0, "departure", core.scheduled(11, 0, "departure"))
    fol = core.departure_command("t11", 1)
    arrival = fol.departure_time_s - fol.target_dwell_s
    assert arrival >= reg.departure_time_s + line.separation_min_s - 1e-9


def test_restart_rebuilds_identical_state():
    line = taipei_blue()
    ids = [f"t{i}" for i in range(12)]
    core = AtsRegulatorCore(line, "lqr", train_ids=ids)
    rng = np.random.default_rng(0)
    for m in range(8):
        t = core.scheduled(m, 0, "arrival") + rng.uniform(0, 40)
        for j in range(3):
            core.on_event(ids[m], j, "arrival", t)
            t += 30.0 + rng.uniform(0, 5)
            core.on_event(ids[m], j, "departure", t)
            t += 80.0
    again = AtsRegulatorCore.from_history(core.history, line, regulator_name="lqr",
                                          train_ids=ids)
    for m in range(9):
        assert again.departure_command(ids[m], 3) == core.departure_command(ids[m], 3)
    with pytest.raises(ValueError, match="out-of-order"):
        AtsRegulatorCore.from_history(core.history[::-1], line, regulator_name="lqr",
                                      train_ids=ids)


def test_constructor_validation():
    with pytest.raises(ValueError, match="unique"):
        AtsRegulatorCore(small_line(3), train_ids=["a", "a"])
    with pytest.raises(ValueError, match="departure table"):
        AtsRegulatorCore(small_line(3), train_ids=["a"], departure_table_s=np.zeros((2, 3)))
