"""FleetBrakeSensorData (line_simulator -> brake_diagnostic, recorders): its one codec.

Layout: ``header``, ``train_id``, then the per-sample arrays of
``msg_defs/msg/FleetBrakeSensorData.msg``, read from the generated class (:data:`ARRAYS`)
and checked against the names the conversions know when this module loads.

* :func:`encode` / :func:`to_msg`: the simulator's samples -> bytes or a message object;
* :func:`decode`: bytes -> :class:`Decoded` (None when not well formed);
* :func:`samples`: a message -> the core's validated per-sample dicts (the brake
  diagnostic's input), each sample checked with the per-train rules.
"""

from __future__ import annotations

import array
import functools
import struct
from typing import Any, Mapping, NamedTuple, Sequence

import numpy as np
from metro_atc_msgs.msg import FleetBrakeSensorData

from metro_atc.core.validate import Bounds, Rejected, check_time
from metro_atc.nodes import conversions as conv
from metro_atc.nodes.wire import cdr

HEAD = (("header", "header"), ("train_id", "strings"))
"""The leading fields, written by hand (the rest are the per-sample arrays)."""
ARRAYS = cdr.split_layout(FleetBrakeSensorData, HEAD, "array")
"""The arrays after ``train_id``, in order, from the message class."""
NAMES = tuple(f.name for f in ARRAYS)
"""Their names."""
cdr.require_names(FleetBrakeSensorData, ARRAYS, (
    "sample_train", "stamp_ns", "axle_count", "wheel_angular_speed_radps", "clamp_force_n",
    "longitudinal_acceleration_mps2", "reference_speed_mps", "car_mass_kg"), ordered=True)


def encode(t_s: float, ids_block: bytes, arrays: Sequence[Any]) -> bytes:
    """Serialize a FleetBrakeSensorData.

    Header stamp ``t_s`` [s] (frame "line"), the train ids as :func:`cdr.string_seq` and
    the arrays of :data:`ARRAYS` in order.
    """
    w = cdr.Writer()
    w.header(t_s)
    w.strings(ids_block)
    for a, f in zip(arrays, ARRAYS):
        w.array(a, f.dtype)
    return w.bytes()


class Decoded(NamedTuple):
    """A decoded FleetBrakeSensorData (arrays are read-only views of the message)."""

    sec: int
    nanosec: int
    frame_id: str
    train_id: list[str]
    arrays: dict[str, np.ndarray]


def decode(data: bytes) -> Decoded | None:
    """Decode a FleetBrakeSensorData (None when not a well-formed one; never raises).

    None for another encapsulation, a truncated message, lengths beyond the data or
    :data:`cdr.MAX_COUNT`, a string without its NUL or not UTF-8; bytes after the message
    are ignored, as rclpy ignores them.
    """
    try:
        r = cdr.Reader(data)
        sec, nsec = r.stamp()
        frame = r.string()
        ids = r.strings()
        arrays = {f.name: r.array(f.dtype) for f in ARRAYS}
    except (ValueError, TypeError, struct.error):  # pragma: no cover - bounds checked above
        return None
    if not r.finished():
        return None
    return Decoded(sec, nsec, frame, ids, arrays)


MAX_SAMPLES = 10_000
"""Most samples one FleetBrakeSensorData may carry (beyond: the message is rejected, kind
``length``); a step of the largest line has a few hundred, a re-sent batch fewer."""
MAX_AXLES = 64
"""Most axles a sample of a FleetBrakeSensorData may declare (beyond: kind ``length``)."""


def _ints(values: Any, typecode: str, dtype: Any) -> "array.array[int]":
    """An ``array(typecode)`` of ``values`` copied as one buffer (see :func:`doubles`)."""
    return array.array(typecode, np.ascontiguousarray(values, dtype=dtype).tobytes())


def to_msg(train_ids: Sequence[str], t_step_s: float, trains: Any,
           t_s: Any, omega_radps: Any, clamp_n: Any, accel_mps2: Any,
           ref_speed_mps: Any, car_mass_kg: Any,
           out: FleetBrakeSensorData | None = None) -> FleetBrakeSensorData:
    """FleetBrakeSensorData of the samples ``s`` (in order) of several trains.

    ``train_ids``: the message's ``train_id``; ``trains[s]``: index into it of sample s's
    train; ``t_s[s]`` its time [s]; ``omega_radps``, ``clamp_n``: (samples, axles) wheel
    speeds [rad/s] and clamp forces [N]; ``accel_mps2`` [m/s^2], ``ref_speed_mps`` [m/s],
    ``car_mass_kg`` [kg] (NaN: none) per sample.  ``t_step_s``: the header stamp (the
    simulation time of the step).  The arrays go in as one buffer each (no per-value Python
    loop).  ``out``: a message to refill instead of a new one (its header object is kept:
    building a header cost more than the rest; publish copies the message out at once).
    """
    m = out if out is not None else FleetBrakeSensorData()
    m.header.frame_id = "line"
    conv.set_stamp(m.header.stamp, t_step_s)
    m.train_id = list(train_ids)
    w = np.asarray(omega_radps, dtype=np.float64)
    n = len(t_s)
    axles = w.size // n if n else 0
    m.sample_train = _ints(trains, "I", np.uint32)
    m.stamp_ns = _ints(conv.stamps_ns(t_s), "q", np.int64)
    m.axle_count = _ints(np.full(n, axles), "I", np.uint32)
    m.wheel_angular_speed_radps = conv.doubles(w)
    m.clamp_force_n = conv.doubles(clamp_n)
    m.longitudinal_acceleration_mps2 = conv.doubles(accel_mps2)
    m.reference_speed_mps = conv.doubles(ref_speed_mps)
    m.car_mass_kg = conv.doubles(car_mass_kg)
    return m


def _f64(values: Any) -> np.ndarray:
    """A float64 array of a message's float64[] field (its buffer, no per-value loop)."""
    if isinstance(values, array.array) and values.typecode == "d":
        return np.frombuffer(values, dtype=np.float64) if len(values) else np.zeros(0)
    return np.asarray(values, dtype=np.float64).reshape(-1)


def samples(msg: FleetBrakeSensorData, topic: str, index: Mapping[str, int],
            n_axles: int, b: Bounds, lists: bool = False,
            rows: list[bytes] | None = None
            ) -> list[tuple[str | None, float, dict[str, Any] | Rejected]]:
    """Validate a FleetBrakeSensorData; return per sample ``(train, stamp, sample)``.

    The message as a whole is rejected (raises :class:`conv.MessageRejected`, kind ``length``)
    when its arrays disagree in length, a ``sample_train`` index points outside
    ``train_id``, it carries more than :data:`MAX_SAMPLES` samples or a sample
    declares more than :data:`MAX_AXLES` axles: nothing in it can be attributed
    to a train.  Otherwise each sample is checked on its own, with the rules and kinds of
    :func:`conv.sensor_from_msg` (a wrong number of axles, a stamp outside the run's horizon, a
    finite channel outside ``conv.SENSOR_RANGES``); its entry is then the
    :class:`conv.MessageRejected` instead of the sample dict.  A sample of a train not in
    ``index`` comes back with train ``None`` and a rejection of kind ``train_id``.
    ``stamp`` is the sample's stamp [s] (also of a rejected one: a receiver acknowledges
    those too).  The sample dicts are those of :func:`conv.sensor_from_msg` (``omega``, ``clamp``
    float arrays of ``n_axles``; ``car_mass`` NaN when not finite).  With ``lists`` they
    are float lists instead (a sample dict is then its own JSON round trip: the
    ``brake_diagnostic`` node journals it as it is).  ``rows``: a list that gets
    each sample's values in binary, one ``bytes`` per returned entry (little-endian float64
    ``t_s``, ``omega``, ``clamp``, ``accel``, ``ref_speed``, ``car_mass``, the sample dict's
    values bit for bit; meaningless for a rejected sample): the node's packed journal lines.
    """
    ns = np.frombuffer(msg.stamp_ns, dtype=np.int64) if isinstance(msg.stamp_ns, array.array) \
        else np.asarray(msg.stamp_ns, dtype=np.int64).reshape(-1)
    n = ns.size
    which = np.asarray(msg.sample_train, dtype=np.int64).reshape(-1)
    axles = np.asarray(msg.axle_count, dtype=np.int64).reshape(-1)
    ids = list(msg.train_id)
    w = _f64(msg.wheel_angular_speed_radps)
    c = _f64(msg.clamp_force_n)
    acc = _f64(msg.longitudinal_acceleration_mps2)
    vref = _f64(msg.reference_speed_mps)
    mass = _f64(msg.car_mass_kg)
    if n > MAX_SAMPLES:
        raise Rejected("length", f"{topic}: {n} samples (at most {MAX_SAMPLES})")
    if not (which.size == axles.size == acc.size == vref.size == mass.size == n):
        raise Rejected("length", f"{topic}: per-sample arrays of different lengths "
                       f"(stamp_ns[{n}], sample_train[{which.size}], axle_count[{axles.size}],"
                       f" channels [{acc.size}, {vref.size}, {mass.size}])")
    if n and (which.min() < 0 or which.max() >= len(ids)):
        raise Rejected("length", f"{topic}: sample_train outside train_id[{len(ids)}]")
    if n and axles.max() > MAX_AXLES:
        raise Rejected("length", f"{topic}: a sample declares {int(axles.max())} axles (at "
                       f"most {MAX_AXLES})")
    total = int(axles.sum())
    if w.size != total or c.size != total:
        raise Rejected("length", f"{topic}: per-axle arrays wheel_angular_speed_radps"
                       f"[{w.size}], clamp_force_n[{c.size}] do not hold the {total} axle "
                       "values of axle_count")
    out: list[tuple[str | None, float, dict[str, Any] | Rejected]] = []
    if n == 0:
        return out
    t = conv.seconds_of_ns(ns)
    good_axles = axles == n_axles
    # per-axle channels as (samples, n_axles) rows where the count is right (else zeros:
    # those samples are rejected before their rows are read)
    if good_axles.all():
        wr, cr = w.reshape(n, n_axles), c.reshape(n, n_axles)
    else:
        start = np.concatenate(([0], np.cumsum(axles)[:-1]))
        pick = start[:, None] + np.arange(n_axles)[None, :]
        pick = np.where(good_axles[:, None], pick, 0)
        wr = w[pick] if w.size else np.zeros((n, n_axles))
        cr = c[pick] if c.size else np.zeros((n, n_axles))

    # every channel of every sample against its range in one pass (NaN passes; an
    # infinity fails); which channel failed is worked out only for a rejected sample
    x = np.concatenate((wr, cr, acc[:, None], vref[:, None], mass[:, None]), axis=1)
    lo, hi = _sensor_bounds(n_axles)
    bad = (~np.isnan(x) & ~((x >= lo) & (x <= hi))).any(axis=1)
    bad |= ~good_axles | ~((t >= 0.0) & (t <= b.horizon_s))
    known = [index.get(name) is not None for name in ids]
    # rows of x (owned: the message's buffers are not kept)
    wl, cl = x[:, :n_axles], x[:, n_axles:2 * n_axles]
    if lists:
        wl, cl = wl.tolist(), cl.tolist()
    tl, al, vl = t.tolist(), acc.tolist(), vref.tolist()
    ml = np.where(np.isfinite(mass), mass, np.nan).tolist()
    badl, whichl = bad.tolist(), which.tolist()
    if rows is not None:
        full = np.empty((n, 4 + 2 * n_axles), dtype="<f8")
        full[:, 0] = t
        full[:, 1:1 + 2 * n_axles] = x[:, :2 * n_axles]
        full[:, -3] = acc
        full[:, -2] = vref
        full[:, -1] = np.where(np.isfinite(mass), mass, np.nan)
        data = full.tobytes()
        k = full.shape[1] * 8
        rows.extend([data[i:i + k] for i in range(0, n * k, k)])
    for s in range(n):
        j = whichl[s]
        tid = ids[j]
        if not known[j]:
            out.append((None, tl[s], Rejected("train_id", f"{topic}: train_id "
                                              f"{str(tid)[:40]!r} is not a train of the "
                                              "scenario")))
            continue
        if badl[s]:
            out.append((tid, tl[s], _sample_rejection(topic, s, int(axles[s]), n_axles,
                                                      tl[s], b, x[s])))
            continue
        out.append((tid, tl[s], {"t_s": tl[s], "omega": wl[s], "clamp": cl[s],
                                 "accel": al[s], "ref_speed": vl[s], "car_mass": ml[s]}))
    return out


_SENSOR_ORDER = ("wheel_angular_speed_radps", "clamp_force_n",
                 "longitudinal_acceleration_mps2", "reference_speed_mps", "car_mass_kg")
"""The channels in the order :func:`conv.sensor_from_msg` checks them."""


@functools.lru_cache(maxsize=8)
def _sensor_bounds(n_axles: int) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper bounds of a fleet sample's channels laid out as one row.

    The row: ``n_axles`` wheel speeds, ``n_axles`` clamp forces, acceleration, speed, mass.
    """
    counts = (n_axles, n_axles, 1, 1, 1)
    lo = np.repeat([conv.SENSOR_RANGES[k][0] for k in _SENSOR_ORDER], counts)
    hi = np.repeat([conv.SENSOR_RANGES[k][1] for k in _SENSOR_ORDER], counts)
    return lo, hi


def _sample_rejection(topic: str, s: int, axles: int, n_axles: int, t: float, b: Bounds,
                      row: np.ndarray) -> Rejected:
    """The rejection of sample ``s`` of a fleet message, in :func:`conv.sensor_from_msg`'s order.

    ``row``: the sample's channels as laid out by :func:`_sensor_bounds`.
    """
    if axles != n_axles:
        return Rejected("axles", f"{topic}: sample {s}: expected {n_axles} axles, got {axles}")
    try:
        check_time(f"{topic}.stamp_ns[{s}]", t, b)
    except Rejected as exc:
        return exc
    start = 0
    for name, k in zip(_SENSOR_ORDER, (n_axles, n_axles, 1, 1, 1)):
        lo, hi = conv.SENSOR_RANGES[name]
        for v in row[start:start + k].tolist():
            if v == v and not lo <= v <= hi:
                return Rejected("range", f"{topic}.{name}[{s}] outside [{lo:g}, {hi:g}]")
        start += k
    return Rejected("error", f"{topic}: sample {s} rejected")
