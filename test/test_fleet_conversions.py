"""Fleet lockstep messages: the same values and rules as the per-train ones."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from metro_atc.core.line.scenario import load_scenario
from metro_atc.core.plant.line import LineSim
from metro_atc.core.plant.driver import simple_driver
from metro_atc.core.validate import Rejected, StepWindow, bounds_for
from metro_atc.nodes import conversions as conv
from metro_atc.nodes.wire import fleet_command, fleet_state


def _states_along_a_run(steps: int = 1200, every: int = 37) -> list[tuple[int, float, Any]]:
    """(step, t, states) of the mini line under the reference driver, every few steps."""
    sim = LineSim(load_scenario("mini"), seed=3)
    out = []
    for k in range(steps):
        if k % every == 0:
            out.append((k, float(sim.t), {a: np.array(b, copy=True)
                                          for a, b in sim.states().items()}))
        sim.step(simple_driver(sim))
    return out


def test_fleet_entries_validate_to_the_per_train_states() -> None:
    """Every entry of a FleetState, through state_from_msg, is the per-train TrainState's
    result bit for bit (so the ATO decides the same from either)."""
    scn = load_scenario("mini")
    b = bounds_for(scn)
    ids = list(scn.train_ids)
    n_checked = 0
    for k, t, st in _states_along_a_run():
        idx = np.flatnonzero(np.ones(len(ids), dtype=bool))
        echo = np.arange(idx.size) % 2 == 0
        fleet = fleet_state.to_msg(ids, idx, st, k, t, echo)
        per = dict(conv.state_msgs(ids, idx, st, k, t))
        entries = fleet_state.entries(fleet, "/line/fleet_state", {i: None for i in ids})
        assert [tid for tid, _ in entries] == [ids[i] for i in idx]
        for j, (tid, e) in enumerate(entries):
            i = ids.index(tid)
            try:
                a = conv.state_from_msg(per[i], "/x/state", tid, b, StepWindow())
            except Rejected:
                with pytest.raises(Rejected):
                    conv.state_from_msg(e, "/line/fleet_state", tid, b, StepWindow())
                continue
            f = conv.state_from_msg(e, "/line/fleet_state", tid, b, StepWindow())
            assert e.echo == bool(echo[j])
            assert a.keys() == f.keys()
            for key in a:
                x, y = a[key], f[key]
                assert type(x) is type(y) and (x == y or (math.isnan(x) and math.isnan(y))), \
                    (key, x, y)
            n_checked += 1
    assert n_checked > 20


def test_fleet_entries_of_other_trains_are_skipped() -> None:
    """A process answers only its own trains (the others are another process's)."""
    scn = load_scenario("mini")
    ids = list(scn.train_ids)
    _, t, st = _states_along_a_run(1, 1)[0]
    fleet = fleet_state.to_msg(ids, np.arange(len(ids)), st, 0, t)
    got = fleet_state.entries(fleet, "/line/fleet_state", {ids[-1]: None})
    assert [tid for tid, _ in got] == [ids[-1]]


def test_fleet_command_round_trip_and_rules() -> None:
    """FleetCommand entries pass traction_from_msg like /<train>/command messages."""
    index = {"train_01": 0, "train_02": 1}
    m = fleet_command.to_msg(12, 3.0, ["train_02", "train_01"], [0.25, -1.0], [2, 5])
    got = fleet_command.entries(m, "/line/fleet_command", index)
    assert [i for i, _ in got] == [1, 0]
    eff = [conv.traction_from_msg(e, "/line/fleet_command", e.train_id, 12, 3.0)
           for _, e in got]
    assert eff == [0.25, -1.0]
    # previous step: a stale duplicate (None); another step or stamp: rejected
    assert conv.traction_from_msg(got[0][1], "t", "train_02", 13, 3.25) is None
    with pytest.raises(Rejected):
        conv.traction_from_msg(got[0][1], "t", "train_02", 11, 2.75)
    # the per-train echo of a fleet-driven train may arrive steps late: dropped, not counted
    with pytest.raises(Rejected):
        conv.traction_from_msg(got[0][1], "t", "train_02", 14, 3.5)
    assert conv.traction_from_msg(got[0][1], "t", "train_02", 14, 3.5, late_echo=True) is None
    with pytest.raises(Rejected):  # a future step is never an echo
        conv.traction_from_msg(got[0][1], "t", "train_02", 10, 2.5, late_echo=True)
    with pytest.raises(Rejected):
        conv.traction_from_msg(got[0][1], "t", "train_02", 12, 3.5)


@pytest.mark.parametrize("bad", ["length", "duplicate", "unknown"])
def test_malformed_fleet_messages_are_rejected(bad: str) -> None:
    """Arrays of different lengths, a train twice, an unknown train: the message is rejected
    as a whole (kinds shape / train_id)."""
    scn = load_scenario("mini")
    ids = list(scn.train_ids)
    _, t, st = _states_along_a_run(1, 1)[0]
    fleet = fleet_state.to_msg(ids, np.arange(len(ids)), st, 0, t)
    cmd = fleet_command.to_msg(0, 0.0, ids, [0.0] * len(ids), [2] * len(ids))
    if bad == "length":
        fleet.speed_mps = list(fleet.speed_mps)[:-1]
        cmd.mode = [2] * (len(ids) + 1)
        kind = "shape"
    elif bad == "duplicate":
        fleet.train_id = [ids[0]] * len(ids)
        cmd.train_id = [ids[0]] * len(ids)
        kind = "train_id"
    else:
        fleet.train_id = ["train_99"] + ids[1:]
        cmd.train_id = ["train_99"] + ids[1:]
        kind = "train_id"
    index = {tid: i for i, tid in enumerate(ids)}
    with pytest.raises(Rejected) as e:
        fleet_command.entries(cmd, "/line/fleet_command", index)
    assert e.value.kind == kind
    if bad != "unknown":  # an unknown train in a fleet state is another process's
        with pytest.raises(Rejected) as e:
            fleet_state.entries(fleet, "/line/fleet_state", index)
        assert e.value.kind == kind


def _slow_fleet_command(msg: Any, index: dict[str, int], step: int, t: float
                        ) -> tuple[list[int], list[float | None], int]:
    """What the simulator took from a FleetCommand entry by entry: (trains, efforts or
    None, rejected entries)."""
    trains, efforts, rejected = [], [], 0
    for i, e in fleet_command.entries(msg, "/line/fleet_command", index):
        try:
            u = conv.traction_from_msg(e, "/line/fleet_command", e.train_id, step, t,
                                       late_echo=True)
        except Rejected:
            rejected += 1
            continue
        trains.append(i)
        efforts.append(u)
    return trains, efforts, rejected


def test_fleet_command_fast_path_equals_entry_by_entry() -> None:
    """fleet_command.efforts (the simulator's whole-message path) gives what the
    entry-by-entry rules give whenever it answers, and declines (None) exactly when some
    entry would be rejected: random valid and broken commands (efforts out of range or
    NaN, undefined modes, other steps, wrong stamps)."""
    rng = np.random.default_rng(7)
    ids = [f"train_{j:02d}" for j in range(1, 16)]
    index = {tid: i for i, tid in enumerate(ids)}
    seen = {"fast": 0, "stale": 0, "declined": 0}
    for trial in range(600):
        step = int(rng.integers(2, 5000))
        t = step * 0.25
        n = int(rng.integers(1, len(ids) + 1))
        chosen = list(rng.choice(ids, size=n, replace=False))
        eff = rng.uniform(-1.0, 1.0, size=n)
        modes = rng.integers(0, len(conv.MODES), size=n)
        kind = trial % 6
        if kind == 1:
            eff[rng.integers(n)] = rng.choice([np.nan, np.inf, 1.5, -1.2, 1.0 + 1e-10])
        elif kind == 2:
            modes[rng.integers(n)] = len(conv.MODES) + int(rng.integers(0, 5))
        msg_step, msg_t = step, t
        if kind == 3:
            msg_step = step - int(rng.integers(1, 4))  # an earlier step: stale
            msg_t = msg_step * 0.25
        elif kind == 4:
            msg_step = step + 1
            msg_t = msg_step * 0.25
        elif kind == 5:
            msg_t = t + 0.1  # the stamp is not the step's time
        m = fleet_command.to_msg(msg_step, msg_t, chosen, eff.tolist(), modes.tolist())
        trains, efforts, rejected = _slow_fleet_command(m, index, step, t)
        fast = fleet_command.efforts(m, "/line/fleet_command", index, step, t)
        if fast is None:
            seen["declined"] += 1
            assert rejected > 0
            continue
        assert rejected == 0
        ix, u = fast
        assert ix.tolist() == trains
        if u is None:
            seen["stale"] += 1
            assert efforts == [None] * len(trains)
        else:
            seen["fast"] += 1
            assert u.tolist() == efforts  # bit for bit
    assert min(seen.values()) > 50, seen


@pytest.mark.parametrize("bad", ["length", "duplicate", "unknown"])
def test_fleet_command_fast_path_rejects_malformed_messages(bad: str) -> None:
    """The whole-message path raises the same kinds as fleet_command_entries."""
    ids = ["train_01", "train_02", "train_03"]
    index = {tid: i for i, tid in enumerate(ids)}
    cmd = fleet_command.to_msg(4, 1.0, ids, [0.0] * 3, [2] * 3)
    if bad == "length":
        cmd.mode = [2] * 4
    elif bad == "duplicate":
        cmd.train_id = [ids[0]] * 3
    else:
        cmd.train_id = ["train_99"] + ids[1:]
    with pytest.raises(Rejected) as fast:
        fleet_command.efforts(cmd, "/line/fleet_command", index, 4, 1.0)
    with pytest.raises(Rejected) as slow:
        fleet_command.entries(cmd, "/line/fleet_command", index)
    assert fast.value.kind == slow.value.kind and str(fast.value) == str(slow.value)


def test_refilled_sensor_message_equals_a_fresh_one() -> None:
    """The simulator refills one BrakeSensorData per train: after any sequence of samples
    the message equals one built fresh from the last sample (NaN dropouts included)."""
    from types import SimpleNamespace

    rng = np.random.default_rng(11)
    out = conv.sensor_sample_msg("train_03", 0.0, [], [], math.nan, math.nan, math.nan)
    for _ in range(200):
        t = float(rng.uniform(0.0, 7200.0))
        w = rng.uniform(0.0, 120.0, size=4)
        c = rng.uniform(0.0, 3e4, size=4)
        if rng.random() < 0.3:
            w[rng.integers(4)] = np.nan
        acc, vref, mass = (float(x) for x in rng.uniform(-1.5, 30.0, size=3))
        got = conv.fill_sensor_msg(out, t, conv.doubles(w), c, acc, vref, mass)
        ref = conv.sensor_msg(SimpleNamespace(
            train_idx=2, t_s=t, wheel_omega_radps=w, clamp_force_n=c, accel_x_mps2=acc,
            ref_speed_mps=vref, car_mass_kg=mass), ["train_01", "train_02", "train_03"])
        assert got.header == ref.header and got.train_id == ref.train_id
        assert got.header.stamp == conv.to_time(t)
        np.testing.assert_array_equal(np.asarray(got.wheel_angular_speed_radps), w)
        np.testing.assert_array_equal(np.asarray(got.clamp_force_n), c)
        assert (got.longitudinal_acceleration_mps2, got.reference_speed_mps,
                got.car_mass_kg) == (acc, vref, mass)


def _per_entry(fleet: Any, hosted: dict[str, Any], b: Any) -> list[tuple[str, Any, bool]]:
    """The slow path: fleet_state_entries + state_from_msg per entry (``again`` dropped)."""
    out = []
    for tid, e in fleet_state.entries(fleet, "/line/fleet_state", hosted):
        s = conv.state_from_msg(e, "/line/fleet_state", tid, b, StepWindow())
        del s["again"]
        out.append((tid, s, e.echo))
    return out


def test_checked_fast_path_equals_the_per_entry_path() -> None:
    """fleet_states_checked gives the per-entry path's dicts (values, types, key order)."""
    scn = load_scenario("mini")
    b = bounds_for(scn)
    ids = list(scn.train_ids)
    n = 0
    for k, t, st in _states_along_a_run():
        for hosted in ({i: None for i in ids}, {ids[-1]: None}, {"train_99": None}):
            echo = np.arange(len(ids)) % 3 == 0
            fleet = fleet_state.to_msg(ids, np.arange(len(ids)), st, k, t, echo)
            try:
                slow = _per_entry(fleet, hosted, b)
            except Rejected:
                assert fleet_state.checked(fleet, "/line/fleet_state", hosted, b) is None
                continue
            fast = fleet_state.checked(fleet, "/line/fleet_state", hosted, b)
            assert fast is not None
            assert [(tid, list(s.items()), e) for tid, s, e in fast] == \
                [(tid, list(s.items()), e) for tid, s, e in slow]
            assert [type(v) for _, s, _ in fast for v in s.values()] == \
                [type(v) for _, s, _ in slow for v in s.values()]
            n += len(fast)
    assert n > 20


@pytest.mark.parametrize("field,value", [
    ("position_m", math.nan), ("position_m", -1e7), ("speed_mps", -0.1),
    ("speed_mps", math.inf), ("acceleration_mps2", 1e3), ("current_station", 99),
    ("next_station", -2), ("mode", 200), ("departure_time_s", -1.0),
    ("target_running_time_s", math.inf), ("supervision_speed_mps", math.nan),
    ("movement_authority_m", -math.inf), ("movement_authority_m", math.nan),
    ("stamp", 0.1), ("length", 0), ("duplicate", 0)])
def test_checked_fast_path_refuses_what_the_per_entry_path_rejects(field: str,
                                                                   value: float) -> None:
    """One bad value in one hosted entry: the fast path returns None (the caller then takes
    the per-entry path, which rejects that entry or the message)."""
    scn = load_scenario("mini")
    b = bounds_for(scn)
    ids = list(scn.train_ids)
    k, t, st = _states_along_a_run(40, 39)[-1]
    fleet = fleet_state.to_msg(ids, np.arange(len(ids)), st, k, t)
    hosted = {i: None for i in ids}
    assert fleet_state.checked(fleet, "/line/fleet_state", hosted, b) is not None
    if field == "stamp":
        fleet.header.stamp = conv.to_time(t + value)
    elif field == "length":
        fleet.echo = [False] * (len(ids) + 1)
    elif field == "duplicate":
        fleet.train_id = [ids[0]] * len(ids)
    else:
        vals = list(getattr(fleet, field))
        vals[-1] = value
        setattr(fleet, field, vals)
    with pytest.raises(Rejected):
        _per_entry(fleet, hosted, b)
    assert fleet_state.checked(fleet, "/line/fleet_state", hosted, b) is None
