"""FleetCommand (an ATO process -> line_simulator, every lockstep step): its one codec.

Layout: ``header``, ``step``, ``train_id``, then the per-train arrays of
``msg_defs/msg/FleetCommand.msg`` (``effort``, ``mode``), read from the generated class
(:data:`ARRAYS`) and checked against the names the conversions know when this module loads.

* :func:`encode`: the ATO's bytes; :func:`to_msg`: the same as a message object;
* :func:`decode`: the simulator's read of the bytes (None for anything not well formed: the
  caller falls back to rclpy's reader);
* :func:`efforts_cdr` / :func:`efforts` / :func:`entries`: a command (bytes or message) ->
  the core's train indices and efforts, or per-train views for the per-train rules.
"""

from __future__ import annotations

import struct
from typing import Any, Mapping, NamedTuple, Sequence

import numpy as np
from metro_atc_msgs.msg import FleetCommand

from metro_atc.core.validate import Rejected, check_stamp
from metro_atc.nodes import conversions as conv
from metro_atc.nodes.wire import cdr

HEAD = (("header", "header"), ("step", "scalar"), ("train_id", "strings"))
"""The leading fields, written by hand (the rest are the per-train arrays)."""
ARRAYS = cdr.split_layout(FleetCommand, HEAD, "array")
"""The per-train arrays after ``train_id``, in order, from the message class."""
NAMES = tuple(f.name for f in ARRAYS)
"""Their names."""
cdr.require_names(FleetCommand, ARRAYS, ("effort", "mode"), ordered=True)
EFFORT = NAMES.index("effort")
"""Index of ``effort`` (normalised, [-1, 1]) in :data:`ARRAYS`."""
MODE = NAMES.index("mode")
"""Index of ``mode`` (a TrainState.MODE_*) in :data:`ARRAYS`."""
_CODES = tuple(f.code for f in ARRAYS)


# ------------------------------------------------------------------ encode
_prefixes: dict[tuple[str, tuple[str, ...]], tuple[bytes, bytes, struct.Struct]] = {}
_structs: dict[Any, tuple[struct.Struct, tuple[int, ...]]] = {}


def encode(stamp: tuple[int, int], frame_id: str, step: int, train_ids: Sequence[str],
           efforts: Sequence[float], modes: Sequence[int]) -> bytes:
    """A FleetCommand's CDR bytes (what rclpy publishes for the same field values).

    ``stamp``: (sec, nanosec), e.g. :func:`cdr.stamp_parts`; ``efforts`` [-1, 1] and
    ``modes`` (TrainState.MODE_*) per train, the arrays of :data:`ARRAYS` in their order
    (checked when the module loads).  Raises ValueError / struct.error on values
    the message cannot hold (as rclpy's setters raise on them) and on arrays of unequal
    lengths (the caller then publishes a message object).  The bytes up to the arrays
    depend on the frame and the train ids only (cached); the arrays are packed by one
    cached Struct.
    """
    if not 0 <= step < 1 << 64:
        raise ValueError("step out of uint64")
    n = len(train_ids)
    if len(efforts) != n or len(modes) != n:
        raise ValueError("efforts, modes and train ids of unequal lengths")
    key = (frame_id, tuple(train_ids))
    pre = _prefixes.get(key)
    if pre is None:
        frame = cdr.cdr_string(frame_id)
        pos = 8 + len(frame)  # body offset after the stamp and the frame id
        head = frame + b"\x00" * (-pos % 8)
        pos += -pos % 8 + 8  # the step
        ids = cdr.string_seq(list(train_ids))  # follows an 8-aligned offset
        st, _ = cdr.seq_struct(n, pos + len(ids), _CODES, _structs)
        pre = (head, ids, st)
        if len(_prefixes) < 1024:
            _prefixes[key] = pre
    head, ids, st = pre
    return b"".join((cdr.ENCAPSULATION, cdr.STAMP.pack(*stamp), head, cdr.U64.pack(step), ids,
                     st.pack(n, *efforts, n, *modes)))


def to_msg(step: int, t_s: float, train_ids: Sequence[str], efforts: Sequence[float],
           modes: Sequence[int]) -> FleetCommand:
    """One FleetCommand object (the commands of one ATO process for step ``step``)."""
    m = FleetCommand()
    m.header.stamp = conv.to_time(t_s)
    m.header.frame_id = "line"
    m.step = int(step)
    m.train_id = list(train_ids)
    m.effort = [float(u) for u in efforts]
    m.mode = [int(x) for x in modes]
    return m


# ------------------------------------------------------------------ decode
class Decoded(NamedTuple):
    """A decoded FleetCommand.

    ``train_id_raw``: the train ids' bytes, not decoded (a cache key; :func:`cdr.text`
    decodes one); ``arrays``: read-only views of :data:`ARRAYS`, in order.
    """

    sec: int
    nanosec: int
    frame_id: str
    step: int
    train_id_raw: tuple[bytes, ...]
    arrays: tuple[np.ndarray, ...]

    @property
    def effort(self) -> np.ndarray:
        """The efforts (normalised, [-1, 1])."""
        return self.arrays[EFFORT]

    @property
    def mode(self) -> np.ndarray:
        """The modes (TrainState.MODE_*)."""
        return self.arrays[MODE]


class _Layout(NamedTuple):
    """Where the values of a FleetCommand are, for messages whose other bytes are these.

    A writer sends the same frame and train ids every step: only the stamp, the step and
    the arrays' values change, at the same offsets.  ``fixed``: (start, end, bytes) of
    every other stretch after the stamp (frame_id, train ids, counts, padding);
    ``at``: the offset of each array's values.
    """

    fixed: tuple[tuple[int, int, bytes], ...]
    step_at: int
    at: tuple[int, ...]
    n: int
    frame: str
    train_id_raw: tuple[bytes, ...]


_LAYOUTS: dict[int, list[_Layout]] = {}
"""FleetCommand layouts seen, by message size (a few per size: one per ATO process)."""
_LAYOUTS_MAX = 64
"""Layouts kept at most (a writer cycling through train lists: the oldest dropped)."""


def decode(data: bytes) -> Decoded | None:
    """Decode a FleetCommand (None when not a well-formed one; never raises).

    None for another encapsulation, a truncated message, lengths beyond the data or
    :data:`cdr.MAX_COUNT`, a string without its NUL, not UTF-8; bytes after the message
    are ignored, as rclpy ignores them.  Values are not checked (that is
    :func:`efforts_cdr`'s job).  A message laid out as one read before (same size, and the
    same bytes everywhere but in the stamp, the step and the arrays' values) is read at that
    layout's offsets (~5x cheaper); anything else by :class:`cdr.Reader` field by field.
    Same result either way.
    """
    for lay in _LAYOUTS.get(len(data), ()):
        for a, b, piece in lay.fixed:
            if data[a:b] != piece:
                break
        else:
            if data[:2] == b"\x00\x01":
                sec, nsec = cdr.STAMP.unpack_from(data, 4)
                n = lay.n
                return Decoded(sec, nsec, lay.frame, cdr.U64.unpack_from(data, lay.step_at)[0],
                               lay.train_id_raw,
                               tuple([np.frombuffer(data, f.dtype, n, at)
                                      for f, at in zip(ARRAYS, lay.at)]))
    try:
        r = cdr.Reader(data)
        sec, nsec = r.stamp()
        frame = r.string()
        step = r.u64()
        step_at = r.pos - 8
        ids = r.strings_raw()
        arrays: list[np.ndarray] = []
        at: list[int] = []
        ends: list[int] = []
        for f in ARRAYS:
            values = r.array(f.dtype)
            arrays.append(values)
            ends.append(r.pos)
            at.append(r.pos - values.nbytes)
    except (ValueError, TypeError, struct.error):  # pragma: no cover - bounds checked above
        return None
    if not r.finished():
        return None
    n = len(ids)
    if n and all(a.size == n for a in arrays):
        fixed = [(12, step_at, bytes(data[12:step_at]))]
        start = step_at + 8
        for begin, end in zip(at, ends):
            fixed.append((start, begin, bytes(data[start:begin])))
            start = end
        _remember(len(data), _Layout(tuple(fixed), step_at, tuple(at), n, frame, ids))
    return Decoded(sec, nsec, frame, step, ids, tuple(arrays))


def _remember(size: int, lay: _Layout) -> None:
    """Keep a FleetCommand layout (bounded: :data:`_LAYOUTS_MAX`)."""
    if sum(len(v) for v in _LAYOUTS.values()) >= _LAYOUTS_MAX:
        _LAYOUTS.clear()
    _LAYOUTS.setdefault(size, []).append(lay)


# ------------------------------------------------------------------ to the core
def entries(msg: Any, topic: str, index: Mapping[str, int]) -> list[tuple[int, Any]]:
    """The entries of a FleetCommand as (train index, TractionCommand-like view).

    Checked here: the shape (kind ``shape`` / ``train_id``) and that every train is one of
    ``index`` (kind ``train_id``); each entry is then validated by the receiver with
    ``conv.traction_from_msg``, exactly as a ``/<train>/command`` message.
    """
    effort, mode = conv.fleet_arrays(msg, topic, ("effort", "mode"))
    out = []
    for j, tid in enumerate(msg.train_id):
        i = conv.train_index(tid, index, topic)
        md = mode[j]
        out.append((i, conv.Entry(msg.header, msg.step, tid, effort=effort[j],
                                  mode=md[0] if isinstance(md, bytes) else int(md))))
    return out


def efforts(msg: Any, topic: str, index: Mapping[str, int], step: int,
            t_s: float) -> tuple[np.ndarray, np.ndarray | None] | None:
    """A FleetCommand object validated as a whole, for lockstep step ``step`` at ``t_s`` [s].

    The simulator's fast path: ``(train indices, efforts)`` when every entry passes
    ``conv.traction_from_msg`` (with ``late_echo``) as it would one by one, ``efforts``
    None for a command of an earlier step (stale duplicates, dropped without counting);
    None when some entry breaks a per-entry rule (effort, mode, step, stamp): the caller
    then validates entry by entry (:func:`entries`), which counts every rejected entry.
    The message's shape and trains are checked here as there (kinds ``shape`` /
    ``train_id``, raised for the whole message).
    """
    effort, mode = conv.fleet_arrays(msg, topic, ("effort", "mode"))
    ix = np.fromiter((conv.train_index(tid, index, topic) for tid in msg.train_id),
                     dtype=np.intp, count=len(msg.train_id))
    e = np.asarray(effort, dtype=np.float64)
    md = np.asarray([x[0] if isinstance(x, bytes) else int(x) for x in mode], dtype=np.int64)
    ok = bool(np.all(np.isfinite(e)) and np.all(np.abs(e) <= 1.0 + 1e-9)
              and np.all((md >= 0) & (md <= len(conv.MODES) - 1)))
    if not ok:
        return None
    k = int(msg.step)
    if k < step:
        return ix, None
    if k != step:
        return None
    try:
        check_stamp(topic, conv.from_time(msg.header.stamp), t_s)
    except Rejected:
        return None
    return ix, np.clip(e, -1.0, 1.0)


FALLBACK = None
"""What :func:`efforts_cdr` returns when the message must take the slow path."""


def efforts_cdr(data: bytes, topic: str, index: dict[bytes, int],
                ix_cache: dict[tuple[bytes, ...], np.ndarray], step: int,
                t_s: float) -> tuple[np.ndarray, np.ndarray | None] | None:
    """:func:`efforts` of a serialized FleetCommand (a raw subscription).

    ``index``: train id (UTF-8 bytes) -> train index; ``ix_cache``: the train indices of
    each train id list seen (filled here; the caller bounds it).  Returns what
    :func:`efforts` returns for a message all of whose entries pass, and :data:`FALLBACK`
    (None) for anything else: bytes that are not a well-formed FleetCommand
    (:func:`decode`), arrays of unequal lengths, an unknown or repeated train, an entry
    breaking a per-entry rule; the caller then deserializes the message and takes the
    object path, which rejects and counts exactly as for a message object.  Never raises.
    """
    m = decode(data)
    if m is None:
        return FALLBACK
    n = len(m.train_id_raw)
    e, md = m.arrays[EFFORT], m.arrays[MODE]
    if e.size != n or md.size != n:
        return FALLBACK
    ix = ix_cache.get(m.train_id_raw)
    if ix is None:
        got = [index.get(b, -1) for b in m.train_id_raw]
        if min(got, default=0) < 0 or len(set(got)) != n:
            return FALLBACK
        ix = ix_cache[m.train_id_raw] = np.array(got, dtype=np.intp)
    # the largest |effort| is NaN when any is (NaN fails the comparison), inf when any is
    if n and not (float(np.abs(e).max()) <= 1.0 + 1e-9 and int(md.max()) <= len(conv.MODES) - 1):
        return FALLBACK
    if m.step < step:
        return ix, None
    if m.step != step:
        return FALLBACK
    try:
        check_stamp(topic, float(m.sec) + 1e-9 * float(m.nanosec), t_s)
    except Rejected:
        return FALLBACK
    # np.minimum(np.maximum()) is np.clip's result (|e| <= 1 + 1e-9, no NaN) at ~1/5 the cost
    return ix, np.minimum(np.maximum(e, -1.0), 1.0)
