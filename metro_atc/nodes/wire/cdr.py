"""CDR (XCDR1, little endian) byte helpers of the hand codecs, and message layouts.

rclpy's ``Publisher.publish`` takes serialized ``bytes`` and a subscription made with
``raw=True`` hands over the CDR bytes of each message: the lockstep messages are written
and read here, without a message object (building one cost more than the DDS write or take
itself).  Byte for byte what ``rclpy.serialization`` gives for the same values (but for
padding, which rmw leaves uninitialised and which is written as zeros and ignored on read).

Wire format (OMG CDR as Fast DDS writes it for ROS 2): a 4-byte encapsulation header
``00 01 00 00`` (CDR, little endian), then the fields in order, each primitive aligned to
its size counted from the end of that header (8-byte types to 8); a string is a uint32
length including the terminating NUL, its UTF-8 bytes and the NUL; a sequence is a uint32
count, then its elements (aligned as their type; an empty sequence adds no padding).

Layouts are not written here by hand: :func:`layout` reads a rosidl-generated message
class's own field list (``get_fields_and_field_types``, in the order of the ``.msg`` file
under ``msg_defs/msg``), so each codec's field list is the message definition's.
"""

from __future__ import annotations

import struct
from typing import Any, NamedTuple, Sequence

import numpy as np

ENCAPSULATION = b"\x00\x01\x00\x00"
"""CDR_LE encapsulation header (XCDR1, little endian, no options)."""
MAX_COUNT = 1 << 24
"""Largest count [elements] of a sequence, or length [bytes] of a string, a decoder reads.

Beyond it the decoder returns None (the receiver then falls back to rclpy's own reader).
16 Mi: 25 times the largest sequence a valid message of the line holds (a
FleetBrakeSensorData's per-axle channels, at most 10 000 samples x 64 axles = 640 000
values), yet a forged uint32 count (up to 4 Gi) cannot make a decoder build a struct
format or loop for that long; every count is checked against the bytes present as well."""

U32 = struct.Struct("<I")
"""A uint32 (a count, a string length)."""
U64 = struct.Struct("<Q")
"""A uint64 (a lockstep step)."""
STAMP = struct.Struct("<iI")
"""A builtin_interfaces/Time (sec, nanosec)."""
STAMP_STRING_LEN = struct.Struct("<iII")
"""A Header's stamp followed by its frame_id's length (they are contiguous at offset 0)."""
FRAME_LINE = b"\x05\x00\x00\x00line\x00"
"""frame_id "line" as a CDR string."""


class LayoutError(TypeError):
    """A message class has a field this codec cannot lay out (its .msg changed)."""


# ------------------------------------------------------------------ layouts from the class
class Field(NamedTuple):
    """One field of a message as it goes on the wire.

    ``kind``: ``header`` (std_msgs/Header), ``time`` (builtin_interfaces/Time), ``string``,
    ``strings`` (string[]), ``scalar`` (a primitive) or ``array`` (a primitive sequence);
    ``dtype``: the numpy dtype of a primitive ('<f8', '<i4', 'u1', ...; '' otherwise);
    ``code``: its :mod:`struct` code ('d', 'i', 'B', ...); ``boolean``: a bool (one byte,
    0 or 1).
    """

    name: str
    kind: str
    dtype: str
    code: str
    boolean: bool


PRIMITIVES = {"double": ("<f8", "d"), "float": ("<f4", "f"), "int8": ("i1", "b"),
              "uint8": ("u1", "B"), "octet": ("u1", "B"), "boolean": ("u1", "B"),
              "int16": ("<i2", "h"), "uint16": ("<u2", "H"), "int32": ("<i4", "i"),
              "uint32": ("<u4", "I"), "int64": ("<i8", "q"), "uint64": ("<u8", "Q")}
"""rosidl primitive type names -> (numpy dtype, struct code), little endian."""


def _field(name: str, ros_type: str) -> Field:
    """The wire field of one entry of ``get_fields_and_field_types()``."""
    if ros_type == "std_msgs/Header":
        return Field(name, "header", "", "", False)
    if ros_type == "builtin_interfaces/Time":
        return Field(name, "time", "", "", False)
    if ros_type == "string":
        return Field(name, "string", "", "", False)
    if ros_type == "sequence<string>":
        return Field(name, "strings", "", "", False)
    seq = ros_type.startswith("sequence<") and ros_type.endswith(">")
    base = ros_type[len("sequence<"):-1] if seq else ros_type
    if base not in PRIMITIVES:
        raise LayoutError(f"field {name!r} of type {ros_type!r}: no CDR layout here")
    dtype, code = PRIMITIVES[base]
    return Field(name, "array" if seq else "scalar", dtype, code, base == "boolean")


def layout(cls: Any) -> tuple[Field, ...]:
    """The wire layout of a rosidl message class, from its own field list, in order.

    Raises :class:`LayoutError` for a field type without a layout here (a nested message
    other than Header / Time, a bounded or fixed-size array).
    """
    return tuple(_field(name, t) for name, t in cls.get_fields_and_field_types().items())


def split_layout(cls: Any, head: Sequence[tuple[str, str]], kind: str
                 ) -> tuple[Field, ...]:
    """The fields of ``cls`` after its ``head`` fields, all of ``kind``.

    ``head``: (name, kind) of the leading fields the codec writes by hand (a Header, a
    step, the train ids).  Raises :class:`LayoutError` when the class does not start with
    them or a later field is of another kind: the codec then refuses to load rather than
    write a message the .msg no longer describes.
    """
    fields = layout(cls)
    got = tuple((f.name, f.kind) for f in fields[:len(head)])
    if got != tuple(head):
        raise LayoutError(f"{cls.__name__} starts with {got}, the codec with {tuple(head)}")
    rest = fields[len(head):]
    for f in rest:
        if f.kind != kind:
            raise LayoutError(f"{cls.__name__}.{f.name} is a {f.kind}, the codec reads a "
                              f"{kind} there")
    return rest


def require_names(cls: Any, fields: Sequence[Field], known: Sequence[str],
                  ordered: bool = False) -> None:
    """Raise :class:`LayoutError` unless ``fields`` are exactly the ``known`` names.

    The conversions to and from the core know each field by name (its unit, its core
    key, its range): a field added to (or dropped from) the .msg without them is refused
    when the codec loads.  ``ordered``: in that order too (for callers that pass the
    values by position).
    """
    names = [f.name for f in fields]
    if ordered and names != list(known) and sorted(names) == sorted(known):
        raise LayoutError(f"{cls.__name__}: fields in the order {names}, the conversions "
                          f"pass them as {list(known)}")
    if sorted(names) != sorted(known):
        extra = sorted(set(names) - set(known))
        missing = sorted(set(known) - set(names))
        raise LayoutError(f"{cls.__name__}: fields without a conversion {extra}, conversions "
                          f"without a field {missing}")


def seq_struct(n: int, off: int, codes: Sequence[str],
               cache: dict[Any, tuple[struct.Struct, tuple[int, ...]]]
               ) -> tuple[struct.Struct, tuple[int, ...]]:
    """One Struct for consecutive sequences of ``n`` elements each, from body offset ``off``.

    ``codes``: the struct code of each sequence's elements.  Returns the Struct (counts
    and elements, with the padding) and the index of each count in its unpacked tuple.
    Kept in ``cache`` (at most 256 layouts: they depend on ``n`` and ``off % 8`` only).
    """
    key = (n, off % 8, tuple(codes))
    got = cache.get(key)
    if got is not None:
        return got
    fmt, pos, where, k = ["<"], off, [], 0
    for c in codes:
        pad = -pos % 4
        if pad:
            fmt.append(f"{pad}x")
            pos += pad
        fmt.append("I")
        where.append(k)
        k += 1
        pos += 4
        if n:
            size = struct.calcsize("<" + c)
            pad = -pos % size
            if pad:
                fmt.append(f"{pad}x")
                pos += pad
            fmt.append(f"{n}{c}")
            k += n
            pos += size * n
    got = (struct.Struct("".join(fmt)), tuple(where))
    if len(cache) < 256:
        cache[key] = got
    return got


def scalars_struct(fields: Sequence[Field], off: int) -> struct.Struct:
    """One Struct for consecutive primitive fields from body offset ``off`` (with padding)."""
    fmt, pos = ["<"], off
    for f in fields:
        size = struct.calcsize("<" + f.code)
        pad = -pos % size
        if pad:
            fmt.append(f"{pad}x")
        fmt.append(f.code)
        pos += pad + size
    return struct.Struct("".join(fmt))


# ------------------------------------------------------------------ writing
def stamp_parts(t_s: float) -> tuple[int, int]:
    """(sec, nanosec) of a builtin_interfaces/Time for ``t_s`` simulation seconds.

    Rounded to the nanosecond, negative times clamped to 0 (as ``conversions.set_stamp``).
    """
    ns = int(round(max(0.0, float(t_s)) * 1e9))
    sec, nsec = divmod(ns, 1_000_000_000)
    return sec, nsec


def cdr_string(text: str) -> bytes:
    """One CDR string (uint32 length with NUL, UTF-8 bytes, NUL), unaligned.

    Raises ValueError for a text holding a NUL (a CDR string cannot carry one).
    """
    if "\x00" in text:
        raise ValueError("a CDR string cannot hold a NUL")
    b = text.encode("utf-8")
    return U32.pack(len(b) + 1) + b + b"\x00"


def string_seq(items: Sequence[str]) -> bytes:
    """A string[] (count, then each string 4-aligned) as it follows a 4-aligned offset."""
    out = [U32.pack(len(items))]
    pos = 4
    for s in items:
        pad = -pos % 4
        b = cdr_string(s)
        out.append(b"\x00" * pad + b)
        pos += pad + len(b)
    return b"".join(out)


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

    def header(self, t_s: float, frame: bytes = FRAME_LINE) -> None:
        """std_msgs/Header with stamp ``t_s`` [s] and a frame_id given as a CDR string."""
        self.raw(STAMP.pack(*stamp_parts(t_s)), 4)
        self.raw(frame, 4)

    def u64(self, value: int) -> None:
        """A uint64."""
        self.raw(U64.pack(int(value)), 8)

    def strings(self, block: bytes) -> None:
        """A string[] given as :func:`string_seq` bytes (its count included)."""
        self.raw(block, 4)

    def array(self, values: Any, dtype: str) -> None:
        """A sequence of a primitive type (``dtype``: '<f8', '<i4', '<u4', '<i8', 'u1')."""
        a = np.ascontiguousarray(values, dtype=dtype)
        self.raw(U32.pack(a.size), 4)
        if a.size:
            self.raw(a.tobytes(), a.dtype.itemsize)

    def bytes(self) -> bytes:
        """The message (encapsulation header included)."""
        return b"".join(self.parts)


# ------------------------------------------------------------------ reading
def text(raw: bytes) -> str | None:
    """UTF-8 text of a string's bytes (None when not UTF-8)."""
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError:
        return None


def read_ids(b: bytes, p: int, n: int, cache: dict[bytes, str]) -> tuple[list[str], int] | None:
    """``n`` CDR strings from offset ``p`` of ``b`` (4-aligned each), and the offset after.

    None when one is malformed (no NUL, an inner NUL, not UTF-8, its bytes cut off);
    raises struct.error when a length itself is cut off (the callers catch it: no bounds
    check per string on the hot path).  ``cache`` maps a string's raw bytes (NUL included)
    to its text (bounded to 4096 entries): the same train ids come every step.
    """
    if n > MAX_COUNT or n > (len(b) - p) // 5 + 1:
        return None
    ids = []
    u32 = U32.unpack_from
    for _ in range(n):
        p += (-(p - 4)) % 4
        (size,) = u32(b, p)
        raw = b[p + 4:p + 4 + size]
        if size == 0 or len(raw) != size or raw[-1] != 0:
            return None
        s = cache.get(raw)
        if s is None:
            if 0 in raw[:-1]:
                return None
            got = text(raw[:-1])
            if got is None:
                return None
            s = got
            if len(cache) < 4096:
                cache[raw] = s
        ids.append(s)
        p += 4 + size
    return ids, p


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
        return U32.unpack_from(self.buf, at)[0] if self.ok else 0

    def u64(self) -> int:
        """A uint64 (0 when past the end)."""
        at = self._take(8, 8)
        return U64.unpack_from(self.buf, at)[0] if self.ok else 0

    def stamp(self) -> tuple[int, int]:
        """A builtin_interfaces/Time as (sec, nanosec)."""
        at = self._take(8, 4)
        return STAMP.unpack_from(self.buf, at) if self.ok else (0, 0)

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
        unpack = U32.unpack_from
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
    """A rosgraph_msgs/Clock for ``t_s`` simulation seconds (a Time is its only field)."""
    return ENCAPSULATION + STAMP.pack(*stamp_parts(t_s))
