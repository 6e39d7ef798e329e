"""CDR codec of the fleet lockstep messages, ROS-free (issue 13, graph speed).

An ATO process receives one ``FleetState`` and sends one ``FleetCommand`` per lockstep
step.  rclpy turns each received message into a Python message object (every array field
checked by its property setter) and each sent one back into C: per step that cost more than
the validation of the entries.  The process instead takes the CDR bytes (a ``raw=True``
subscription, ``Publisher.publish(bytes)``) and reads / writes them here with :mod:`struct`.

Wire format (OMG CDR as ROS 2's rmw serialises it, XCDR1 plain little endian): a 4-byte
encapsulation header ``00 01 00 00``, then the fields in order, each primitive aligned to
its size counted from the end of the header; a string is a uint32 length (the terminating
NUL included) followed by its UTF-8 bytes and the NUL; a sequence is a uint32 count
followed by its elements (float64 elements aligned to 8).  Padding bytes are ignored on
read (rmw leaves them uninitialised) and written as zeros.

The ATO's end of the lockstep: :func:`decode_fleet_state` and :func:`encode_fleet_command`
(the simulator's end, FleetState out and FleetCommand in, and the CDR primitives, are in
:mod:`metro_atc.nodes.cdr`).  The decoder is strict and never raises: anything it does not
read exactly as rmw would (another encapsulation, a truncated buffer, a count beyond the
buffer, arrays of unequal lengths, a string without its NUL or not UTF-8, a bool other than
0 / 1) gives None, and the caller falls back to rclpy's own deserialisation (which then
rejects or reads it as before).  Values are not validated
here (NaN, ranges): that stays the receiver's job (:mod:`metro_atc.nodes.conversions`).
Proven against rclpy ``serialize_message`` / ``deserialize_message`` on many random and
hostile messages in ``test/test_cdr_fleet.py``.
"""

from __future__ import annotations

import struct
from typing import Any, NamedTuple, Optional, Sequence

from metro_atc.nodes.cdr import ENCAPSULATION, cdr_string, string_seq
MAX_TRAINS = 1 << 16
"""More entries than this in one fleet message are not decoded here (rclpy's path)."""

_U32 = struct.Struct("<I")
_U64 = struct.Struct("<Q")
_STAMP = struct.Struct("<iI")


class Stamp(NamedTuple):
    """builtin_interfaces/Time as read from the wire (sec, nanosec)."""

    sec: int
    nanosec: int


class Header(NamedTuple):
    """std_msgs/Header as read from the wire."""

    stamp: Stamp
    frame_id: str


class FleetStateView:
    """A decoded FleetState: the message's field names, plain Python values.

    Arrays are tuples (float64: float, int32 / uint8: int), ``train_id`` a list of str,
    ``echo`` a list of bool: what :mod:`metro_atc.nodes.conversions` reads of a FleetState.
    """

    __slots__ = ("header", "step", "train_id", "position_m", "speed_mps",
                 "acceleration_mps2", "current_station", "next_station", "mode",
                 "departure_time_s", "target_running_time_s", "supervision_speed_mps",
                 "movement_authority_m", "echo")

    def __init__(self, **fields: Any) -> None:
        """Set every field (keyword per message field)."""
        for k, v in fields.items():
            setattr(self, k, v)


def decode_fleet_state(buf: Any) -> Optional[FleetStateView]:
    """A FleetState's fields from its CDR bytes; None when not read exactly (see module)."""
    try:
        return _decode_state_fast(bytes(buf))
    except (struct.error, TypeError, ValueError, MemoryError):
        return None


_HEAD = struct.Struct("<iII")
_STATE_ARRAYS = ("d", "d", "d", "i", "i", "B", "d", "d", "d", "d", "B")
"""Element codes of the FleetState arrays after ``train_id``, in order."""
_STATE_NAMES = ("position_m", "speed_mps", "acceleration_mps2", "current_station",
                "next_station", "mode", "departure_time_s", "target_running_time_s",
                "supervision_speed_mps", "movement_authority_m", "echo")
_SIZES = {"d": 8, "i": 4, "B": 1, "I": 4}
_layouts: dict[tuple[int, int, tuple[str, ...]], tuple[struct.Struct, tuple[int, ...]]] = {}
_strings: dict[bytes, str] = {}


def _layout(n: int, off: int, codes: tuple[str, ...]) -> tuple[struct.Struct, tuple[int, ...]]:
    """One Struct for sequences of n elements each (``codes``) from body offset ``off``.

    Returns the Struct and the index of each count in its unpacked tuple.
    """
    key = (n, off % 8, codes)
    got = _layouts.get(key)
    if got is not None:
        return got
    fmt, pos, where, k = ["<"], off, [], 0
    for c in codes:
        for code in ("I", c):
            size = _SIZES[code]
            if code == "I" or n:
                pad = (-pos) % size
                if pad:
                    fmt.append(f"{pad}x")
                    pos += pad
            if code == "I":
                fmt.append("I")
                where.append(k)
                k += 1
                pos += 4
            elif n:
                fmt.append(f"{n}{code}")
                k += n
                pos += size * n
    got = (struct.Struct("".join(fmt)), tuple(where))
    if len(_layouts) < 256:
        _layouts[key] = got
    return got


def _decode_state_fast(b: bytes) -> Optional[FleetStateView]:
    """:func:`decode_fleet_state` of a well-formed message of equal-length arrays, else None.

    The arrays after ``train_id`` are read by one cached Struct (their layout depends on
    the number of trains and the alignment only); the train ids by a short loop.
    """
    if b[:4] != ENCAPSULATION or len(b) < 16:
        return None
    sec, nsec, flen = _HEAD.unpack_from(b, 4)
    p = 16 + flen
    if flen == 0 or p > len(b) or b[p - 1] != 0:
        return None
    frame_b = b[16:p - 1]
    p += (-(p - 4)) % 8
    if p + 12 > len(b):
        return None
    step, n = _STEP_COUNT.unpack_from(b, p)
    p += 12
    if n > MAX_TRAINS:
        return None
    ids = []
    cache = _strings
    u32 = _U32.unpack_from
    for _ in range(n):
        p += (-(p - 4)) % 4
        (L,) = u32(b, p)
        raw = b[p + 4:p + 4 + L]
        if L == 0 or len(raw) != L or raw[-1] != 0:
            return None
        s = cache.get(raw)
        if s is None:
            if 0 in raw[:-1]:
                return None
            s = raw[:-1].decode("utf-8")
            if len(cache) < 4096:
                cache[raw] = s
        ids.append(s)
        p += 4 + L
    st, where = _layout(n, p - 4, _STATE_ARRAYS)
    if p + st.size > len(b):
        return None
    v = st.unpack_from(b, p)
    for k in where:  # every count is n (a loop: no generator per message, issue 13)
        if v[k] != n:
            return None
    arrays = [v[k + 1:k + 1 + n] for k in where]
    echo = arrays[-1]
    if echo and max(echo) > 1:  # booleans are 0 or 1
        return None
    if 0 in frame_b:
        return None
    try:
        frame = frame_b.decode("utf-8")
    except UnicodeDecodeError:
        return None
    view = FleetStateView(header=Header(Stamp(sec, nsec), frame), step=step, train_id=ids,
                          echo=[x == 1 for x in echo])
    for name, a in zip(_STATE_NAMES[:-1], arrays):
        setattr(view, name, a)
    return view


_STEP_COUNT = struct.Struct("<QI")


def encode_fleet_command(stamp: tuple[int, int], frame_id: str, step: int,
                         train_ids: Sequence[str], efforts: Sequence[float],
                         modes: Sequence[int]) -> bytes:
    """A FleetCommand's CDR bytes (what rclpy publishes for the same field values).

    ``stamp``: (sec, nanosec), e.g. :func:`metro_atc.nodes.cdr.stamp_parts`.  Raises
    ValueError / struct.error on values the message cannot hold (as rclpy's setters raise
    on them) and on arrays of unequal lengths (the caller then publishes a message object).
    The bytes up to the arrays depend on the frame and the train ids only (cached); the
    arrays are packed by one cached Struct.
    """
    if not 0 <= step < 1 << 64:
        raise ValueError("step out of uint64")
    n = len(train_ids)
    if len(efforts) != n or len(modes) != n:
        raise ValueError("efforts, modes and train ids of unequal lengths")
    key = (frame_id, tuple(train_ids))
    pre = _prefixes.get(key)
    if pre is None:
        if "\x00" in frame_id or any("\x00" in t for t in train_ids):
            raise ValueError("a CDR string cannot hold a NUL")
        frame = cdr_string(frame_id)
        pos = 8 + len(frame)  # body offset after the stamp and the frame id
        head = frame + b"\x00" * (-pos % 8)
        pos += -pos % 8 + 8  # the step
        ids = string_seq(list(train_ids))  # follows an 8-aligned offset
        st, _ = _layout(n, pos + len(ids), ("d", "B"))
        pre = (head, ids, st)
        if len(_prefixes) < 1024:
            _prefixes[key] = pre
    head, ids, st = pre
    return b"".join((ENCAPSULATION, _STAMP.pack(*stamp), head, _U64.pack(step), ids,
                     st.pack(n, *efforts, n, *modes)))


_prefixes: dict[tuple[str, tuple[str, ...]], tuple[bytes, bytes, struct.Struct]] = {}


_TC_TAIL = struct.Struct("<QdB")
_tc_prefixes: dict[tuple[str, str], bytes] = {}


def encode_traction_command(stamp: tuple[int, int], frame_id: str, train_id: str,
                            step: int, effort: float, mode: int) -> bytes:
    """A TractionCommand's CDR bytes (what rclpy publishes for the same field values).

    ``stamp``: (sec, nanosec), e.g. :func:`metro_atc.nodes.cdr.stamp_parts`; ``effort``
    [-1, 1]; ``mode`` a TrainState.MODE_*.  Raises ValueError / struct.error on values the
    message cannot hold (the caller then publishes a message object, whose setters
    decide).  The bytes between the stamp and the step depend on the frame and the train
    id only (cached).  The per-train echo of a fleet command (issue 13: a rosidl message
    per echo cost ~40 µs).
    """
    if type(effort) is not float or type(step) is not int or type(mode) is not int:
        raise ValueError("step, effort or mode of another type")
    key = (frame_id, train_id)
    mid = _tc_prefixes.get(key)
    if mid is None:
        if "\x00" in frame_id or "\x00" in train_id:
            raise ValueError("a CDR string cannot hold a NUL")
        frame = cdr_string(frame_id)
        pos = 8 + len(frame)  # body offset after the stamp and the frame id
        tid = cdr_string(train_id)
        pad = -pos % 4
        pos += pad + len(tid)
        mid = frame + b"\x00" * pad + tid + b"\x00" * (-pos % 8)  # the step is 8-aligned
        if len(_tc_prefixes) < 4096:
            _tc_prefixes[key] = mid
    return b"".join((ENCAPSULATION, _STAMP.pack(*stamp), mid, _TC_TAIL.pack(step, effort, mode)))
