"""The hand CDR codecs of :mod:`metro_atc.nodes.wire`: one per message, from its class.

Per message: the codec's layout is the generated class's field list (a field added to the
.msg changes the layout, and one without a conversion stops the codec from loading); a
round trip through encode and decode gives the values back; the bytes of random valid
messages are rclpy's own (``serialize_message``; padding and rclpy's trailing slack
aside); truncated, oversized and NaN input is refused with one reason and changes nothing.
"""

from __future__ import annotations

import importlib.util
import math
import random
import struct
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from metro_atc_msgs.msg import FleetBrakeSensorData, FleetCommand, FleetState, TractionCommand
from rclpy.serialization import deserialize_message, serialize_message

from metro_atc.core.validate import Rejected
from metro_atc.nodes import conversions as conv
from metro_atc.nodes.wire import cdr, fleet_command, fleet_sensors, fleet_state, traction_command

WIRE = Path(fleet_state.__file__).parent
CODECS = ((fleet_state, FleetState), (fleet_command, FleetCommand),
          (fleet_sensors, FleetBrakeSensorData), (traction_command, TractionCommand))


def _fields(cls: Any) -> list[tuple[str, str]]:
    """(name, rosidl type) of every field of a message class, in .msg order."""
    return list(cls.get_fields_and_field_types().items())


# ------------------------------------------------------------------ layouts
@pytest.mark.parametrize("module,cls", CODECS)
def test_layout_is_the_class_field_list(module: Any, cls: Any) -> None:
    """The codec's fields, head and body, are the class's, in order, with their types."""
    body = getattr(module, "ARRAYS", None) or getattr(module, "SCALARS")
    names = [n for n, _ in module.HEAD] + [f.name for f in body]
    assert names == [n for n, _ in _fields(cls)]
    # the slots of the generated class say the same (the C layout rclpy serializes)
    assert [s.lstrip("_") for s in cls.__slots__ if s != "_check_fields"] == names
    for f, (_, t) in zip(body, _fields(cls)[len(module.HEAD):]):
        base = t[len("sequence<"):-1] if t.startswith("sequence<") else t
        assert (f.dtype, f.code) == cdr.PRIMITIVES[base]
        assert np.dtype(f.dtype).itemsize == struct.calcsize("<" + f.code)
        assert f.boolean == (base == "boolean")


class _Grown:
    """A FleetState class whose .msg gained a float64[] field (as a regenerated class)."""

    @staticmethod
    def get_fields_and_field_types() -> dict[str, str]:
        """The field list with the new field at the end."""
        return {**FleetState.get_fields_and_field_types(), "brake_pressure_pa": "sequence<double>"}


def test_a_field_added_to_the_msg_changes_the_layout() -> None:
    """The layout follows the class: a new field is in it, and without a conversion the
    codec refuses it (:class:`cdr.LayoutError`) instead of writing a stale message."""
    grown = cdr.split_layout(_Grown, fleet_state.HEAD, "array")
    assert [f.name for f in grown] == list(fleet_state.NAMES) + ["brake_pressure_pa"]
    assert grown[-1].dtype == "<f8"
    with pytest.raises(cdr.LayoutError, match="brake_pressure_pa"):
        cdr.require_names(_Grown, grown, tuple(fleet_state.CORE_KEYS) + (fleet_state.ECHO,))


def _load_with(module: Any, cls_name: str, fields: dict[str, str]) -> Any:
    """Load ``module``'s source afresh with ``cls_name``'s field list replaced by ``fields``."""
    import metro_atc_msgs.msg as msgs

    cls = getattr(msgs, cls_name)
    saved = cls.get_fields_and_field_types
    cls.get_fields_and_field_types = classmethod(lambda c: dict(fields))
    try:
        spec = importlib.util.spec_from_file_location(f"_wire_probe_{cls_name}",
                                                      module.__file__)
        assert spec is not None and spec.loader is not None
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        return mod
    finally:
        cls.get_fields_and_field_types = saved


@pytest.mark.parametrize("module,cls", CODECS)
def test_a_codec_does_not_load_when_its_msg_gains_a_field(module: Any, cls: Any) -> None:
    """Each codec module, loaded against its class with one more field, fails to load."""
    fields = dict(_fields(cls))
    extra = "sequence<double>" if hasattr(module, "ARRAYS") else "double"
    with pytest.raises(cdr.LayoutError, match="extra_field"):
        _load_with(module, cls.__name__, {**fields, "extra_field": extra})
    # the same source with the real field list loads (the probe itself is sound)
    assert _load_with(module, cls.__name__, fields).HEAD == module.HEAD


def test_a_codec_does_not_load_when_its_msg_reorders_positional_fields() -> None:
    """FleetCommand's effort and mode are passed by position: swapped in the .msg, refused."""
    fields = dict(_fields(FleetCommand))
    swapped = {k: fields[k] for k in ("header", "step", "train_id", "mode", "effort")}
    with pytest.raises(cdr.LayoutError, match="order"):
        _load_with(fleet_command, "FleetCommand", swapped)


def test_an_unknown_field_type_has_no_layout() -> None:
    """A nested message other than Header / Time (or a fixed array) is refused, by name."""

    class Odd:
        @staticmethod
        def get_fields_and_field_types() -> dict[str, str]:
            return {"pose": "geometry_msgs/Pose", "v": "double[3]"}

    with pytest.raises(cdr.LayoutError, match="pose"):
        cdr.layout(Odd)


# ------------------------------------------------------------------ random valid messages
def _rand_f(rng: random.Random) -> float:
    special = (0.0, -0.0, math.inf, -math.inf, math.nan, 5e-324, 1.7976931348623157e308)
    return rng.choice(special) if rng.random() < 0.15 else rng.uniform(-1e6, 1e6)


def _rand_id(rng: random.Random) -> str:
    alphabet = "abcxyz_0123456789" + ("éü漢" if rng.random() < 0.2 else "")
    return "".join(rng.choice(alphabet) for _ in range(rng.randint(0, 12)))


def _stamp(rng: random.Random) -> tuple[int, int]:
    """A stamp :func:`cdr.stamp_parts` can give (its time rounds back to it)."""
    while True:
        sec, nsec = rng.randint(0, 2**31 - 1), rng.randint(0, 999_999_999)
        if cdr.stamp_parts(sec + 1e-9 * nsec) == (sec, nsec):
            return sec, nsec


def _values(rng: random.Random, f: cdr.Field, n: int) -> list[Any]:
    """``n`` random valid values of a primitive field."""
    if f.boolean:
        return [rng.random() < 0.5 for _ in range(n)]
    if f.code in "fd":
        return [_rand_f(rng) for _ in range(n)]
    bits = 8 * struct.calcsize(f.code)
    lo, hi = (0, 2**bits - 1) if f.code.isupper() else (-2**(bits - 1), 2**(bits - 1) - 1)
    return [rng.randint(lo, hi) for _ in range(n)]


def _random(cls: Any, rng: random.Random) -> Any:
    """A random valid message of a fleet class: every array as long as its train ids."""
    m = cls()
    m.header.stamp.sec, m.header.stamp.nanosec = _stamp(rng)
    m.header.frame_id = "line"
    n = rng.choice((0, 1, 2, 7, 30))
    m.train_id = [f"{_rand_id(rng)}_{i}" for i in range(n)]
    if hasattr(m, "step"):
        m.step = rng.randint(0, 2**64 - 1)
    for f in cdr.layout(cls):
        if f.kind == "array":
            setattr(m, f.name, _values(rng, f, n))
    return m


def _masked_equal(ours: bytes, theirs: bytes) -> bool:
    """Equal but for rclpy's padding bytes (uninitialised there, zero here) and its slack.

    rclpy's buffer is as long as rmw's size estimate (it counts the alignment of empty
    sequences too): the bytes past the message are left over; ours end with it.
    """
    if len(ours) > len(theirs) or len(theirs) - len(ours) > 8 * 16:
        return False
    return all(a == b or a == 0 for a, b in zip(ours, theirs))


def _bits(v: Any) -> Any:
    """Floats as their bits (NaN == NaN), sequences element-wise."""
    if isinstance(v, float):
        return struct.pack("<d", v)
    if isinstance(v, (bytes, bytearray)):
        return list(v)
    if isinstance(v, np.ndarray):
        return _bits(v.tolist())
    if isinstance(v, (list, tuple)) or type(v).__name__ == "array":
        return [_bits(x) for x in v]
    return v


def _encode_state(m: FleetState) -> bytes:
    t = m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec
    return fleet_state.encode(t, m.step, cdr.string_seq(list(m.train_id)),
                              [np.frombuffer(bytes(a), np.uint8) if isinstance(a, bytes)
                               else np.asarray(a) for a in
                               (getattr(m, n) for n in fleet_state.NAMES)])


def _encode_command(m: FleetCommand) -> bytes:
    return fleet_command.encode((m.header.stamp.sec, m.header.stamp.nanosec), "line", m.step,
                                list(m.train_id), list(m.effort), list(m.mode))


def _encode_sensors(m: FleetBrakeSensorData) -> bytes:
    t = m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec
    return fleet_sensors.encode(t, cdr.string_seq(list(m.train_id)),
                                [np.asarray(getattr(m, n)) for n in fleet_sensors.NAMES])


def test_fleet_state_round_trip_and_rclpys_bytes() -> None:
    """500 random valid FleetStates: our bytes are rclpy's and decode to the values."""
    rng = random.Random(101)
    for _ in range(500):
        m = _random(FleetState, rng)
        ours = _encode_state(m)
        assert _masked_equal(ours, serialize_message(m))
        n = len(m.train_id)
        builder = fleet_state.Builder(cdr.string_seq(list(m.train_id)), n)
        t = m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec
        assert builder.build(t, m.step, [np.frombuffer(bytes(a), np.uint8)
                                         if isinstance(a, bytes) else np.asarray(a)
                                         for a in (getattr(m, f) for f in
                                                   fleet_state.NAMES)]) == ours
        view = fleet_state.decode(ours)
        assert view is not None
        assert view.header == ((m.header.stamp.sec, m.header.stamp.nanosec), "line")
        assert view.step == m.step and view.train_id == list(m.train_id)
        for f in fleet_state.NAMES:
            assert _bits(list(getattr(view, f))) == _bits(list(getattr(m, f))), f


def test_fleet_command_round_trip_and_rclpys_bytes() -> None:
    """500 random valid FleetCommands: our bytes are rclpy's and decode to the values."""
    rng = random.Random(102)
    for _ in range(500):
        m = _random(FleetCommand, rng)
        ours = _encode_command(m)
        assert _masked_equal(ours, serialize_message(m))
        got = fleet_command.decode(ours)
        assert got is not None and (got.sec, got.nanosec, got.frame_id, got.step) == (
            m.header.stamp.sec, m.header.stamp.nanosec, "line", m.step)
        assert [cdr.text(b) for b in got.train_id_raw] == list(m.train_id)
        assert _bits(got.effort) == _bits(list(m.effort))
        assert _bits(got.mode) == _bits(m.mode)
        again = fleet_command.decode(ours)  # the remembered layout reads the same
        assert again is not None and _bits(again.effort) == _bits(got.effort)


def test_fleet_sensors_round_trip_and_rclpys_bytes() -> None:
    """500 random valid FleetBrakeSensorData: our bytes are rclpy's and decode to the values."""
    rng = random.Random(103)
    for _ in range(500):
        m = _random(FleetBrakeSensorData, rng)
        ours = _encode_sensors(m)
        assert _masked_equal(ours, serialize_message(m))
        got = fleet_sensors.decode(ours)
        assert got is not None and got.train_id == list(m.train_id)
        for f in fleet_sensors.NAMES:
            assert _bits(got.arrays[f]) == _bits(list(getattr(m, f))), f


def test_traction_command_round_trip_and_rclpys_bytes() -> None:
    """500 random valid TractionCommands: our bytes are rclpy's and read back."""
    rng = random.Random(104)
    for _ in range(500):
        m = TractionCommand()
        m.header.stamp.sec, m.header.stamp.nanosec = _stamp(rng)
        m.header.frame_id = "line"
        m.train_id = _rand_id(rng)
        m.step = rng.randint(0, 2**64 - 1)
        m.effort = _rand_f(rng)
        m.mode = rng.randint(0, 255)
        ours = traction_command.encode((m.header.stamp.sec, m.header.stamp.nanosec), "line",
                                       m.train_id, m.step, m.effort, m.mode)
        assert _masked_equal(ours, serialize_message(m))
        back = deserialize_message(ours, TractionCommand)
        assert (back.train_id, back.step, back.mode) == (m.train_id, m.step, m.mode)
        assert _bits(back.effort) == _bits(m.effort)


# ------------------------------------------------------------------ hostile input
def _state_of(n: int) -> bytes:
    """The bytes of a random valid FleetState of ``n`` trains."""
    rng = random.Random(n)
    m = _random(FleetState, rng)
    m.train_id = [f"train_{i:02d}" for i in range(n)]
    for f in cdr.layout(FleetState):
        if f.kind == "array":
            setattr(m, f.name, _values(rng, f, n))
    return _encode_state(m)


def test_truncated_input_is_refused_and_changes_nothing() -> None:
    """Every proper prefix of a message decodes to None, and no layout is remembered."""
    rng = random.Random(105)
    m = _random(FleetCommand, rng)
    while not m.train_id:
        m = _random(FleetCommand, rng)
    cmd = _encode_command(m)
    fleet_command._LAYOUTS.clear()
    for k in range(len(cmd)):
        assert fleet_command.decode(cmd[:k]) is None
    assert fleet_command._LAYOUTS == {}
    state = _state_of(7)
    sensors = _encode_sensors(_random(FleetBrakeSensorData, rng))
    for k in range(len(state)):
        assert fleet_state.decode(state[:k]) is None
    for k in range(len(sensors)):
        assert fleet_sensors.decode(sensors[:k]) is None


def test_oversized_counts_are_refused() -> None:
    """A count or string length beyond :data:`cdr.MAX_COUNT` (or the data) gives None."""
    state = bytearray(_state_of(3))
    # the train count follows the step (offset 4 + 24 + 8 for frame "line")
    at = 4 + fleet_state.STEP_AT + 8
    assert struct.unpack_from("<I", state, at)[0] == 3
    for count in (cdr.MAX_COUNT + 1, 2**32 - 1, 4):
        bad = bytearray(state)
        struct.pack_into("<I", bad, at, count)
        assert fleet_state.decode(bytes(bad)) is None
    frame_len = bytearray(state)
    struct.pack_into("<I", frame_len, 12, cdr.MAX_COUNT + 1)
    assert fleet_state.decode(bytes(frame_len)) is None
    cmd = bytearray(_encode_command(_random(FleetCommand, random.Random(7))))
    struct.pack_into("<I", cmd, 12, cdr.MAX_COUNT + 1)
    assert fleet_command.decode(bytes(cmd)) is None
    r = cdr.Reader(b"\x00\x01\x00\x00" + struct.pack("<I", cdr.MAX_COUNT + 1) + bytes(64))
    assert r.array("<f8").size == 0 and not r.finished()


def test_nan_effort_is_rejected_with_one_reason_and_changes_nothing() -> None:
    """A FleetCommand with a NaN effort: the fast paths decline it, the per-entry rules
    reject that entry with a one-line reason; the simulator's caches stay as they were."""
    ids = ["train_01", "train_02"]
    index = {t: i for i, t in enumerate(ids)}
    m = fleet_command.to_msg(4, 1.0, ids, [0.2, math.nan], [2, 2])
    raw = serialize_message(m)
    cache: dict[tuple[bytes, ...], np.ndarray] = {}
    raw_index = {t.encode(): i for t, i in index.items()}
    assert fleet_command.efforts_cdr(raw, "/line/fleet_command", raw_index, cache, 4, 1.0) \
        is fleet_command.FALLBACK
    assert fleet_command.efforts(m, "/line/fleet_command", index, 4, 1.0) is None
    reasons = []
    for i, e in fleet_command.entries(m, "/line/fleet_command", index):
        try:
            conv.traction_from_msg(e, "/line/fleet_command", ids[i], 4, 1.0)
        except Rejected as exc:
            reasons.append(str(exc))
    assert len(reasons) == 1 and "\n" not in reasons[0] and "effort" in reasons[0]


def test_nan_state_is_refused_by_the_fast_path_and_rejected_per_entry() -> None:
    """A FleetState entry with a NaN position: :func:`fleet_state.checked` declines the
    message (None) and the per-entry rule rejects that entry, with a one-line reason."""
    from metro_atc.core.line.scenario import load_scenario
    from metro_atc.core.plant.line import LineSim
    from metro_atc.core.validate import StepWindow, bounds_for

    scn = load_scenario("mini")
    sim = LineSim(scn, seed=1)
    b = bounds_for(scn)
    ids = list(sim.train_ids)
    st = {k: np.array(v, copy=True) for k, v in sim.states().items()}
    st["x_m"][0] = math.nan
    m = fleet_state.to_msg(ids, np.arange(len(ids)), st, 0, 0.0)
    hosted = {t: None for t in ids}
    assert fleet_state.checked(m, "/line/fleet_state", hosted, b) is None
    reasons = []
    for tid, e in fleet_state.entries(m, "/line/fleet_state", hosted):
        try:
            conv.state_from_msg(e, "/line/fleet_state", tid, b, StepWindow())
        except Rejected as exc:
            reasons.append(str(exc))
    assert len(reasons) == 1 and "\n" not in reasons[0] and "position_m" in reasons[0]
    # the decoder itself passes NaN through unchanged (the rules above judge it)
    view = fleet_state.decode(_encode_state(m))
    assert view is not None and math.isnan(view.position_m[0])


def test_oversized_sensor_batch_is_rejected_with_one_reason() -> None:
    """More samples than :data:`fleet_sensors.MAX_SAMPLES`: one rejection, kind ``length``."""
    from types import SimpleNamespace

    from metro_atc.core.line.scenario import load_scenario
    from metro_atc.core.validate import bounds_for

    n = fleet_sensors.MAX_SAMPLES + 1
    msg = SimpleNamespace(train_id=["train_01"], sample_train=np.zeros(n, np.uint32),
                          stamp_ns=np.zeros(n, np.int64), axle_count=np.full(n, 4, np.uint32),
                          wheel_angular_speed_radps=np.zeros(4 * n),
                          clamp_force_n=np.zeros(4 * n),
                          longitudinal_acceleration_mps2=np.zeros(n),
                          reference_speed_mps=np.zeros(n), car_mass_kg=np.zeros(n))
    with pytest.raises(Rejected) as exc:
        fleet_sensors.samples(msg, "/line/brake_sensors", {"train_01": 0}, 4,
                              bounds_for(load_scenario("mini")))
    assert exc.value.kind == "length" and "\n" not in str(exc.value)


def test_one_size_limit() -> None:
    """The codecs share :data:`cdr.MAX_COUNT`; no module keeps a limit of its own."""
    for path in WIRE.glob("*.py"):
        text = path.read_text()
        assert "1 << 16" not in text and "MAX_TRAINS" not in text, path.name
        if path.name != "cdr.py":
            assert "1 << 24" not in text, path.name
    # and it is above the largest sequence a valid sensor batch carries
    assert cdr.MAX_COUNT >= fleet_sensors.MAX_SAMPLES * fleet_sensors.MAX_AXLES
