"""The ROS-free fleet CDR codec against rclpy's own (de)serialisation.

:mod:`metro_atc.nodes.wire` (the ATO's end: ``fleet_state.decode``,
``fleet_command.encode``) must read every FleetState rclpy writes field for field (bit for
bit: NaN payloads, signed zeros, infinities), write FleetCommands rclpy reads back
identically (and byte for byte, but for padding, what rclpy writes), and give None --
never raise, never a wrong value -- on hostile bytes: truncated at every length, counts
that overrun, corrupted bytes, another encapsulation.
"""

from __future__ import annotations

import math
import random
import struct
from typing import Any

import numpy as np
import pytest
from metro_atc_msgs.msg import FleetCommand, FleetState
from rclpy.serialization import deserialize_message, serialize_message

from metro_atc.nodes.wire import cdr as codec
from metro_atc.nodes.wire import fleet_command, fleet_state, traction_command

F64 = ("position_m", "speed_mps", "acceleration_mps2", "departure_time_s",
       "target_running_time_s", "supervision_speed_mps", "movement_authority_m",
       "mass_kg")
SPECIAL = (0.0, -0.0, math.inf, -math.inf, math.nan, 5e-324, 1.7976931348623157e308,
           struct.unpack("<d", b"\x01\x00\x00\x00\x00\x00\xf8\x7f")[0])  # a NaN payload


def _bits(v: object) -> object:
    """Floats as their bits (NaN == NaN), sequences element-wise."""
    if isinstance(v, float):
        return struct.pack("<d", v)
    if isinstance(v, (list, tuple)) or type(v).__name__ == "array":
        return [_bits(x) for x in v]  # type: ignore[union-attr]
    if isinstance(v, dict):
        return {k: _bits(x) for k, x in v.items()}
    return v


def _rand_f(rng: random.Random) -> float:
    return rng.choice(SPECIAL) if rng.random() < 0.15 else rng.uniform(-1e6, 1e6)


def _rand_id(rng: random.Random) -> str:
    alphabet = "abcxyz_0123456789" + ("éü漢" if rng.random() < 0.2 else "")
    return "".join(rng.choice(alphabet) for _ in range(rng.randint(0, 12)))


def random_state(rng: random.Random) -> FleetState:
    """A FleetState with random (also ragged) arrays and special floats."""
    m = FleetState()
    m.header.stamp.sec = rng.randint(-2**31, 2**31 - 1)
    m.header.stamp.nanosec = rng.randint(0, 2**32 - 1)
    m.header.frame_id = _rand_id(rng)
    m.step = rng.choice((0, 1, rng.randint(0, 2**64 - 1)))
    n = rng.choice((0, 1, 2, 3, 15, 30))

    def k() -> int:  # ragged sometimes: the message allows it, the receiver rejects it
        return n if rng.random() < 0.9 else rng.randint(0, 5)

    m.train_id = [_rand_id(rng) for _ in range(k())]
    for f in F64:
        setattr(m, f, [_rand_f(rng) for _ in range(k())])
    m.current_station = [rng.randint(-2**31, 2**31 - 1) for _ in range(k())]
    m.next_station = [rng.randint(-5, 40) for _ in range(k())]
    m.mode = [rng.randint(0, 255) for _ in range(k())]
    m.echo = [rng.random() < 0.5 for _ in range(k())]
    return m


def random_command(rng: random.Random) -> FleetCommand:
    """A FleetCommand with random arrays."""
    m = FleetCommand()
    m.header.stamp.sec = rng.randint(0, 2**31 - 1)
    m.header.stamp.nanosec = rng.randint(0, 999_999_999)
    m.header.frame_id = rng.choice(("line", "", _rand_id(rng)))
    m.step = rng.randint(0, 2**64 - 1)
    n = rng.choice((0, 1, 2, 15))
    m.train_id = [_rand_id(rng) for _ in range(n)]
    m.effort = [_rand_f(rng) for _ in range(n if rng.random() < 0.9 else n + 1)]
    m.mode = [rng.randint(0, 255) for _ in range(n)]
    return m


def assert_state_equal(view: fleet_state.FleetStateView, m: FleetState) -> None:
    """Every field of the decoded view equals the message's, bit for bit."""
    assert view.header.stamp == (m.header.stamp.sec, m.header.stamp.nanosec)
    assert view.header.frame_id == m.header.frame_id
    assert view.step == m.step
    for f in ("train_id",) + F64 + ("current_station", "next_station", "mode", "echo"):
        assert _bits(list(getattr(view, f))) == _bits(list(getattr(m, f))), f
    for f in F64:
        assert all(type(x) is float for x in getattr(view, f))
    assert all(type(x) is bool for x in view.echo)


def test_decode_equals_rclpy_on_random_states() -> None:
    """2 000 random FleetStates: rclpy's bytes read back field for field (ragged ones refused)."""
    rng = random.Random(13)
    ragged = 0
    for _ in range(2000):
        m = random_state(rng)
        view = fleet_state.decode(serialize_message(m))
        lengths = {len(getattr(m, f)) for f in ("train_id",) + F64 + (
            "current_station", "next_station", "mode", "echo")}
        if len(lengths) > 1:  # ragged: refused, the node falls back to rclpy's reader
            assert view is None
            ragged += 1
            continue
        assert view is not None
        assert_state_equal(view, m)
    assert 0 < ragged < 2000  # both kinds were met (~70 % ragged)


def _masked_equal(ours: bytes, theirs: bytes) -> bool:
    """Equal but for rclpy's padding bytes (uninitialised there, zero here).

    rclpy's buffer is as long as rmw's size estimate (it counts the float64 alignment of
    empty sequences too): the bytes past the message are left over; ours end with it.
    """
    if len(ours) > len(theirs) or len(theirs) - len(ours) > 8 * 16:
        return False
    return all(a == b or a == 0 for a, b in zip(ours, theirs))


def test_encode_command_equals_rclpy() -> None:
    """2 000 random FleetCommands: our bytes are rclpy's (padding aside) and read back."""
    rng = random.Random(11)
    for _ in range(2000):
        m = random_command(rng)
        st = (m.header.stamp.sec, m.header.stamp.nanosec)
        if not len(m.effort) == len(m.mode) == len(m.train_id):
            with pytest.raises(ValueError):  # the node then publishes the message object
                fleet_command.encode(st, m.header.frame_id, m.step, m.train_id,
                                     m.effort, m.mode)
            continue
        ours = fleet_command.encode(st, m.header.frame_id, m.step, m.train_id, m.effort,
                                    m.mode)
        assert _masked_equal(ours, serialize_message(m))
        back = deserialize_message(ours, FleetCommand)
        assert (back.header.stamp.sec, back.header.stamp.nanosec) == st
        assert back.header.frame_id == m.header.frame_id and back.step == m.step
        assert back.train_id == m.train_id and list(back.mode) == list(m.mode)
        assert _bits(list(back.effort)) == _bits(list(m.effort))
        view = fleet_command.decode(ours)  # the simulator's reader
        assert view is not None and [codec.text(b) for b in view.train_id_raw] == m.train_id
        assert _bits(view.effort.tolist()) == _bits(list(m.effort))


def test_stamp_of_rounds_as_set_stamp() -> None:
    """The command's stamp is rounded as conversions.set_stamp rounds it."""
    from metro_atc.nodes.conversions import to_time
    rng = random.Random(3)
    for t in [0.0, -1.0, 0.25, 1e-10, 0.4999999999, 1799.75] + \
            [rng.uniform(0, 1e5) for _ in range(2000)]:
        want = to_time(t)
        assert codec.stamp_parts(t) == (want.sec, want.nanosec)


def _rclpy_reads(b: bytes) -> bool:
    try:
        deserialize_message(b, FleetState)
    except Exception:  # noqa: BLE001 - rclpy raises several kinds on bad bytes
        return False
    return True


def test_hostile_bytes_never_raise_and_never_misread() -> None:
    """Truncations, overrunning counts, corrupted bytes: None, or exactly rclpy's reading.

    Whatever the decoder accepts must be what rclpy reads from the same bytes (the same
    fields); what it refuses falls back to rclpy in the node.
    """
    rng = random.Random(5)
    cases: list[bytes] = [b"", b"\x00", b"\x00\x01\x00", b"\x00\x00\x00\x00" + b"\x00" * 64,
                          b"\x00\x01\x00\x00", b"\x00\x01\x00\x00" + b"\xff" * 64]
    for _ in range(150):
        good = serialize_message(random_state(rng))
        cases += [good[:k] for k in rng.sample(range(len(good)), min(len(good), 8))]
        for _ in range(6):
            bad = bytearray(good)
            for _ in range(rng.randint(1, 4)):
                bad[rng.randrange(len(bad))] = rng.randrange(256)
            cases.append(bytes(bad))
        # a count set huge, and one set just past the end
        bad = bytearray(good)
        off = rng.randrange(4, max(len(bad) - 4, 5))
        bad[off:off + 4] = struct.pack("<I", rng.choice((2**31, 2**32 - 1, 70000)))
        cases.append(bytes(bad))
    accepted = 0
    for b in cases:
        view = fleet_state.decode(b)  # must not raise
        if view is None:
            continue
        accepted += 1
        assert _rclpy_reads(b), "decoded bytes rclpy refuses"
        assert_state_equal(view, deserialize_message(b, FleetState))
    assert accepted > 50  # corrupted values inside arrays still decode (and equal rclpy)
    assert fleet_state.decode(bytearray(serialize_message(FleetState()))) is not None
    assert fleet_state.decode(None) is None
    assert fleet_command.decode(b"\x00\x01\x00\x00\x01") is None


def test_bad_command_values_raise_like_rclpy() -> None:
    """Values a FleetCommand cannot hold raise (as rclpy's setters do), never encode."""
    st = (0, 0)
    with pytest.raises((ValueError, struct.error)):
        fleet_command.encode(st, "line", 1, ["a"], [0.0], [256])
    with pytest.raises((ValueError, struct.error)):
        fleet_command.encode(st, "line", -1, ["a"], [0.0], [1])
    with pytest.raises(ValueError):
        fleet_command.encode(st, "li\x00ne", 1, ["a"], [0.0], [1])


def _states(d: dict[str, Any]) -> list[Any]:
    return [(tid, list(s.items()), e) for tid, s, e in d]  # type: ignore[attr-defined]


def test_validated_entries_of_a_decoded_view_equal_the_messages() -> None:
    """The ATO's validation (fast and per-entry paths) reads a decoded view as the message.

    Real fleet states of the mini line under the reference driver, good and with one bad
    value each: the dicts (values, types, key order), the rejections and their kinds.
    """
    from metro_atc.core.line.scenario import load_scenario
    from metro_atc.core.plant.driver import simple_driver
    from metro_atc.core.plant.line import LineSim
    from metro_atc.core.validate import Rejected, StepWindow, bounds_for
    from metro_atc.nodes import conversions as conv

    scn = load_scenario("mini")
    b = bounds_for(scn)
    ids = list(scn.train_ids)
    sim = LineSim(scn, seed=3)
    rng = random.Random(1)
    n = 0
    topic = "/line/fleet_state"
    for k in range(900):
        if k % 29 == 0:
            st = {a: np.array(v, copy=True) for a, v in sim.states().items()}
            m = fleet_state.to_msg(ids, np.arange(len(ids)), st, k, float(sim.t),
                                   np.arange(len(ids)) % 2 == 0)
            if k % 58 == 0:  # one bad value
                f = rng.choice(F64 + ("current_station", "mode"))
                vals = list(getattr(m, f))
                vals[rng.randrange(len(vals))] = rng.choice(
                    (-1e9, 300) if f in ("current_station", "mode")  # no NaN int32
                    else (math.nan, math.inf, -1e9)) if f != "mode" else 200
                setattr(m, f, [int(v) for v in vals] if f in ("current_station", "mode")
                        else vals)
            view = fleet_state.decode(serialize_message(m))
            assert view is not None
            for hosted in ({i: None for i in ids}, {ids[-1]: None}):
                a = fleet_state.checked(m, topic, hosted, b)
                c = fleet_state.checked(view, topic, hosted, b)  # type: ignore[arg-type]
                assert (a is None) == (c is None)
                if a is not None:
                    assert _bits(_states(c)) == _bits(_states(a))  # type: ignore[arg-type]
                    assert [type(v) for _, s, _ in c for v in s.values()] == \
                        [type(v) for _, s, _ in a for v in s.values()]  # type: ignore
                    n += len(a)
                ea = fleet_state.entries(m, topic, hosted)
                ec = fleet_state.entries(view, topic, hosted)  # type: ignore[arg-type]
                for (ta, xa), (tc, xc) in zip(ea, ec, strict=True):
                    assert ta == tc
                    try:
                        ra: Any = conv.state_from_msg(xa, topic, ta, b, StepWindow())
                    except Rejected as exc:
                        ra = exc.kind
                    try:
                        rc: Any = conv.state_from_msg(xc, topic, tc, b, StepWindow())
                    except Rejected as exc:
                        rc = exc.kind
                    assert _bits(list(ra.items()) if isinstance(ra, dict) else ra) == \
                        _bits(list(rc.items()) if isinstance(rc, dict) else rc)
        sim.step(simple_driver(sim))
    assert n > 20


def test_encode_traction_command_equals_rclpy() -> None:
    """20 000 random TractionCommands (the per-train echo): rclpy's bytes but for padding,
    read back field for field (effort bits: NaN, signed zeros, infinities)."""
    from metro_atc_msgs.msg import TractionCommand

    from metro_atc.nodes import conversions as conv

    rng = random.Random(13)
    for _ in range(20000):
        tid = rng.choice(["train_01", "t", "", "train_123456", "é_train", "ab", "abc", "abcd",
                          "abcde", "x" * rng.randint(0, 40)])
        frame = rng.choice(["line", "", "x", "frame_id_long", "abcdefg"])
        step = rng.choice([0, 1, (1 << 64) - 1, rng.getrandbits(64), rng.getrandbits(20)])
        t = rng.choice([0.0, 0.25, rng.uniform(0.0, 1e6), 1e-9 * rng.getrandbits(30)])
        u = rng.choice([rng.uniform(-1.0, 1.0), *SPECIAL])
        md = rng.randint(0, 255)
        m = conv.traction_msg(tid, step, t, u, md)
        m.header.frame_id = frame
        st = codec.stamp_parts(t)
        ours = traction_command.encode(st, frame, tid, step, u, md)
        assert _masked_equal(ours, serialize_message(m))
        back = deserialize_message(ours, TractionCommand)
        assert (back.header.stamp.sec, back.header.stamp.nanosec) == st \
            == (m.header.stamp.sec, m.header.stamp.nanosec)
        assert back.header.frame_id == frame and back.train_id == tid
        assert back.step == step and back.mode == md and _bits([back.effort]) == _bits([u])
    for bad in ((1, 0.0, 256), (-1, 0.0, 1), (1 << 64, 0.0, 1), (1, 1, 1), (1.0, 0.0, 1)):
        with pytest.raises((ValueError, struct.error)):
            traction_command.encode((0, 0), "line", "a", *bad)
    with pytest.raises(ValueError):
        traction_command.encode((0, 0), "line", "a\x00", 1, 0.0, 1)


def test_fleet_state_carries_the_load_weigh_mass_to_the_ato() -> None:
    """The plant's train masses reach the ATO's validated states through the wire (fast and
    per-entry paths); the per-train TrainState carries it too; a mass out of range is
    rejected, NaN (no signal) passes."""
    from metro_atc.core.line.scenario import load_scenario
    from metro_atc.core.plant.line import LineSim
    from metro_atc.core.validate import Rejected, StepWindow, bounds_for
    from metro_atc.nodes import conversions as conv

    scn = load_scenario("mini")
    b = bounds_for(scn)
    ids = list(scn.train_ids)
    sim = LineSim(scn, seed=3)
    sim.fleet.load[:] = np.linspace(0.0, sim.p.capacity_pax, sim.n)
    for i in range(sim.n):
        sim.fleet.set_mass_from_load(i)
    st = sim.states()
    topic = "/line/fleet_state"
    hosted = {i: None for i in ids}
    m = fleet_state.to_msg(ids, np.arange(len(ids)), st, 0, 0.0, np.zeros(len(ids), bool))
    view = fleet_state.decode(serialize_message(m))
    got = fleet_state.checked(view, topic, hosted, b)  # type: ignore[arg-type]
    assert got is not None
    assert [s["mass_kg"] for _, s, _ in got] == sim.fleet.mass.tolist()
    for j, (tid, e) in enumerate(fleet_state.entries(m, topic, hosted)):
        s = conv.state_from_msg(e, topic, tid, b, StepWindow())
        assert s["mass_kg"] == sim.fleet.mass[j]
    ts = conv.state_msgs(ids, [0], st, 0, 0.0)[0][1]
    assert ts.mass_kg == sim.fleet.mass[0]
    ts.mass_kg = math.nan
    assert math.isnan(conv.state_from_msg(ts, f"/{ids[0]}/state", ids[0], b,
                                          StepWindow())["mass_kg"])
    ts.mass_kg = -5.0
    with pytest.raises(Rejected):
        conv.state_from_msg(ts, f"/{ids[0]}/state", ids[0], b, StepWindow())
    m.mass_kg = [-5.0] * len(ids)
    assert fleet_state.checked(m, topic, hosted, b) is None
