"""The numpy CDR codec of the fleet messages against rclpy's own serialization.

Every encoder's bytes, read back by ``rclpy.serialization.deserialize_message``, give the
message's values (the bytes match rclpy's except the padding, which rclpy leaves
uninitialised); every decoder, fed rclpy's bytes of random messages (NaN, infinities,
extreme integers, empty and odd train ids, empty arrays, arrays of unequal lengths), gives
the values rclpy put in; truncated or corrupted bytes give None (bytes after the message
are ignored, as rclpy ignores them), never a raise.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from rclpy.serialization import deserialize_message, serialize_message

from metro_atc_msgs.msg import FleetBrakeSensorData, FleetCommand, FleetState
from rosgraph_msgs.msg import Clock

from metro_atc.nodes.wire import cdr, fleet_command, fleet_sensors, fleet_state

STATE_ARRAYS = [(f.name, f.dtype) for f in fleet_state.ARRAYS]
SENSOR_ARRAYS = [(f.name, f.dtype) for f in fleet_sensors.ARRAYS]

RNG_SEED = 20261124
N_RANDOM = 300


def _floats(rng: np.random.Generator, n: int) -> np.ndarray:
    """Random float64 values with NaN, infinities, extremes and signed zeros mixed in."""
    x = rng.normal(0.0, 10.0 ** rng.integers(-3, 6), n)
    special = np.array([math.nan, math.inf, -math.inf, 1.7e308, -1.7e308, 0.0, -0.0, 5e-324])
    pick = rng.random(n) < 0.2
    x[pick] = special[rng.integers(0, special.size, int(pick.sum()))]
    return x


def _ids(rng: np.random.Generator, n: int) -> list[str]:
    """Train ids of random lengths (empty, 1 to 40 characters, a non-ASCII one now and then)."""
    out = []
    for _ in range(n):
        k = int(rng.integers(0, 41))
        s = "".join(chr(int(c)) for c in rng.integers(97, 123, k))
        if rng.random() < 0.1:
            s += "é"
        out.append(s)
    return out


def _lengths(rng: np.random.Generator, n: int, k: int) -> list[int]:
    """``k`` array lengths: mostly ``n``, sometimes another (hostile messages)."""
    return [n if rng.random() < 0.8 else int(rng.integers(0, 2 * n + 2)) for _ in range(k)]


def _stamp(rng: np.random.Generator) -> tuple[int, int]:
    return (int(rng.integers(-2**31, 2**31)) if rng.random() < 0.2
            else int(rng.integers(0, 100_000)), int(rng.integers(0, 2**32)))


def _same(a: Any, b: Any) -> bool:
    """Equal arrays/lists/values, NaN equal to NaN, -0.0 distinct from 0.0 (bit equality)."""
    x, y = np.asarray(a), np.asarray(b)
    if x.dtype.kind == "f" or y.dtype.kind == "f":
        return x.shape == y.shape and np.array_equal(x.astype(np.float64).view(np.int64),
                                                     y.astype(np.float64).view(np.int64))
    return x.shape == y.shape and np.array_equal(x, y)


def _msg_same(a: Any, b: Any, arrays: Any) -> bool:
    """Two messages equal in header, step, train ids and arrays (NaN equal to NaN)."""
    if (a.header != b.header or getattr(a, "step", 0) != getattr(b, "step", 0)
            or list(a.train_id) != list(b.train_id)):
        return False
    for name, _ in arrays:
        x, y = getattr(a, name), getattr(b, name)
        x = np.frombuffer(x, np.uint8) if isinstance(x, bytes) else x
        y = np.frombuffer(y, np.uint8) if isinstance(y, bytes) else y
        if not _same(x, y):
            return False
    return True


def _random_fleet_state(rng: np.random.Generator) -> FleetState:
    n = int(rng.integers(0, 35))
    m = FleetState()
    m.header.stamp.sec, m.header.stamp.nanosec = _stamp(rng)
    m.header.frame_id = "line" if rng.random() < 0.7 else _ids(rng, 1)[0]
    m.step = int(rng.integers(0, 2**64, dtype=np.uint64))
    m.train_id = _ids(rng, n)
    lens = _lengths(rng, n, len(STATE_ARRAYS))
    for (name, dt), k in zip(STATE_ARRAYS, lens):
        if dt == "<f8":
            setattr(m, name, _floats(rng, k).tolist())
        elif dt == "<i4":
            setattr(m, name, rng.integers(-2**31, 2**31, k).tolist())
        elif name == "mode":
            setattr(m, name, bytes(rng.integers(0, 256, k).astype(np.uint8)))
        else:
            setattr(m, name, [bool(x) for x in rng.random(k) < 0.5])
    return m


def _random_fleet_command(rng: np.random.Generator) -> FleetCommand:
    n = int(rng.integers(0, 35))
    m = FleetCommand()
    m.header.stamp.sec, m.header.stamp.nanosec = _stamp(rng)
    m.header.frame_id = "line"
    m.step = int(rng.integers(0, 2**63))
    m.train_id = _ids(rng, n)
    ke, km = _lengths(rng, n, 2)
    m.effort = _floats(rng, ke).tolist()
    m.mode = bytes(rng.integers(0, 256, km).astype(np.uint8))
    return m


def _random_fleet_sensors(rng: np.random.Generator) -> FleetBrakeSensorData:
    n = int(rng.integers(0, 12))
    s = int(rng.integers(0, 60))
    m = FleetBrakeSensorData()
    m.header.stamp.sec, m.header.stamp.nanosec = _stamp(rng)
    m.header.frame_id = "line"
    m.train_id = _ids(rng, n)
    lens = _lengths(rng, s, len(SENSOR_ARRAYS))
    for (name, dt), k in zip(SENSOR_ARRAYS, lens):
        if dt == "<f8":
            setattr(m, name, _floats(rng, 4 * k if "radps" in name or "clamp" in name
                                     else k).tolist())
        elif dt == "<i8":
            setattr(m, name, rng.integers(-2**63, 2**63 - 1, k).tolist())
        else:
            setattr(m, name, rng.integers(0, 2**32, k).tolist())
    return m


def test_clock_bytes_are_rclpys() -> None:
    """/clock: the same bytes as rclpy for times across the range (rounded to the ns)."""
    from metro_atc.nodes.conversions import clock_msg

    for t in (0.0, 0.25, 1799.75, 12345.678912345, -3.0, 1e6 + 1e-9):
        assert cdr.clock(t) == serialize_message(clock_msg(t)), t
        back = deserialize_message(cdr.clock(t), Clock)
        assert (back.clock.sec, back.clock.nanosec) == cdr.stamp_parts(t)


def test_fleet_state_both_ways() -> None:
    """FleetState: rclpy reads our bytes as the message; the ATO's decoder
    (:func:`fleet_state.decode`) reads rclpy's bytes as it, or refuses arrays of
    unequal lengths (then rclpy's reader is used)."""
    rng = np.random.default_rng(RNG_SEED)
    decoded = 0
    for _ in range(N_RANDOM):
        m = _random_fleet_state(rng)
        ref = serialize_message(m)
        arrays = [np.frombuffer(a, np.uint8) if isinstance(a, bytes) else np.asarray(a)
                  for a in (getattr(m, n) for n, _ in STATE_ARRAYS)]
        view = fleet_state.decode(ref)
        if len({len(a) for a in arrays} | {len(m.train_id)}) == 1:
            assert view is not None
            decoded += 1
            assert (view.header.stamp.sec, view.header.stamp.nanosec, view.header.frame_id,
                    view.step, view.train_id) == (m.header.stamp.sec, m.header.stamp.nanosec,
                                                  m.header.frame_id, m.step, list(m.train_id))
            for name, a in zip((n for n, _ in STATE_ARRAYS), arrays):
                assert _same(np.asarray(getattr(view, name)).astype(a.dtype), a), name
        else:
            assert view is None
        if m.header.frame_id == "line" and m.header.stamp.sec >= 0:
            t = m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec
            if cdr.stamp_parts(t) != (m.header.stamp.sec, m.header.stamp.nanosec):
                continue  # a stamp no float time rounds to
            ours = fleet_state.encode(t, m.step, cdr.string_seq(list(m.train_id)), arrays)
            assert len(ours) <= len(ref)  # rclpy's buffer can have bytes after the message
            assert _msg_same(deserialize_message(ours, FleetState), m, STATE_ARRAYS)
    assert decoded > 0  # ~13 % of the random states have equal lengths; test_cdr_fleet has more


def test_fleet_command_both_ways() -> None:
    """FleetCommand: both directions on random (and ill-shaped) messages."""
    rng = np.random.default_rng(RNG_SEED + 1)
    for _ in range(N_RANDOM):
        m = _random_fleet_command(rng)
        ref = serialize_message(m)
        got = fleet_command.decode(ref)
        assert got is not None
        assert [cdr.text(b) for b in got.train_id_raw] == list(m.train_id)
        assert got.step == m.step and (got.sec, got.nanosec) == (m.header.stamp.sec,
                                                                 m.header.stamp.nanosec)
        assert _same(got.effort, m.effort)
        assert _same(got.mode, np.frombuffer(m.mode, np.uint8))
        if m.header.stamp.sec >= 0 and len(m.effort) == len(m.mode):
            t = m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec
            if cdr.stamp_parts(t) != (m.header.stamp.sec, m.header.stamp.nanosec):
                continue
            ours = fleet_command.encode(
                (m.header.stamp.sec, m.header.stamp.nanosec), m.header.frame_id, m.step,
                m.train_id, m.effort, np.frombuffer(m.mode, np.uint8).tolist())
            assert len(ours) <= len(ref)
            assert _msg_same(deserialize_message(ours, FleetCommand), m,
                             (("effort", ""), ("mode", "")))


def test_fleet_sensors_both_ways() -> None:
    """FleetBrakeSensorData: both directions on random (and ill-shaped) messages."""
    rng = np.random.default_rng(RNG_SEED + 2)
    for _ in range(N_RANDOM):
        m = _random_fleet_sensors(rng)
        ref = serialize_message(m)
        got = fleet_sensors.decode(ref)
        assert got is not None
        assert got.train_id == list(m.train_id)
        for name, _ in SENSOR_ARRAYS:
            assert _same(got.arrays[name], np.asarray(getattr(m, name)).astype(
                got.arrays[name].dtype)), name
        if m.header.stamp.sec >= 0:
            t = m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec
            if cdr.stamp_parts(t) != (m.header.stamp.sec, m.header.stamp.nanosec):
                continue
            ours = fleet_sensors.encode(t, cdr.string_seq(list(m.train_id)),
                                        [got.arrays[n] for n, _ in SENSOR_ARRAYS])
            assert len(ours) <= len(ref)
            assert _msg_same(deserialize_message(ours, FleetBrakeSensorData), m,
                             SENSOR_ARRAYS)


def test_damaged_bytes_give_none_never_raise() -> None:
    """Truncated, corrupted and foreign bytes: None (or, for a corruption that still
    parses, a message rclpy reads too), never an exception."""
    rng = np.random.default_rng(RNG_SEED + 3)
    makers = ((_random_fleet_command, fleet_command.decode, FleetCommand),
              (_random_fleet_sensors, fleet_sensors.decode, FleetBrakeSensorData))
    nones = 0
    for k in range(2 * N_RANDOM):
        make, read, typ = makers[k % 2]
        ref = serialize_message(make(rng))
        # rclpy's buffer can have bytes after the message: find where the message ends
        end = len(ref)
        while read(ref[:end - 1]) is not None:
            end -= 1
        assert len(ref) - end < 64
        cut = int(rng.integers(0, end))
        assert read(ref[:cut]) is None  # every truncation of the message is seen
        longer = read(ref + bytes(rng.integers(0, 256, 8).astype(np.uint8)))
        assert longer is not None and longer[:3] == read(ref)[:3]  # trailing bytes ignored
        assert read(b"\x00\x00\x00\x00" + ref[4:]) is None  # big endian: not ours
        bad = bytearray(ref)
        for _ in range(int(rng.integers(1, 4))):
            bad[int(rng.integers(4, len(bad)))] = int(rng.integers(0, 256))
        got = read(bytes(bad))
        if got is None:
            nones += 1
            continue
        # what still parses is what rclpy reads too (same lengths and values)
        again = deserialize_message(bytes(bad), typ)
        assert again is not None
    assert nones > 0
    for junk in (b"", b"\x00", b"\x00\x01\x00\x00", b"\x00\x01\x00\x00" + b"\xff" * 64):
        for _, read, _ in makers:
            assert read(junk) is None


def test_fleet_state_cdr_is_fleet_state_msg() -> None:
    """The simulator's serialized FleetState is its FleetState message, value for value,
    along a run of the mini line (every train set, echo flags, the key without a value)."""
    from metro_atc.core.line.scenario import load_scenario
    from metro_atc.core.plant.driver import simple_driver
    from metro_atc.core.plant.line import LineSim

    sim = LineSim(load_scenario("mini"), seed=3)
    ids = list(sim.train_ids)
    rng = np.random.default_rng(RNG_SEED + 4)
    checked = 0
    for k in range(900):
        if k % 7 == 0:
            st = sim.states()
            idx = np.flatnonzero(rng.random(len(ids)) < 0.7)
            echo = rng.random(idx.size) < 0.5
            t = float(sim.t)
            want = fleet_state.to_msg(ids, idx, st, k, t, echo)
            block = cdr.string_seq([ids[i] for i in idx])
            ours = fleet_state.from_core(fleet_state.Builder(block, idx.size), idx, st, k, t,
                                         echo)
            got = deserialize_message(ours, FleetState)
            assert _msg_same(got, want, STATE_ARRAYS)
            # the template's bytes are those of the plain encoder
            assert ours == fleet_state.encode(t, k, block, [
                getattr(got, f) if not isinstance(getattr(got, f), bytes)
                else np.frombuffer(getattr(got, f), np.uint8)
                for f, _ in STATE_ARRAYS])
            checked += 1
        sim.step(simple_driver(sim))
    assert checked > 100


def test_fleet_command_cdr_takes_what_the_object_path_takes() -> None:
    """fleet_command.efforts_cdr on random (partly hostile) FleetCommands: where it
    answers, the answer is fleet_command.efforts's on the message; where it declines
    (FALLBACK), the object path would not take the message whole (it rejects it, or goes
    entry by entry)."""
    from metro_atc.core.validate import Rejected

    ids = [f"train_{i:02d}" for i in range(1, 31)]
    index = {t: i for i, t in enumerate(ids)}
    raw_index = {t.encode(): i for t, i in index.items()}
    cache: dict[tuple[bytes, ...], np.ndarray] = {}
    rng = np.random.default_rng(RNG_SEED + 5)
    topic = "/line/fleet_command"
    answered = declined = 0
    for _ in range(2000):
        step = int(rng.integers(0, 10_000))
        t = 0.25 * step
        n = int(rng.integers(0, 16))
        pick = list(rng.choice(len(ids), size=n, replace=False))
        tids = [ids[i] for i in pick]
        if rng.random() < 0.05 and tids:
            tids[0] = "train_99"  # unknown
        if rng.random() < 0.05 and len(tids) > 1:
            tids[1] = tids[0]  # twice
        eff = rng.uniform(-1.0, 1.0, n)
        if rng.random() < 0.1 and n:
            eff[int(rng.integers(0, n))] = [math.nan, 1.5, -math.inf][int(rng.integers(0, 3))]
        mode = rng.integers(0, 7, n)
        if rng.random() < 0.05 and n:
            mode[0] = 200
        k = step + int(rng.choice([0, 0, 0, -1, -5, 1]))
        ts = t + (0.0 if rng.random() < 0.9 else 0.125)
        m = fleet_command.to_msg(k, ts, tids, eff, mode)
        if rng.random() < 0.05 and n:
            m.effort = list(m.effort)[:-1]  # wrong length
        got = fleet_command.efforts_cdr(serialize_message(m), topic, raw_index, cache,
                                        step, t)
        try:
            want = fleet_command.efforts(m, topic, index, step, t)
        except Rejected:
            want = None
        if got is fleet_command.FALLBACK:
            declined += 1
            assert want is None  # whole-message rejection or the entry-by-entry path
            continue
        answered += 1
        assert want is not None
        assert np.array_equal(got[0], want[0])
        assert (got[1] is None) == (want[1] is None)
        if got[1] is not None:
            assert np.array_equal(got[1], want[1])
    assert answered > 1000 and declined > 100
    for junk in (b"", b"\x00\x01\x00\x00", b"\x00\x01\x00\x00" + b"\x07" * 40):
        assert fleet_command.efforts_cdr(junk, topic, raw_index, cache, 0, 0.0) is None


def test_fleet_command_layouts_read_as_the_reader_does() -> None:
    """A FleetCommand laid out as one read before is read at the remembered offsets: equal
    to rclpy's reading for new stamps, steps, efforts and modes; a message of the same size
    with other ids, frame or counts is not read at that layout."""
    rng = np.random.default_rng(RNG_SEED + 7)
    fleet_command._LAYOUTS.clear()
    for _ in range(200):
        n = int(rng.integers(1, 16))
        ids = [f"train_{int(x):02d}" for x in rng.choice(99, n, replace=False)]
        base = FleetCommand(train_id=ids, effort=_floats(rng, n).tolist(),
                            mode=[int(x) for x in rng.integers(0, 256, n)])
        base.header.frame_id = "line" if rng.random() < 0.8 else _ids(rng, 1)[0]
        fleet_command.decode(serialize_message(base))  # remembered
        for _ in range(3):
            m = FleetCommand(header=base.header, train_id=ids,
                             effort=_floats(rng, n).tolist(),
                             mode=[int(x) for x in rng.integers(0, 256, n)])
            m.header.stamp.sec, m.header.stamp.nanosec = _stamp(rng)
            m.step = int(rng.integers(0, 2**63))
            data = serialize_message(m)
            assert fleet_command._LAYOUTS.get(len(data))
            got = fleet_command.decode(data)
            assert got is not None and got.frame_id == m.header.frame_id
            assert [cdr.text(b) for b in got.train_id_raw] == ids
            assert (got.sec, got.nanosec, got.step) == (m.header.stamp.sec,
                                                        m.header.stamp.nanosec, m.step)
            assert _same(got.effort, m.effort)
            assert _same(got.mode, np.frombuffer(m.mode, np.uint8))
        # same size, another train (same id length): its own ids, not the layout's
        other = list(ids)
        other[-1] = "train_99" if ids[-1] != "train_99" else "train_98"
        m = FleetCommand(header=base.header, train_id=other, effort=base.effort,
                         mode=base.mode)
        got = fleet_command.decode(serialize_message(m))
        assert got is not None and [cdr.text(b) for b in got.train_id_raw] == other
        # fewer modes than efforts (same size as a full one with one more id byte): the
        # reader's result, never the layout's
        m = FleetCommand(header=base.header, train_id=ids, effort=base.effort,
                         mode=base.mode[:-1])
        got = fleet_command.decode(serialize_message(m))
        assert got is not None and got.mode.size == n - 1
    assert sum(len(v) for v in fleet_command._LAYOUTS.values()) <= fleet_command._LAYOUTS_MAX
