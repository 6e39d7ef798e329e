"""Validation at the edge: the rules and the conversion layer.

Every case of the issue is here as a unit test of ``metro_atc.nodes.conversions`` (which
calls ``metro_atc.core.validate``), plus a property test: thousands of random messages of
every subscribed type, with the extremes of each field type, never raise anything but a
counted rejection.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from metro_atc_msgs.msg import (BrakeSensorData, DepartureCommand, TractionCommand, TrainEvent,
                                TrainState)

from metro_atc.core.line.scenario import load_scenario
from metro_atc.core.validate import Rejected, Rejections, StepWindow, bounds_for
from metro_atc.nodes import conversions as conv

SCN = load_scenario("mini")
B = bounds_for(SCN)
DT = float(SCN.sim.control_period_s)


def _cmd(step: int, t: float, effort: float = 0.5, train: str = "train_01",
         mode: int = 2) -> TractionCommand:
    return conv.traction_msg(train, step, t, effort, mode) if math.isfinite(effort) else \
        TractionCommand(train_id=train, step=step, effort=effort, mode=mode,
                        header=conv.traction_msg(train, step, t, 0.0, mode).header)


def _state(step: int, **kw: Any) -> TrainState:
    m = TrainState(train_id="train_01", step=step, position_m=100.0, speed_mps=10.0,
                   acceleration_mps2=0.1, current_station=0, next_station=1, mode=2,
                   departure_time_s=40.0, target_running_time_s=80.0,
                   supervision_speed_mps=22.0, movement_authority_m=2000.0, mass_kg=214000.0)
    m.header.stamp = conv.to_time(step * DT)
    for k, v in kw.items():
        setattr(m, k, v)
    return m


def _departure(station: int = 1, dep: float = 300.0, run: float = 80.0,
               dwell: float = math.nan, stamp: float | None = None) -> DepartureCommand:
    m = conv.departure_msg("train_01", station, dep, run, dwell, "none", 1,
                           dep if stamp is None else stamp)
    return m


# --------------------------------------------------------------------------- commands

def test_command_for_current_step_only() -> None:
    """Step k with the state's stamp is taken; k-1 ignored; 2**64-1 and others rejected."""
    k, t = 40, 40 * DT
    assert conv.traction_from_msg(_cmd(k, t), "c", "train_01", k, t) == 0.5
    assert conv.traction_from_msg(_cmd(k - 1, t - DT), "c", "train_01", k, t) is None
    for step in (k + 1, 0, 2 ** 64 - 1):
        with pytest.raises(Rejected) as ei:
            conv.traction_from_msg(_cmd(step, t), "c", "train_01", k, t)
        assert ei.value.kind == "step"
    with pytest.raises(Rejected) as ei:  # right step, stamp not the state's
        conv.traction_from_msg(_cmd(k, t + 1e-3), "c", "train_01", k, t)
    assert ei.value.kind == "stamp"


@pytest.mark.parametrize("kw,kind", [({"effort": math.nan}, "nan"),
                                     ({"effort": 1.5}, "effort"),
                                     ({"mode": 255}, "mode"),
                                     ({"train": "train_02"}, "train_id"),
                                     ({"train": ""}, "train_id")])
def test_command_content(kw: dict[str, Any], kind: str) -> None:
    """NaN or out-of-range effort, undefined mode, another train: rejected by kind."""
    with pytest.raises(Rejected) as ei:
        conv.traction_from_msg(_cmd(3, 3 * DT, **kw), "c", "train_01", 3, 3 * DT)
    assert ei.value.kind == kind


# --------------------------------------------------------------------------- departures

def test_departure_rules() -> None:
    """1e9 s departure, station beyond the line, stamp mismatch: rejected; NaN dwell fine."""
    assert conv.departure_from_msg(_departure(), "d", "train_01", B)[:3] == (1, 300.0, 80.0)
    cases = [(_departure(dep=1e9), "time"), (_departure(station=10), "station"),
             (_departure(station=3), "station"),  # the terminus: nothing to depart to
             (_departure(stamp=0.0), "stamp"), (_departure(dep=0.0), "time"),
             (_departure(run=math.inf), "time"), (_departure(dwell=-1.0), "time")]
    for msg, kind in cases:
        with pytest.raises(Rejected) as ei:
            conv.departure_from_msg(msg, "d", "train_01", B)
        assert ei.value.kind == kind, (msg, ei.value)


# --------------------------------------------------------------------------- states

@pytest.mark.parametrize("kw,kind", [
    ({"current_station": 10}, "station"), ({"next_station": -2}, "station"),
    ({"supervision_speed_mps": math.nan}, "nan"), ({"movement_authority_m": math.nan}, "nan"),
    ({"mode": 255}, "mode"), ({"position_m": 1e7}, "position"), ({"speed_mps": -1.0}, "speed"),
    ({"departure_time_s": 1e9}, "time"), ({"train_id": "train_02"}, "train_id"),
])
def test_state_fields(kw: dict[str, Any], kind: str) -> None:
    """Each implausible field of a state is rejected by its kind; the window is unchanged."""
    w = StepWindow()
    with pytest.raises(Rejected) as ei:
        conv.state_from_msg(_state(8, **kw), "s", "train_01", B, w)
    assert ei.value.kind == kind
    assert w.last is None


def test_state_step_and_stamp() -> None:
    """A state's stamp is step x dt; steps follow the window; 2**64-1 never passes."""
    w = StepWindow()
    assert not conv.state_from_msg(_state(8), "s", "train_01", B, w)["again"]
    assert conv.state_from_msg(_state(8), "s", "train_01", B, w)["again"]
    conv.state_from_msg(_state(9), "s", "train_01", B, w)
    bad = _state(9)
    bad.header.stamp = conv.to_time(9 * DT + 0.5)
    with pytest.raises(Rejected, match="stamp"):
        conv.state_from_msg(bad, "s", "train_01", B, w)
    huge = _state(2 ** 64 - 1)
    with pytest.raises(Rejected):
        conv.state_from_msg(huge, "s", "train_01", B, w)
    with pytest.raises(Rejected) as ei:
        conv.state_from_msg(_state(500), "s", "train_01", B, w)
    assert ei.value.kind == "step"
    # MA +inf (nothing ahead) is a valid state
    assert conv.state_from_msg(_state(10, movement_authority_m=math.inf), "s", "train_01",
                               B, w)["movement_authority_m"] == math.inf


def test_step_window_resync() -> None:
    """A consistent jump (restarted simulator) is followed after ``resync`` steps; random
    steps never are."""
    w = StepWindow(resync=4)
    for k in range(5):
        assert w.accept(k) == "next"
    rng = np.random.default_rng(0)
    for _ in range(200):
        s = int(rng.integers(10, 2 ** 62))
        with pytest.raises(Rejected):
            w.accept(s)
    assert w.last == 4
    for k in (100, 101, 102):
        with pytest.raises(Rejected):
            w.accept(k)
    assert w.accept(103) == "next" and w.last == 103
    assert w.accept(104) == "next"
    # a simulator restarted behind, re-sending the step it waits on, is followed too
    for _ in range(3):
        with pytest.raises(Rejected):
            w.accept(50)
    assert w.accept(50) == "next" and w.accept(51) == "next"


# --------------------------------------------------------------------------- events, sensors

def _event(seq: int, t: float = 50.0, station: int = 0) -> TrainEvent:
    m = TrainEvent(train_id="train_01", kind=TrainEvent.KIND_ARRIVAL, station_index=station,
                   actual_time_s=t, scheduled_time_s=t, sequence=seq)
    m.header.stamp = conv.to_time(t)
    return m


def test_event_rules() -> None:
    """Sequence 1, 2, ... per train; stamp equals the event time; station on the line."""
    idx = {"train_01": 0, "train_02": 1}
    assert conv.event_from_msg(_event(1), "e", idx, B, {})["sequence"] == 1
    for msg, last, kind in [(_event(3), {"train_01": 1}, "sequence"),
                            (_event(1), {"train_01": 1}, "sequence"),
                            (_event(1, station=7), {}, "station"),
                            (_event(1, t=1e9), {}, "time")]:
        with pytest.raises(Rejected) as ei:
            conv.event_from_msg(msg, "e", idx, B, last)
        assert ei.value.kind == kind
    m = _event(1)
    m.header.stamp = Time(sec=0, nanosec=0)
    with pytest.raises(Rejected, match="stamp"):
        conv.event_from_msg(m, "e", idx, B, {})


def _sample(t: float, **kw: Any) -> BrakeSensorData:
    m = BrakeSensorData(train_id="train_01", wheel_angular_speed_radps=[40.0] * 4,
                        clamp_force_n=[0.0] * 4, longitudinal_acceleration_mps2=-0.1,
                        reference_speed_mps=17.0, car_mass_kg=30_000.0)
    m.header.stamp = conv.to_time(t)
    for k, v in kw.items():
        setattr(m, k, v)
    return m


@pytest.mark.parametrize("kw,kind", [
    ({"wheel_angular_speed_radps": [1.0] * 3}, "axles"), ({"car_mass_kg": -5.0}, "range"),
    ({"clamp_force_n": [1e300] * 4}, "range"), ({"reference_speed_mps": math.inf}, "range"),
    ({"train_id": "train_02"}, "train_id"),
])
def test_sensor_rules(kw: dict[str, Any], kind: str) -> None:
    """Wrong axles, implausible channels, another train: rejected by kind; NaN is a dropout."""
    with pytest.raises(Rejected) as ei:
        conv.sensor_from_msg(_sample(10.0, **kw), "b", "train_01", 4, B)
    assert ei.value.kind == kind
    s = conv.sensor_from_msg(_sample(10.0, reference_speed_mps=math.nan), "b", "train_01", 4, B)
    assert math.isnan(s["ref_speed"])


def test_future_sample_does_not_poison_the_stream() -> None:
    """Samples stamped 1e6 s are rejected; a future one inside the horizon is outlived."""
    from metro_atc.nodes.brake_diagnostic import RESYNC_SAMPLES, TrainBrakeWatch, observer_setup

    with pytest.raises(Rejected) as ei:
        conv.sensor_from_msg(_sample(1e6), "b", "train_01", 4, B)
    assert ei.value.kind == "time"
    w = TrainBrakeWatch("train_01", observer_setup(load_scenario("mini_pad_fault")))
    w.feed(conv.sensor_from_msg(_sample(1000.0), "b", "train_01", 4, B))  # the outlier
    out = [w.feed(conv.sensor_from_msg(_sample(10.0 + 0.05 * i), "b", "train_01", 4, B))
           for i in range(3 * RESYNC_SAMPLES)]
    assert out[:RESYNC_SAMPLES - 1] == ["out_of_order"] * (RESYNC_SAMPLES - 1)
    assert "out_of_order" not in out[RESYNC_SAMPLES - 1:]
    # the observer itself follows the genuine stream again (its time base was reset)
    assert w.obs.t_last == pytest.approx(10.0 + 0.05 * (3 * RESYNC_SAMPLES - 1))
    assert w.result.measurement_used


# --------------------------------------------------------------------------- property

_U64 = 2 ** 64 - 1


def _pick(rng: Any, values: list[Any]) -> Any:
    """One of ``values`` as the Python object (rng.choice would make 2**64-1 a float)."""
    return values[int(rng.integers(0, len(values)))]


def _rand(rng: Any, kind: str) -> Any:
    if kind == "f":
        return float(rng.choice([math.nan, math.inf, -math.inf, 0.0, -0.0, 1.7e308, -1.7e308,
                                 5e-324, rng.normal(0, 1e3), rng.uniform(0, 3000)]))
    if kind == "u64":
        return int(_pick(rng, [0, 1, _U64, int(rng.integers(0, 3000)),
                               int(rng.integers(0, 2 ** 63))]))
    if kind == "i32":
        return int(_pick(rng, [-2 ** 31, 2 ** 31 - 1, -1, 0, 1, 2, int(rng.integers(-5, 9))]))
    if kind == "u32":
        return int(_pick(rng, [0, 2 ** 32 - 1, int(rng.integers(0, 2 ** 32))]))
    if kind == "u8":
        return int(rng.choice([0, 1, 2, 255, int(rng.integers(0, 256))]))
    if kind == "id":
        return str(rng.choice(["train_01", "", "train_99", "x" * 1000, "\u00e9\U0001f600"]))
    n = int(rng.choice([0, 3, 4, 4, 100]))
    return [_rand(rng, "f") for _ in range(n)]


FIELDS: dict[Any, dict[str, str]] = {
    TractionCommand: {"train_id": "id", "step": "u64", "effort": "f", "mode": "u8"},
    DepartureCommand: {"train_id": "id", "station_index": "i32", "departure_time_s": "f",
                       "target_running_time_s": "f", "dwell_limit_s": "f", "regulator": "u8",
                       "sequence": "u64"},
    TrainState: {"train_id": "id", "step": "u64", "position_m": "f", "speed_mps": "f",
                 "acceleration_mps2": "f", "current_station": "i32", "next_station": "i32",
                 "mode": "u8", "departure_time_s": "f", "target_running_time_s": "f",
                 "supervision_speed_mps": "f", "movement_authority_m": "f",
                 "atp_interventions": "u32"},
    TrainEvent: {"train_id": "id", "kind": "u8", "station_index": "i32", "actual_time_s": "f",
                 "scheduled_time_s": "f", "dwell_s": "f", "sequence": "u64"},
    BrakeSensorData: {"train_id": "id", "wheel_angular_speed_radps": "f[]",
                      "clamp_force_n": "f[]", "longitudinal_acceleration_mps2": "f",
                      "reference_speed_mps": "f", "car_mass_kg": "f"},
}


def test_random_messages_only_ever_rejected() -> None:
    """5 000 random messages of every subscribed type: each either passes every rule or is
    rejected with a kind; nothing else is raised; the counters add up."""
    rng = np.random.default_rng(15)
    rej = Rejections()
    passed = 0
    w = StepWindow()
    for i in range(5000):
        tp = list(FIELDS)[i % len(FIELDS)]
        m = tp()
        m.header.stamp = Time(sec=int(_pick(rng, [0, 1, 2 ** 31 - 1, -2 ** 31,
                                                  int(rng.integers(0, 3000))])),
                              nanosec=int(_pick(rng, [0, 2 ** 32 - 1,
                                                      int(rng.integers(0, 10 ** 9))])))
        for name, kind in FIELDS[tp].items():
            setattr(m, name, _rand(rng, kind))
        try:
            if tp is TractionCommand:
                conv.traction_from_msg(m, "c", "train_01", 40, 40 * DT)
            elif tp is DepartureCommand:
                conv.departure_from_msg(m, "d", "train_01", B)
            elif tp is TrainState:
                conv.state_from_msg(m, "s", "train_01", B, w)
            elif tp is TrainEvent:
                conv.event_from_msg(m, "e", {"train_01": 0}, B, {})
            else:
                conv.sensor_from_msg(m, "b", "train_01", 4, B)
            passed += 1
        except Rejected as exc:
            assert exc.kind and "\n" not in str(exc) and len(str(exc)) < 300
            rej.add(exc.kind)
    assert rej.total + passed == 5000
    assert rej.total > 4900, (passed, rej.summary())
    assert {"nan", "train_id", "step", "stamp", "station", "axles"} <= set(rej.counts)


def test_guarded_turns_errors_into_rejections() -> None:
    """The last line of defence: any exception of a core call becomes a counted rejection."""
    def boom(x: int) -> int:
        raise IndexError("list index out of range")
    with pytest.raises(Rejected) as ei:
        conv.guarded("topic", boom, 1)
    assert ei.value.kind == "error" and "IndexError" in str(ei.value)
    assert conv.guarded("topic", lambda x: x + 1, 1) == 2
