"""FleetState (line_simulator -> the ATO processes, every lockstep step): its one codec.

Layout: ``header``, ``step``, ``train_id``, then the per-train arrays of
``msg_defs/msg/FleetState.msg``, read from the generated class (:data:`ARRAYS`); each array
is known to the core conversions by name (:data:`CORE_KEYS`; ``echo`` is the flag of the
per-train state published too), checked when this module loads.

* :func:`encode` / :class:`Builder`: the simulator's bytes (the builder writes the values
  into a template laid out once per list of trains);
* :func:`decode`: the ATO's read of the bytes into a :class:`FleetStateView` (None for
  anything not read exactly as rmw would: the caller falls back to rclpy's reader);
* :func:`from_core` / :func:`from_core_rows` / :func:`to_msg`: core state arrays -> bytes or
  a message object;
* :func:`entries` / :func:`checked`: a message (or view) -> per-train views for the
  per-train rules, or validated core state dicts.
"""

from __future__ import annotations

import array
import math
import struct
from typing import Any, Mapping, NamedTuple, Optional, Sequence

import numpy as np
from metro_atc_msgs.msg import FleetState

from metro_atc.core.validate import Bounds, Rejected, check_stamp, check_time
from metro_atc.nodes import conversions as conv
from metro_atc.nodes.wire import cdr

HEAD = (("header", "header"), ("step", "scalar"), ("train_id", "strings"))
"""The leading fields, written by hand (the rest are the per-train arrays)."""
ARRAYS = cdr.split_layout(FleetState, HEAD, "array")
"""The per-train arrays after ``train_id``, in order, from the message class."""
NAMES = tuple(f.name for f in ARRAYS)
"""Their names."""

CORE_KEYS = {"position_m": "x_m", "speed_mps": "v_mps", "acceleration_mps2": "a_mps2",
             "current_station": "current_station", "next_station": "next_station",
             "mode": "mode", "departure_time_s": "departure_time_s",
             "target_running_time_s": "target_running_time_s",
             "supervision_speed_mps": "atp_limit_mps",
             "movement_authority_m": "movement_authority_m", "mass_kg": "mass_kg"}
"""Per-train field -> core state key (:mod:`metro_atc.core.plant.views`); the order is the
one :func:`checked` reads them in.  ``echo`` is not a core state."""
ECHO = "echo"
"""The flag field: the per-train state was published for this step as well."""
cdr.require_names(FleetState, ARRAYS, tuple(CORE_KEYS) + (ECHO,))
STATE_FIELDS = tuple(CORE_KEYS)
"""Per-train arrays of a FleetState that are core state (TrainState fields of the same
names)."""

STEP_AT = 24
"""Offset of the step after the encapsulation for frame "line" (stamp 8 bytes, frame_id
9, padded to 8)."""


# ------------------------------------------------------------------ encode
def encode(t_s: float, step: int, ids_block: bytes, arrays: Sequence[Any]) -> bytes:
    """Serialize a FleetState.

    Header stamp ``t_s`` [s] (frame "line"), ``step``, ``ids_block`` (the train ids as
    :func:`cdr.string_seq`) and the arrays of :data:`ARRAYS` in order.
    """
    w = cdr.Writer()
    w.header(t_s)
    w.u64(step)
    w.strings(ids_block)
    for a, f in zip(arrays, ARRAYS):
        w.array(a, f.dtype)
    return w.bytes()


class Builder:
    """FleetStates of one list of trains, from a template laid out once.

    The simulator publishes one every step for the same trains (until one enters or leaves
    service): the layout (offsets of every array) depends only on the train ids, so each
    message is a copy of the template with the stamp, the step and the arrays written in
    place.  The bytes are those of :func:`encode`.
    """

    def __init__(self, ids_block: bytes, n: int) -> None:
        """Lay out the FleetState of ``n`` trains whose ids are ``ids_block``."""
        w = cdr.Writer()
        w.header(0.0)
        w.u64(0)
        assert w.pos == STEP_AT + 8
        w.strings(ids_block)
        self.n = int(n)
        self.offsets: list[tuple[int, np.dtype[Any]]] = []
        for f in ARRAYS:
            d = np.dtype(f.dtype)
            w.raw(cdr.U32.pack(self.n), 4)
            if self.n:
                w.raw(bytes(self.n * d.itemsize), d.itemsize)
                self.offsets.append((len(cdr.ENCAPSULATION) + w.pos - self.n * d.itemsize, d))
            else:
                self.offsets.append((0, d))
        self.template = w.bytes()

    def build(self, t_s: float, step: int, arrays: Sequence[Any]) -> bytes:
        """The FleetState of stamp ``t_s`` [s], ``step`` and :data:`ARRAYS`."""
        buf = bytearray(self.template)
        cdr.STAMP.pack_into(buf, 4, *cdr.stamp_parts(t_s))
        cdr.U64.pack_into(buf, 4 + STEP_AT, int(step))
        if self.n:
            for (off, d), a in zip(self.offsets, arrays):
                np.frombuffer(buf, dtype=d, count=self.n, offset=off)[:] = a
        return bytes(buf)


# ------------------------------------------------------------------ decode
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
    a bool array a list of bool: what :func:`entries` and :func:`checked` read.
    """

    __slots__ = tuple(name for name, _ in HEAD) + NAMES

    def __init__(self, **fields: Any) -> None:
        """Set every field (keyword per message field)."""
        for k, v in fields.items():
            setattr(self, k, v)


_CODES = tuple(f.code for f in ARRAYS)
_BOOLS = tuple(i for i, f in enumerate(ARRAYS) if f.boolean)
_STEP_COUNT = struct.Struct("<QI")
_structs: dict[Any, tuple[struct.Struct, tuple[int, ...]]] = {}
_strings: dict[bytes, str] = {}


def decode(buf: Any) -> Optional[FleetStateView]:
    """A FleetState's fields from its CDR bytes; None when not read exactly as rmw would.

    None for another encapsulation, a truncated buffer, a count beyond the buffer or
    :data:`cdr.MAX_COUNT`, arrays of unequal lengths, a string without its NUL or not
    UTF-8, a bool other than 0 / 1.  Never raises.  Values are not validated here (NaN,
    ranges): that is :func:`checked`'s job.  The arrays are read by one cached Struct
    (their layout depends on the number of trains and the alignment only).
    """
    try:
        return _decode(bytes(buf))
    except (struct.error, TypeError, ValueError, MemoryError):
        return None


def _decode(b: bytes) -> Optional[FleetStateView]:
    """:func:`decode` (may raise struct.error on a short buffer)."""
    if b[:4] != cdr.ENCAPSULATION or len(b) < 16:
        return None
    sec, nsec, flen = cdr.STAMP_STRING_LEN.unpack_from(b, 4)
    p = 16 + flen
    if flen == 0 or p > len(b) or b[p - 1] != 0:
        return None
    frame_b = b[16:p - 1]
    p += (-(p - 4)) % 8
    if p + 12 > len(b):
        return None
    step, n = _STEP_COUNT.unpack_from(b, p)
    got = cdr.read_ids(b, p + 12, n, _strings)
    if got is None:
        return None
    ids, p = got
    st, where = cdr.seq_struct(n, p - 4, _CODES, _structs)
    if p + st.size > len(b):
        return None
    v = st.unpack_from(b, p)
    for k in where:  # every count is n (a loop: no generator per message)
        if v[k] != n:
            return None
    arrays: list[Any] = [v[k + 1:k + 1 + n] for k in where]
    for i in _BOOLS:  # booleans are 0 or 1
        a = arrays[i]
        if a and max(a) > 1:
            return None
        arrays[i] = [x == 1 for x in a]
    if 0 in frame_b:
        return None
    frame = cdr.text(frame_b)
    if frame is None:
        return None
    view = FleetStateView(header=Header(Stamp(sec, nsec), frame), step=step, train_id=ids)
    for name, a in zip(NAMES, arrays):
        setattr(view, name, a)
    return view


# ------------------------------------------------------------------ from the core
def to_msg(train_ids: Sequence[str], idx: "Sequence[int] | np.ndarray",
           states: Mapping[str, np.ndarray], step: int, t_s: float,
           echo: "Sequence[bool] | np.ndarray | None" = None) -> FleetState:
    """One FleetState object of the trains ``idx`` (same values as ``conv.state_msgs``).

    ``echo`` (per entry of ``idx``): the per-train state was published too this step.
    """
    m = FleetState()
    m.header.stamp = conv.to_time(t_s)
    m.header.frame_id = "line"
    m.step = int(step)
    ix = np.asarray(idx, dtype=np.intp)
    m.train_id = [train_ids[i] for i in ix]
    n = ix.size
    # whole arrays as array('d'/'i'/'B') buffers: no per-value Python loop here, and the
    # C conversion of the publish copies them as buffers
    for f in ARRAYS:
        if f.name == ECHO:
            setattr(m, f.name, [False] * n if echo is None else [bool(x) for x in echo])
            continue
        a = states.get(CORE_KEYS[f.name])
        if f.code == "d":
            setattr(m, f.name, array.array("d", [math.nan]) * n if a is None
                    else conv.doubles(np.asarray(a, dtype=np.float64)[ix]))
        else:
            setattr(m, f.name, array.array(f.code, np.asarray(a, dtype=f.dtype)[ix].tobytes()))
    return m


_ROW_KEYS = tuple(CORE_KEYS.get(f.name) for f in ARRAYS)
"""Core key of each array of :data:`ARRAYS` (None: ``echo``)."""


def from_core(builder: Builder, idx: np.ndarray, states: Mapping[str, np.ndarray],
              step: int, t_s: float, echo: np.ndarray) -> bytes:
    """The serialized FleetState of the trains ``idx``: the values of :func:`to_msg`.

    Built without a message object (the simulator publishes one every step).
    ``builder``: the layout of the train ids of ``idx``; ``echo`` per entry of ``idx``.
    """
    rows = {}
    for key in CORE_KEYS.values():
        a = states.get(key)
        if a is not None:
            rows[key] = np.asarray(a)[idx]
    return from_core_rows(builder, idx.size, rows, step, t_s, echo)


def from_core_rows(builder: Builder, n: int, rows: Mapping[str, np.ndarray], step: int,
                   t_s: float, echo: np.ndarray) -> bytes:
    """:func:`from_core` of state arrays taken at its ``n`` trains already.

    ``rows``: the core state arrays of the trains of the message, entry by entry (e.g.
    :func:`metro_atc.core.plant.views.fleet_state_rows`); a key missing is NaN.
    """
    arrays: list[Any] = []
    for key in _ROW_KEYS:
        if key is None:
            arrays.append(np.asarray(echo, dtype=bool))
        else:
            a = rows.get(key)
            arrays.append(math.nan if a is None else a)
    if builder.n != n:
        raise ValueError(f"a FleetState layout of {builder.n} trains for {n}")
    return builder.build(t_s, step, arrays)


# ------------------------------------------------------------------ to the core
def entries(msg: Any, topic: str, hosted: Mapping[str, Any]) -> list[tuple[str, Any]]:
    """The entries of a FleetState for the ``hosted`` trains, as TrainState-like views.

    The message's shape is checked here (every array as long as ``train_id``, no train
    twice: kind ``shape`` / ``train_id``); each entry is then validated by the receiver
    with ``conv.state_from_msg``, exactly as a ``/<train>/state`` message (``echo``: a
    bool).
    """
    arrays = conv.fleet_arrays(msg, topic, NAMES)
    out = []
    for j, tid in enumerate(msg.train_id):
        if tid in hosted:
            vals = {f: a[j] for f, a in zip(NAMES, arrays)}
            vals[ECHO] = bool(vals[ECHO])
            mode = vals["mode"]
            vals["mode"] = mode[0] if isinstance(mode, bytes) else int(mode)
            out.append((tid, conv.Entry(msg.header, msg.step, tid, **vals)))
    return out


def checked(msg: Any, topic: str, hosted: Mapping[str, Any],
            b: Bounds) -> list[tuple[str, dict[str, Any], bool]] | None:
    """The hosted entries of a FleetState as validated state dicts, in one pass.

    The fast path of :func:`entries` + ``conv.state_from_msg``: the message's shape and
    every rule of ``state_from_msg`` except the step window are checked entry by entry
    without building a view per entry; the dicts are those ``state_from_msg`` returns,
    field for field (without ``again``, which the receiver's step window sets).  None when
    anything fails (a NaN fails every range): the caller then takes the per-entry path,
    which rejects exactly as before.  Returns (train id, state, echo) in message order.
    """
    try:
        ids = msg.train_id
        n = len(ids)
        arrays = [getattr(msg, f) for f in STATE_FIELDS]
        echo = getattr(msg, ECHO)
        for a in arrays:  # a loop: no generator per message
            if len(a) != n:
                return None
        if len(echo) != n or len(set(ids)) != n:
            return None
        rows = [j for j, tid in enumerate(ids) if tid in hosted]
        if not rows:
            return []
        t = conv.from_time(msg.header.stamp)
        k = int(msg.step)
        check_stamp(topic, t, k * b.control_period_s)
        check_time(f"{topic}.header.stamp", t, b)
    except (Rejected, TypeError, ValueError, AttributeError):
        return None
    xs, vs, accs, curs, nxts, modes, deps, tgts, sups, mas, masses = arrays
    x0, x1, vmax, amax, hor = b.x_min_m, b.x_max_m, b.v_max_mps, b.a_max_mps2, b.horizon_s
    last, mmax = b.n_stations - 1, len(conv.MODES) - 1
    out = []
    for j in rows:
        x, v, a, cur, nxt, md = xs[j], vs[j], accs[j], curs[j], nxts[j], modes[j]
        dep, tgt, sup, ma, mass = deps[j], tgts[j], sups[j], mas[j], masses[j]
        if isinstance(md, bytes):
            md = md[0]
        if not (type(x) is float and type(v) is float and type(a) is float  # noqa: E721
                and type(dep) is float and type(tgt) is float and type(sup) is float
                and type(ma) is float and type(mass) is float
                and type(cur) is int and type(nxt) is int
                and type(md) is int
                and x0 <= x <= x1 and 0.0 <= v <= vmax and -amax <= a <= amax
                and -1 <= cur <= last and -1 <= nxt <= last and 0 <= md <= mmax
                and (dep != dep or 0.0 <= dep <= hor) and (tgt != tgt or 0.0 <= tgt <= hor)
                and 0.0 <= sup <= vmax and (ma == math.inf or x0 <= ma <= x1)
                and (mass != mass or conv.MASS_MIN_KG <= mass <= conv.MASS_MAX_KG)):
            return None
        out.append((ids[j], {"step": k, "t_s": t, "x_m": x, "v_mps": v, "a_mps2": a,
                             "current_station": cur, "next_station": nxt, "mode": md,
                             "departure_time_s": dep, "target_running_time_s": tgt,
                             "supervision_speed_mps": sup, "movement_authority_m": ma,
                             "mass_kg": mass},
                    bool(echo[j])))
    return out
