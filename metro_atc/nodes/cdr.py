"""CDR (XCDR1, little endian) of the fleet lockstep messages, with numpy, without ROS.

rclpy's ``Publisher.publish`` takes serialized ``bytes``, and a subscription made with
``raw=True`` hands over the CDR bytes of each message.  Building a FleetState object (a
Header, a Time, per-array conversions) and taking a FleetCommand as an object cost more
than the DDS write or take itself (issue 13 item 4); here the same bytes are built from and
read into numpy arrays directly.  Byte for byte what ``rclpy.serialization`` gives for the
same values (``test/test_cdr.py`` checks it on many random messages).

Layout (OMG CDR as Fast DDS writes it for ROS 2): a 4-byte encapsulation header
``00 01 00 00`` (CDR, little endian), then the fields in order, each primitive aligned to
its size counted from the end of that header (8-byte types to 8); a string is a uint32
length including the terminating NUL, its bytes and the NUL; a sequence is a uint32 count,
then its elements (aligned as their type; an empty sequence adds no padding).

Message definitions: ``msg_defs/msg/Fleet*.msg`` (unchanged).  Decoders never raise: they
return None for anything that is not a well-formed little-endian message of the type
(truncated, lengths beyond the data, a string without its NUL, not UTF-8, big-endian; bytes
after the message are ignored, as rclpy ignores them), and
the receiver then falls back to ``rclpy.serialization.deserialize_message`` (which rejects
what is really broken) and its per-message rules.  Here: the simulator's end of the
lockstep (FleetState out, FleetCommand in), /clock and the fleet sensor batches; the ATO's
end is :mod:`metro_atc.nodes.cdr_fleet`.
"""

from __future__ import annotations

import struct
from typing import Any, NamedTuple, Sequence

import numpy as np

ENCAPSULATION = b"\x00\x01\x00\x00"
"""CDR_LE encapsulation header (XCDR1, little endian, no options)."""
MAX_COUNT = 1 << 24
"""Largest sequence or string length a decoder accepts (beyond: None; the data would have to
be that long anyway)."""

_U32 = struct.Struct("<I")
_U64 = struct.Struct("<Q")
_STAMP = struct.Struct("<iI")
_FRAME_LINE = b"\x05\x00\x00\x00line\x00"
"""frame_id "line" as a CDR string."""


def stamp_parts(t_s: float) -> tuple[int, int]:
    """(sec, nanosec) of a builtin_interfaces/Time for ``t_s`` simulation seconds.

    Rounded to the nanosecond, negative times clamped to 0 (as ``conversions.set_stamp``).
    """
    ns = int(round(max(0.0, float(t_s)) * 1e9))
    sec, nsec = divmod(ns, 1_000_000_000)
    return sec, nsec


class Writer:
    """Appends CDR fields to a list of byte pieces, keeping the alignment offset."""

    __slots__ = ("parts", "pos")

    def __init__(self) -> None:
        """Start a message (the encapsulation header is not counted in the offset)."""
        self.parts: list[bytes] = [ENCAPSULATION]
        self.pos = 0

    def raw(self, data: bytes, align: int = 1) -> None:
        """Append ``data`` after padding to ``align`` bytes."""
        pad = -self.pos % align
        if pad:
            self.parts.append(b"\x00" * pad)
            self.pos += pad
        self.parts.append(data)
        self.pos += len(data)

    def header(self, t_s: float, frame: bytes = _FRAME_LINE) -> None:
        """std_msgs/Header with stamp ``t_s`` [s] and a frame_id given as a CDR string."""
        self.raw(_STAMP.pack(*stamp_parts(t_s)), 4)
        self.raw(frame, 4)

    def u64(self, value: int) -> None:
        """A uint64."""
        self.raw(_U64.pack(int(value)), 8)

    def strings(self, block: bytes) -> None:
        """A string[] given as :func:`string_seq` bytes (its count included)."""
        self.raw(block, 4)

    def array(self, values: np.ndarray, dtype: str) -> None:
        """A sequence of a primitive type (``dtype``: '<f8', '<i4', '<u4', '<i8', 'u1')."""
        a = np.ascontiguousarray(values, dtype=dtype)
        self.raw(_U32.pack(a.size), 4)
        if a.size:
            self.raw(a.tobytes(), a.dtype.itemsize)

    def bytes(self) -> bytes:
        """The message (encapsulation header included)."""
        return b"".join(self.parts)


def cdr_string(text: str) -> bytes:
    """One CDR string (uint32 length with NUL, UTF-8 bytes, NUL), unaligned."""
    b = text.encode("utf-8")
    return _U32.pack(len(b) + 1) + b + b"\x00"


def string_seq(items: Sequence[str]) -> bytes:
    """A string[] (count, then each string 4-aligned) as it follows a 4-aligned offset."""
    out = [_U32.pack(len(items))]
    pos = 4
    for s in items:
        pad = -pos % 4
        b = cdr_string(s)
        out.append(b"\x00" * pad + b)
        pos += pad + len(b)
    return b"".join(out)


def text(raw: bytes) -> str | None:
    """UTF-8 text of a string's bytes (None when not UTF-8)."""
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError:
        return None


class Reader:
    """Reads CDR fields from a message; every read checks the bounds (``ok`` turns False)."""

    __slots__ = ("buf", "pos", "end", "ok")

    def __init__(self, data: bytes) -> None:
        """Open a message; a foreign encapsulation (not CDR_LE) makes the reader not ok."""
        self.buf = memoryview(data) if not isinstance(data, memoryview) else data
        self.end = len(self.buf)
        self.ok = self.end >= 4 and bytes(self.buf[0:2]) == b"\x00\x01"
        self.pos = 4

    def _take(self, n: int, align: int) -> int:
        """Offset of ``n`` bytes after aligning (relative to the encapsulation end)."""
        start = self.pos + (-(self.pos - 4) % align)
        if not self.ok or n < 0 or start + n > self.end:
            self.ok = False
            return self.end
        self.pos = start + n
        return start

    def u32(self) -> int:
        """A uint32 (0 when past the end)."""
        at = self._take(4, 4)
        return _U32.unpack_from(self.buf, at)[0] if self.ok else 0

    def u64(self) -> int:
        """A uint64 (0 when past the end)."""
        at = self._take(8, 8)
        return _U64.unpack_from(self.buf, at)[0] if self.ok else 0

    def stamp(self) -> tuple[int, int]:
        """A builtin_interfaces/Time as (sec, nanosec)."""
        at = self._take(8, 4)
        return _STAMP.unpack_from(self.buf, at) if self.ok else (0, 0)

    def string_bytes(self) -> bytes:
        """A string's bytes without the NUL (b'' and not ok when malformed)."""
        n = self.u32()
        if not self.ok or n == 0 or n > MAX_COUNT:
            self.ok = False
            return b""
        at = self._take(n, 1)
        if not self.ok or self.buf[at + n - 1] != 0:
            self.ok = False
            return b""
        return bytes(self.buf[at:at + n - 1])

    def string(self) -> str:
        """Read one UTF-8 text ('' and not ok when malformed, or not UTF-8)."""
        got = text(self.string_bytes()) if self.ok else None
        if got is None:
            self.ok = False
            return ""
        return got

    def strings_raw(self) -> tuple[bytes, ...]:
        """A string[] as the bytes of each string (a hashable key; no UTF-8 decoding)."""
        n = self.u32()
        if not self.ok or n > MAX_COUNT or n > (self.end - self.pos) // 5 + 1:
            self.ok = False
            return ()
        # one tight loop (the simulator reads a FleetCommand's ids every step)
        buf, pos, end, out = self.buf, self.pos, self.end, []
        unpack = _U32.unpack_from
        for _ in range(n):
            pos += -(pos - 4) % 4
            if pos + 4 > end:
                self.ok = False
                return ()
            size = unpack(buf, pos)[0]
            pos += 4
            if size == 0 or pos + size > end or buf[pos + size - 1] != 0:
                self.ok = False
                return ()
            out.append(bytes(buf[pos:pos + size - 1]))
            pos += size
        self.pos = pos
        return tuple(out)

    def strings(self) -> list[str]:
        """A string[] (not ok when an element is malformed or not UTF-8)."""
        got = [text(b) for b in self.strings_raw()]
        if any(s is None for s in got):
            self.ok = False
            return []
        return got  # type: ignore[return-value]

    def array(self, dtype: str) -> np.ndarray:
        """A sequence of a primitive type as a read-only numpy view (empty when malformed)."""
        dt = np.dtype(dtype)
        n = self.u32()
        if not self.ok or n > MAX_COUNT:
            self.ok = False
            return np.zeros(0, dtype=dt)
        if n == 0:
            return np.zeros(0, dtype=dt)
        at = self._take(n * dt.itemsize, dt.itemsize)
        if not self.ok:
            return np.zeros(0, dtype=dt)
        return np.frombuffer(self.buf, dtype=dt, count=n, offset=at)

    def finished(self) -> bool:
        """Everything read was in bounds.

        Bytes after the message are ignored, as rclpy does (its serialized buffers can be
        longer than the message).
        """
        return self.ok


# ------------------------------------------------------------------ rosgraph_msgs/Clock
def clock(t_s: float) -> bytes:
    """A rosgraph_msgs/Clock for ``t_s`` simulation seconds."""
    return ENCAPSULATION + _STAMP.pack(*stamp_parts(t_s))


# ------------------------------------------------------------------ FleetState
FLEET_STATE_ARRAYS = (("position_m", "<f8"), ("speed_mps", "<f8"),
                      ("acceleration_mps2", "<f8"), ("current_station", "<i4"),
                      ("next_station", "<i4"), ("mode", "u1"), ("departure_time_s", "<f8"),
                      ("target_running_time_s", "<f8"), ("supervision_speed_mps", "<f8"),
                      ("movement_authority_m", "<f8"), ("echo", "u1"))
"""The per-train arrays of a FleetState after ``train_id``, in order, with their CDR types
(bool as one byte)."""


def fleet_state(t_s: float, step: int, ids_block: bytes,
                arrays: Sequence[np.ndarray]) -> bytes:
    """Serialize a FleetState.

    Header stamp ``t_s`` [s] (frame "line"), ``step``, ``ids_block`` (the train ids as
    :func:`string_seq`) and the arrays of :data:`FLEET_STATE_ARRAYS` in order.
    """
    w = Writer()
    w.header(t_s)
    w.u64(step)
    w.strings(ids_block)
    for a, (_, dt) in zip(arrays, FLEET_STATE_ARRAYS):
        w.array(a, dt)
    return w.bytes()


class FleetStateBuilder:
    """FleetStates of one list of trains, from a template laid out once.

    The simulator publishes one every step for the same trains (until one enters or leaves
    service): the layout (offsets of every array) depends only on the train ids, so each
    message is a copy of the template with the stamp, the step and the arrays written in
    place.  The bytes are those of :func:`fleet_state`.
    """

    def __init__(self, ids_block: bytes, n: int) -> None:
        """Lay out the FleetState of ``n`` trains whose ids are ``ids_block``."""
        w = Writer()
        w.header(0.0)
        w.u64(0)
        w.strings(ids_block)
        self.n = int(n)
        self.offsets: list[tuple[int, np.dtype[Any]]] = []
        for _, dt in FLEET_STATE_ARRAYS:
            d = np.dtype(dt)
            w.raw(_U32.pack(self.n), 4)
            if self.n:
                w.raw(bytes(self.n * d.itemsize), d.itemsize)
                self.offsets.append((len(ENCAPSULATION) + w.pos - self.n * d.itemsize, d))
            else:
                self.offsets.append((0, d))
        self.template = w.bytes()

    def build(self, t_s: float, step: int, arrays: Sequence[np.ndarray]) -> bytes:
        """The FleetState of stamp ``t_s`` [s], ``step`` and :data:`FLEET_STATE_ARRAYS`."""
        buf = bytearray(self.template)
        _STAMP.pack_into(buf, 4, *stamp_parts(t_s))
        _U64.pack_into(buf, 4 + _STEP_AT, int(step))
        if self.n:
            for (off, d), a in zip(self.offsets, arrays):
                np.frombuffer(buf, dtype=d, count=self.n, offset=off)[:] = a
        return bytes(buf)


_STEP_AT = 24
"""Offset of a FleetState's step after the encapsulation (header of frame "line": stamp 8
bytes, frame_id 9, padded to 8)."""


# ------------------------------------------------------------------ FleetCommand
class FleetCommandData(NamedTuple):
    """A decoded FleetCommand.

    ``train_id_raw``: the train ids' bytes, not decoded (a cache key; :func:`text`
    decodes one).
    """

    sec: int
    nanosec: int
    frame_id: str
    step: int
    train_id_raw: tuple[bytes, ...]
    effort: np.ndarray
    mode: np.ndarray


class _CommandLayout(NamedTuple):
    """Where the values of a FleetCommand are, for messages whose other bytes are these.

    A writer sends the same frame and train ids every step: only the stamp, the step and
    the efforts and modes change, at the same offsets.  ``head``: the bytes from the end of
    the stamp to the step (frame_id and padding); ``ids``: from the end of the step to the
    efforts (train ids, padding, effort count and padding); ``mode_count``: the mode count.
    """

    size: int
    head: bytes
    step_at: int
    ids: bytes
    effort_at: int
    count_at: int
    mode_count: bytes
    n: int
    frame: str
    train_id_raw: tuple[bytes, ...]


_LAYOUTS: dict[int, list[_CommandLayout]] = {}
"""FleetCommand layouts seen, by message size (a few per size: one per ATO process)."""
_LAYOUTS_MAX = 64
"""Layouts kept at most (a writer cycling through train lists: the oldest dropped)."""


def read_fleet_command(data: bytes) -> FleetCommandData | None:
    """Decode a FleetCommand (None when not a well-formed one, see the module docstring).

    A message laid out as one read before (same size, and the same bytes everywhere but in
    the stamp, the step, the efforts and the modes) is read at that layout's offsets
    (~5x cheaper); anything else by :class:`Reader` field by field. Same result either way.
    """
    for lay in _LAYOUTS.get(len(data), ()):
        c = lay.count_at
        if data[12:lay.step_at] == lay.head and data[lay.step_at + 8:lay.effort_at] == lay.ids \
                and data[c:c + 4] == lay.mode_count and data[:2] == b"\x00\x01":
            sec, nsec = _STAMP.unpack_from(data, 4)
            return FleetCommandData(
                sec, nsec, lay.frame, _U64.unpack_from(data, lay.step_at)[0],
                lay.train_id_raw, np.frombuffer(data, "<f8", lay.n, lay.effort_at),
                np.frombuffer(data, "u1", lay.n, lay.count_at + 4))
    try:
        r = Reader(data)
        sec, nsec = r.stamp()
        frame = r.string()
        step = r.u64()
        step_at = r.pos - 8
        ids = r.strings_raw()
        effort = r.array("<f8")
        effort_end = r.pos
        mode = r.array("u1")
    except (ValueError, TypeError, struct.error):  # pragma: no cover - bounds checked above
        return None
    if not r.finished():
        return None
    n = len(ids)
    if n and effort.size == n and mode.size == n:
        _remember(_CommandLayout(
            len(data), bytes(data[12:step_at]), step_at,
            bytes(data[step_at + 8:effort_end - 8 * n]), effort_end - 8 * n, effort_end,
            bytes(data[effort_end:effort_end + 4]), n, frame, ids))
    return FleetCommandData(sec, nsec, frame, step, ids, effort, mode)


def _remember(lay: _CommandLayout) -> None:
    """Keep a FleetCommand layout (bounded: :data:`_LAYOUTS_MAX`)."""
    if sum(len(v) for v in _LAYOUTS.values()) >= _LAYOUTS_MAX:
        _LAYOUTS.clear()
    _LAYOUTS.setdefault(lay.size, []).append(lay)


# ------------------------------------------------------------------ FleetBrakeSensorData
FLEET_SENSOR_ARRAYS = (("sample_train", "<u4"), ("stamp_ns", "<i8"), ("axle_count", "<u4"),
                       ("wheel_angular_speed_radps", "<f8"), ("clamp_force_n", "<f8"),
                       ("longitudinal_acceleration_mps2", "<f8"),
                       ("reference_speed_mps", "<f8"), ("car_mass_kg", "<f8"))
"""The arrays of a FleetBrakeSensorData after ``train_id``, in order, with their CDR types."""


def fleet_sensors(t_s: float, ids_block: bytes, arrays: Sequence[np.ndarray]) -> bytes:
    """Serialize a FleetBrakeSensorData.

    Header stamp ``t_s`` [s] (frame "line"), the train ids as :func:`string_seq` and the
    arrays of :data:`FLEET_SENSOR_ARRAYS` in order.
    """
    w = Writer()
    w.header(t_s)
    w.strings(ids_block)
    for a, (_, dt) in zip(arrays, FLEET_SENSOR_ARRAYS):
        w.array(a, dt)
    return w.bytes()


class FleetSensorData(NamedTuple):
    """A decoded FleetBrakeSensorData (arrays are read-only views of the message)."""

    sec: int
    nanosec: int
    frame_id: str
    train_id: list[str]
    arrays: dict[str, np.ndarray]


def read_fleet_sensors(data: bytes) -> FleetSensorData | None:
    """Decode a FleetBrakeSensorData (None when not a well-formed one)."""
    try:
        r = Reader(data)
        sec, nsec = r.stamp()
        frame = r.string()
        ids = r.strings()
        arrays = {name: r.array(dt) for name, dt in FLEET_SENSOR_ARRAYS}
    except (ValueError, TypeError, struct.error):  # pragma: no cover - bounds checked above
        return None
    if not r.finished():
        return None
    return FleetSensorData(sec, nsec, frame, ids, arrays)
