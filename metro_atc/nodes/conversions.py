"""All conversions between ROS messages and the ROS-free cores live here.

Incoming messages are validated here, by type and plausibility, with the rules of
:mod:`metro_atc.core.validate` (train id of the topic, finite numbers, ranges of the line
(:class:`~metro_atc.core.validate.Bounds`), lockstep step, header stamp consistent with the
message's own time); a bad message raises :class:`MessageRejected` (``kind`` names the rule,
the text the topic field), which the node counts per kind and logs (rate-limited) before
dropping the message.  Nothing else in a callback may raise: see
:func:`guarded` for the last line of defence.
"""

from __future__ import annotations

import array
import functools
import math
from typing import Any, Iterable, Mapping, Sequence

import numpy as np
from builtin_interfaces.msg import Time
from metro_atc_msgs.msg import (BrakeDiagnosis, BrakeSensorData, DepartureCommand,
                                FleetBrakeSensorData, FleetCommand, FleetState, LineStatus,
                                TractionCommand, TrainEvent, TrainState)
from rosgraph_msgs.msg import Clock

from metro_atc.core.atr.registry import REGULATORS
from metro_atc.core.validate import (Bounds, Rejected, StepWindow, check_finite, check_index,
                                     check_range, check_stamp, check_time)
from metro_atc.nodes import cdr

REGULATOR_CODES = {name: int(getattr(DepartureCommand, f"REGULATOR_{name.upper()}"))
                   for name in REGULATORS}
"""``DepartureCommand.regulator`` code of each regulator (constant ``REGULATOR_<NAME>``)."""


MessageRejected = Rejected
"""An incoming message failed validation (``kind``: the rule; text: the field)."""

MODES = range(TrainState.MODE_ATP_BRAKE + 1)
"""Defined TrainState.MODE_* codes (TractionCommand.mode uses the same)."""


def to_time(t_s: float) -> Time:
    """Simulation seconds -> builtin_interfaces/Time (rounded to the nanosecond)."""
    return set_stamp(Time(), t_s)


def set_stamp(stamp: Any, t_s: float) -> Any:
    """Set a builtin_interfaces/Time in place to ``t_s`` simulation seconds; return it.

    Rounded to the nanosecond (negative times clamp to 0), as :func:`stamps_ns` does.
    """
    ns = int(round(max(0.0, float(t_s)) * 1e9))
    stamp.sec, stamp.nanosec = divmod(ns, 1_000_000_000)
    return stamp


def from_time(t: Time) -> float:
    """builtin_interfaces/Time -> seconds."""
    return float(t.sec) + 1e-9 * float(t.nanosec)


def clock_msg(t_s: float) -> Clock:
    """A /clock message for simulation time t_s [s]."""
    return Clock(clock=to_time(t_s))


_finite = check_finite


def _train(msg: Any, topic: str, train_id: str) -> None:
    """The message's train_id is the topic's train (kind ``train_id``)."""
    if msg.train_id != train_id:
        shown = repr(str(msg.train_id)[:40])
        raise Rejected("train_id", f"{topic}: train_id {shown} does not match the topic "
                       f"('{train_id}')")


def train_index(train_id: str, index: Mapping[str, int], topic: str) -> int:
    """Index of a train id, or :class:`MessageRejected` naming the unknown id."""
    try:
        return index[train_id]
    except KeyError:
        raise Rejected("train_id", f"{topic}: unknown train_id {str(train_id)[:40]!r}") \
            from None


def traction_from_msg(msg: TractionCommand, topic: str, train_id: str, step: int,
                      t_s: float, late_echo: bool = False) -> float | None:
    """Validate the command of ``train_id`` for lockstep step ``step`` at time ``t_s``.

    Returns the effort in [-1, 1], or None for the previous step (a stale duplicate,
    ignored without counting).  Rejected: another train, another step, a stamp that is not
    the state's (``t_s``), a non-finite or out-of-range effort, an undefined mode.
    ``late_echo``: any earlier step is a stale duplicate too (the per-train copy of a
    command the simulator already took from the fleet command: another writer, so it may
    arrive steps late).
    """
    _train(msg, topic, train_id)
    effort = check_finite(f"{topic}.effort", msg.effort)
    effort = check_range(f"{topic}.effort", effort, -1.0 - 1e-9, 1.0 + 1e-9, "effort")
    check_index(f"{topic}.mode", msg.mode, 0, len(MODES) - 1, "mode")
    k = int(msg.step)
    if k == step - 1 or (late_echo and k < step):
        return None
    if k != step:
        raise Rejected("step", f"{topic}.step={k} is not the lockstep step {step}")
    check_stamp(topic, from_time(msg.header.stamp), t_s)
    return float(np.clip(effort, -1.0, 1.0))


def traction_msg(train_id: str, step: int, t_s: float, effort: float,
                 mode: int) -> TractionCommand:
    """Build a TractionCommand."""
    m = TractionCommand(train_id=train_id, step=int(step), effort=float(effort), mode=int(mode))
    m.header.stamp = to_time(t_s)
    m.header.frame_id = "line"
    return m


def departure_from_msg(msg: DepartureCommand, topic: str, train_id: str,
                       b: Bounds) -> tuple[int, float, float, float]:
    """Validate a DepartureCommand; return (station, departure_s, running_s, dwell_limit_s).

    The station is one a train departs from (not the terminus); the departure time is
    within the run's service (from the timetable's first departure to the horizon) and
    equals the header stamp (the ATS stamps its commands with the departure time); the
    running time is in [0, horizon]; ``dwell_limit_s`` is NaN (no
    dwell cut) or in [0, horizon]; the regulator code is defined.
    """
    _train(msg, topic, train_id)
    st = check_index(f"{topic}.station_index", msg.station_index, 0, b.n_stations - 2,
                     "station")
    dep = check_range(f"{topic}.departure_time_s", msg.departure_time_s, b.t_first_s,
                      b.horizon_s, "time")
    check_stamp(topic, from_time(msg.header.stamp), dep)
    run = check_range(f"{topic}.target_running_time_s", msg.target_running_time_s, 0.0,
                      b.horizon_s, "time")
    dwell = check_time(f"{topic}.dwell_limit_s", msg.dwell_limit_s, b, nan_ok=True)
    check_index(f"{topic}.regulator", msg.regulator, 0, max(REGULATOR_CODES.values()),
                "regulator")
    return st, dep, run, dwell


def departure_msg(train_id: str, station: int, departure_s: float, running_s: float,
                  dwell_limit_s: float, regulator: str, seq: int, stamp_s: float
                  ) -> DepartureCommand:
    """Build a DepartureCommand (``dwell_limit_s`` NaN: no dwell cut)."""
    m = DepartureCommand(train_id=train_id, station_index=int(station),
                         departure_time_s=float(departure_s),
                         target_running_time_s=float(running_s),
                         dwell_limit_s=float(dwell_limit_s),
                         regulator=REGULATOR_CODES.get(regulator, 0), sequence=int(seq))
    m.header.stamp = to_time(stamp_s)
    m.header.frame_id = "line"
    return m


def state_msgs(train_ids: Sequence[str], idx: Iterable[int], states: Mapping[str, np.ndarray],
               step: int, t_s: float) -> list[tuple[int, TrainState]]:
    """TrainState messages for the trains in ``idx`` from the core's state arrays."""
    stamp = to_time(t_s)
    out = []
    g = states.get
    for i in idx:
        m = TrainState()
        m.header.stamp = stamp
        m.header.frame_id = "line"
        m.train_id = train_ids[i]
        m.step = int(step)
        m.position_m = float(states["x_m"][i])
        m.speed_mps = float(states["v_mps"][i])
        m.acceleration_mps2 = float(states["a_mps2"][i])
        m.current_station = int(states["current_station"][i])
        m.next_station = int(states["next_station"][i])
        m.mode = int(states["mode"][i])
        m.departure_time_s = float(states["departure_time_s"][i])
        m.target_running_time_s = float(states["target_running_time_s"][i])
        lim = g("atp_limit_mps")
        m.supervision_speed_mps = float(lim[i]) if lim is not None else math.nan
        ma = g("movement_authority_m")
        m.movement_authority_m = float(ma[i]) if ma is not None else math.nan
        ai = g("atp_interventions")
        m.atp_interventions = int(ai[i]) if ai is not None else 0
        m.traction_energy_j = float(states["traction_energy_j"][i])
        m.regenerated_energy_j = float(states["regen_energy_j"][i])
        out.append((i, m))
    return out


def state_from_msg(msg: TrainState, topic: str, train_id: str, b: Bounds,
                   steps: StepWindow) -> dict[str, Any]:
    """Validate a TrainState; return a plain dict of its fields (``again``: a re-send).

    Every field is checked before the step window moves: the stamp is ``step x control
    period`` (the simulator's clock), positions and the movement authority are on the
    gridded line (the authority may be +inf: nothing ahead), speeds below ``v_max``,
    station indices on the line (-1 allowed where the message defines it), the mode
    defined; departure and running times are NaN (not set) or within the horizon.
    """
    _train(msg, topic, train_id)
    t = from_time(msg.header.stamp)
    k = int(msg.step)
    check_stamp(topic, t, k * b.control_period_s)
    check_time(f"{topic}.header.stamp", t, b)
    n = b.n_stations - 1
    out = {"step": k, "t_s": t,
           "x_m": check_range(f"{topic}.position_m", msg.position_m, b.x_min_m, b.x_max_m,
                              "position"),
           "v_mps": check_range(f"{topic}.speed_mps", msg.speed_mps, 0.0, b.v_max_mps,
                                "speed"),
           "a_mps2": check_range(f"{topic}.acceleration_mps2", msg.acceleration_mps2,
                                 -b.a_max_mps2, b.a_max_mps2, "acceleration"),
           "current_station": check_index(f"{topic}.current_station", msg.current_station,
                                          -1, n, "station"),
           "next_station": check_index(f"{topic}.next_station", msg.next_station, -1, n,
                                       "station"),
           "mode": check_index(f"{topic}.mode", msg.mode, 0, len(MODES) - 1, "mode"),
           "departure_time_s": check_time(f"{topic}.departure_time_s", msg.departure_time_s,
                                          b, nan_ok=True),
           "target_running_time_s": check_time(f"{topic}.target_running_time_s",
                                               msg.target_running_time_s, b, nan_ok=True),
           "supervision_speed_mps": check_range(f"{topic}.supervision_speed_mps",
                                                msg.supervision_speed_mps, 0.0, b.v_max_mps,
                                                "speed"),
           "movement_authority_m": _authority(f"{topic}.movement_authority_m",
                                              msg.movement_authority_m, b)}
    out["again"] = steps.accept(k, f"{topic}.step") == "again"
    return out


def _authority(name: str, value: float, b: Bounds) -> float:
    """End of authority: on the line, or +inf (nothing ahead)."""
    v = float(value)
    if v == math.inf:
        return v
    return check_range(name, v, b.x_min_m, b.x_max_m, "position")


def event_msg(ev: Any, train_ids: Sequence[str], station_names: Sequence[str],
              seq: int) -> TrainEvent:
    """TrainEvent message from a core event (``metro_atc.core.plant`` TrainEvent)."""
    m = TrainEvent()
    m.header.stamp = to_time(ev.t_s)
    m.header.frame_id = "line"
    m.train_id = train_ids[ev.train_idx]
    m.kind = TrainEvent.KIND_ARRIVAL if ev.kind == "arrival" else TrainEvent.KIND_DEPARTURE
    m.station_index = int(ev.station_idx)
    m.station_name = str(station_names[ev.station_idx])
    m.actual_time_s = float(ev.t_s)
    m.scheduled_time_s = float(ev.t_s - getattr(ev, "delay_s", 0.0))
    m.passengers_boarded = int(max(0, getattr(ev, "boarded", 0)))
    m.passengers_alighted = int(max(0, getattr(ev, "alighted", 0)))
    m.dwell_s = float(getattr(ev, "dwell_s", 0.0))
    m.sequence = int(seq)
    return m


def event_from_msg(msg: TrainEvent, topic: str, index: Mapping[str, int], b: Bounds,
                   last_seq: Mapping[str, int]) -> dict[str, Any]:
    """Validate a TrainEvent; return a plain dict.

    The train is one of the line, the kind defined, the station on the line, the actual
    time after the first step and within the horizon, and equal to the header stamp (the
    simulator stamps an event with its time), the sequence the next one of the train
    (``last_seq``: the last accepted per train; events of a train are numbered 1, 2, ...
    without gaps), times finite.
    """
    train_index(msg.train_id, index, topic)
    if msg.kind not in (TrainEvent.KIND_ARRIVAL, TrainEvent.KIND_DEPARTURE):
        raise Rejected("kind", f"{topic}.kind={msg.kind} is not ARRIVAL(1) or DEPARTURE(2)")
    st = check_index(f"{topic}.station_index", msg.station_index, 0, b.n_stations - 1,
                     "station")
    t = check_range(f"{topic}.actual_time_s", msg.actual_time_s, b.control_period_s,
                    b.horizon_s, "time")
    check_stamp(topic, from_time(msg.header.stamp), t)
    seq = int(msg.sequence)
    want = int(last_seq.get(msg.train_id, 0)) + 1
    if seq != want:
        raise Rejected("sequence", f"{topic}: {msg.train_id} event sequence {seq} out of order "
                       f"(expected {want})")
    return {"train_id": msg.train_id,
            "kind": "arrival" if msg.kind == TrainEvent.KIND_ARRIVAL else "departure",
            "station": st, "t_s": t,
            "scheduled_s": check_range(f"{topic}.scheduled_time_s", msg.scheduled_time_s,
                                       -b.horizon_s, b.horizon_s, "time"),
            "sequence": seq,
            "dwell_s": check_time(f"{topic}.dwell_s", msg.dwell_s, b)}


def sensor_msg(s: Any, train_ids: Sequence[str]) -> BrakeSensorData:
    """BrakeSensorData from a core BrakeSensorSample (NaN channels pass through: dropouts)."""
    return sensor_sample_msg(train_ids[s.train_idx], float(s.t_s), s.wheel_omega_radps,
                             s.clamp_force_n, float(s.accel_x_mps2), float(s.ref_speed_mps),
                             float(getattr(s, "car_mass_kg", math.nan)))


def sensor_sample_msg(train_id: str, t_s: float, omega_radps: Any, clamp_n: Any,
                      accel_mps2: float, ref_speed_mps: float, car_mass_kg: float
                      ) -> BrakeSensorData:
    """BrakeSensorData of one sample of the instrumented car.

    Time [s], per-axle wheel speeds [rad/s] and clamp forces [N], acceleration [m/s^2],
    reference speed [m/s], car mass [kg] (NaN: none).
    The per-axle arrays go in as ``array('d')`` built from the float64 buffer (no per-value
    Python loop: the simulator builds ~20 samples per simulated second per braking train).
    """
    m = BrakeSensorData()
    m.header.frame_id = "line"
    m.train_id = train_id
    return fill_sensor_msg(m, t_s, omega_radps, clamp_n, accel_mps2, ref_speed_mps,
                           car_mass_kg)


def fill_sensor_msg(m: BrakeSensorData, t_s: float, omega_radps: Any, clamp_n: Any,
                    accel_mps2: float, ref_speed_mps: float, car_mass_kg: float
                    ) -> BrakeSensorData:
    """Set the sample fields of ``m`` (train id and frame kept); return ``m``.

    Same values as :func:`sensor_sample_msg`; the simulator refills one message per train
    (building a message with its header and stamp objects cost more than publishing it).
    """
    set_stamp(m.header.stamp, t_s)
    m.wheel_angular_speed_radps = doubles(omega_radps)
    m.clamp_force_n = doubles(clamp_n)
    m.longitudinal_acceleration_mps2 = float(accel_mps2)
    m.reference_speed_mps = float(ref_speed_mps)
    m.car_mass_kg = float(car_mass_kg)
    return m


def doubles(values: Any) -> "array.array[float]":
    """A float64 ``array('d')`` of ``values`` (a numpy array is copied as one buffer)."""
    if isinstance(values, array.array) and values.typecode == "d":
        return values
    return array.array("d", np.ascontiguousarray(values, dtype=np.float64).tobytes())


SENSOR_RANGES = {"wheel_angular_speed_radps": (-50.0, 1000.0),
                 "clamp_force_n": (-1e5, 1e6),
                 "longitudinal_acceleration_mps2": (-50.0, 50.0),
                 "reference_speed_mps": (-5.0, 150.0),
                 "car_mass_kg": (1e3, 1e6)}
"""Plausible range of each finite sensor channel (beyond: the sample is rejected)."""


def sensor_from_msg(msg: BrakeSensorData, topic: str, train_id: str, n_axles: int,
                    b: Bounds) -> dict[str, Any]:
    """Validate a BrakeSensorData; return its channels as a plain dict.

    Rejected: another train; a wrong number of axles; a stamp outside the run's horizon
    (a sample from the future within the horizon is handled by the receiver's
    out-of-order resynchronisation, see ``TrainBrakeWatch``); a finite channel value
    outside ``SENSOR_RANGES``.  Non-finite channel values are allowed (dropouts: the
    observer does not use them); ``car_mass`` is NaN when the load-weigh signal is missing.
    """
    _train(msg, topic, train_id)
    w = np.asarray(msg.wheel_angular_speed_radps, dtype=float)
    c = np.asarray(msg.clamp_force_n, dtype=float)
    if w.shape != (n_axles,) or c.shape != (n_axles,):
        raise Rejected("axles", f"{topic}: expected {n_axles} axles, got "
                       f"wheel_angular_speed_radps[{w.size}], clamp_force_n[{c.size}]")
    t = check_time(f"{topic}.header.stamp", from_time(msg.header.stamp), b)
    vals: dict[str, Any] = {"wheel_angular_speed_radps": w, "clamp_force_n": c,
                            "longitudinal_acceleration_mps2":
                                float(msg.longitudinal_acceleration_mps2),
                            "reference_speed_mps": float(msg.reference_speed_mps),
                            "car_mass_kg": float(msg.car_mass_kg)}
    for name, v in vals.items():
        lo, hi = SENSOR_RANGES[name]
        # plain floats (4 axles, 20 samples per simulated second per braking train: numpy's
        # per-call overhead was most of the node's per-sample time, issue 13); NaN passes
        for x in (v.tolist() if isinstance(v, np.ndarray) else (v,)):
            if x == x and not lo <= x <= hi:  # an infinity fails the range as well
                raise Rejected("range", f"{topic}.{name} outside [{lo:g}, {hi:g}]")
    mass = float(vals["car_mass_kg"])
    return {"t_s": t, "omega": w, "clamp": c,
            "accel": vals["longitudinal_acceleration_mps2"],
            "ref_speed": vals["reference_speed_mps"],
            "car_mass": mass if math.isfinite(mass) else math.nan}


FLEET_SENSOR_MAX_SAMPLES = 10_000
"""Most samples one FleetBrakeSensorData may carry (beyond: the message is rejected, kind
``length``); a step of the largest line has a few hundred, a re-sent batch fewer."""
FLEET_SENSOR_MAX_AXLES = 64
"""Most axles a sample of a FleetBrakeSensorData may declare (beyond: kind ``length``)."""


def _ints(values: Any, typecode: str, dtype: Any) -> "array.array[int]":
    """An ``array(typecode)`` of ``values`` copied as one buffer (see :func:`doubles`)."""
    return array.array(typecode, np.ascontiguousarray(values, dtype=dtype).tobytes())


def stamps_ns(t_s: Any) -> np.ndarray:
    """Simulation times [s] -> int64 nanoseconds, as :func:`to_time` rounds them."""
    return np.round(np.maximum(np.asarray(t_s, dtype=np.float64), 0.0) * 1e9).astype(np.int64)


def seconds_of_ns(ns: np.ndarray) -> np.ndarray:
    """int64 nanoseconds -> seconds, the same floats as :func:`from_time` of the Time."""
    ns = np.asarray(ns, dtype=np.int64)
    return (ns // 1_000_000_000).astype(np.float64) + 1e-9 * (ns % 1_000_000_000).astype(
        np.float64)


def fleet_sensor_msg(train_ids: Sequence[str], t_step_s: float, trains: Any,
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
    set_stamp(m.header.stamp, t_step_s)
    m.train_id = list(train_ids)
    w = np.asarray(omega_radps, dtype=np.float64)
    n = len(t_s)
    axles = w.size // n if n else 0
    m.sample_train = _ints(trains, "I", np.uint32)
    m.stamp_ns = _ints(stamps_ns(t_s), "q", np.int64)
    m.axle_count = _ints(np.full(n, axles), "I", np.uint32)
    m.wheel_angular_speed_radps = doubles(w)
    m.clamp_force_n = doubles(clamp_n)
    m.longitudinal_acceleration_mps2 = doubles(accel_mps2)
    m.reference_speed_mps = doubles(ref_speed_mps)
    m.car_mass_kg = doubles(car_mass_kg)
    return m


def _f64(values: Any) -> np.ndarray:
    """A float64 array of a message's float64[] field (its buffer, no per-value loop)."""
    if isinstance(values, array.array) and values.typecode == "d":
        return np.frombuffer(values, dtype=np.float64) if len(values) else np.zeros(0)
    return np.asarray(values, dtype=np.float64).reshape(-1)


def fleet_sensor_samples(msg: FleetBrakeSensorData, topic: str, index: Mapping[str, int],
                         n_axles: int, b: Bounds, lists: bool = False,
                         rows: list[bytes] | None = None
                         ) -> list[tuple[str | None, float, dict[str, Any] | Rejected]]:
    """Validate a FleetBrakeSensorData; return per sample ``(train, stamp, sample)``.

    The message as a whole is rejected (raises :class:`MessageRejected`, kind ``length``)
    when its arrays disagree in length, a ``sample_train`` index points outside
    ``train_id``, it carries more than :data:`FLEET_SENSOR_MAX_SAMPLES` samples or a sample
    declares more than :data:`FLEET_SENSOR_MAX_AXLES` axles: nothing in it can be attributed
    to a train.  Otherwise each sample is checked on its own, with the rules and kinds of
    :func:`sensor_from_msg` (a wrong number of axles, a stamp outside the run's horizon, a
    finite channel outside ``SENSOR_RANGES``); its entry is then the
    :class:`MessageRejected` instead of the sample dict.  A sample of a train not in
    ``index`` comes back with train ``None`` and a rejection of kind ``train_id``.
    ``stamp`` is the sample's stamp [s] (also of a rejected one: a receiver acknowledges
    those too).  The sample dicts are those of :func:`sensor_from_msg` (``omega``, ``clamp``
    float arrays of ``n_axles``; ``car_mass`` NaN when not finite).  With ``lists`` they
    are float lists instead (a sample dict is then its own JSON round trip: the
    ``brake_diagnostic`` node journals it as it is, issue 13).  ``rows``: a list that gets
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
    if n > FLEET_SENSOR_MAX_SAMPLES:
        raise Rejected("length", f"{topic}: {n} samples (at most {FLEET_SENSOR_MAX_SAMPLES})")
    if not (which.size == axles.size == acc.size == vref.size == mass.size == n):
        raise Rejected("length", f"{topic}: per-sample arrays of different lengths "
                       f"(stamp_ns[{n}], sample_train[{which.size}], axle_count[{axles.size}],"
                       f" channels [{acc.size}, {vref.size}, {mass.size}])")
    if n and (which.min() < 0 or which.max() >= len(ids)):
        raise Rejected("length", f"{topic}: sample_train outside train_id[{len(ids)}]")
    if n and axles.max() > FLEET_SENSOR_MAX_AXLES:
        raise Rejected("length", f"{topic}: a sample declares {int(axles.max())} axles (at "
                       f"most {FLEET_SENSOR_MAX_AXLES})")
    total = int(axles.sum())
    if w.size != total or c.size != total:
        raise Rejected("length", f"{topic}: per-axle arrays wheel_angular_speed_radps"
                       f"[{w.size}], clamp_force_n[{c.size}] do not hold the {total} axle "
                       "values of axle_count")
    out: list[tuple[str | None, float, dict[str, Any] | Rejected]] = []
    if n == 0:
        return out
    t = seconds_of_ns(ns)
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
"""The channels in the order :func:`sensor_from_msg` checks them."""


@functools.lru_cache(maxsize=8)
def _sensor_bounds(n_axles: int) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper bounds of a fleet sample's channels laid out as one row.

    The row: ``n_axles`` wheel speeds, ``n_axles`` clamp forces, acceleration, speed, mass.
    """
    counts = (n_axles, n_axles, 1, 1, 1)
    lo = np.repeat([SENSOR_RANGES[k][0] for k in _SENSOR_ORDER], counts)
    hi = np.repeat([SENSOR_RANGES[k][1] for k in _SENSOR_ORDER], counts)
    return lo, hi


def _sample_rejection(topic: str, s: int, axles: int, n_axles: int, t: float, b: Bounds,
                      row: np.ndarray) -> Rejected:
    """The rejection of sample ``s`` of a fleet message, in :func:`sensor_from_msg`'s order.

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
        lo, hi = SENSOR_RANGES[name]
        for v in row[start:start + k].tolist():
            if v == v and not lo <= v <= hi:
                return Rejected("range", f"{topic}.{name}[{s}] outside [{lo:g}, {hi:g}]")
        start += k
    return Rejected("error", f"{topic}: sample {s} rejected")


def guarded(what: str, fn: Any, *args: Any) -> Any:
    """Call ``fn(*args)``; turn any exception into :class:`MessageRejected` (kind ``error``).

    The last line of defence of a subscription callback: the rules above should reject a
    bad message first; if one slips through and the core raises, the message is dropped
    and counted instead of killing the node.
    """
    try:
        return fn(*args)
    except Rejected:
        raise
    except Exception as exc:  # noqa: BLE001 - a callback must never raise out of a node
        text = " ".join(str(exc).split())[:120]
        raise Rejected("error", f"{what}: {type(exc).__name__}: {text}") from None


def diagnosis_msg(train_id: str, stamp_s: float, d: Any, level: int, message: str,
                  used: int, rejected: int) -> BrakeDiagnosis:
    """BrakeDiagnosis from a core ``DiagnosisResult`` (metro_atc.core.brake.metro_car).

    ``level``/``message`` are the node's (they may add data-quality warnings to the
    observer's verdict); ``used``/``rejected`` are the sample counters.  Forces are on the
    car, negative while braking [N]; non-finite numbers are replaced by 0 (never NaN out).
    """
    m = BrakeDiagnosis()
    m.header.stamp = to_time(stamp_s)
    m.header.frame_id = "line"
    m.train_id = train_id
    m.friction_coefficient = _float(d.mu_b, 0.0)
    m.friction_coefficient_std = _float(d.mu_b_std, 0.0)
    m.longitudinal_force_n = [_float(x, 0.0) for x in d.forces]
    m.force_residual_n = [_float(x, 0.0) for x in d.residual_forces]
    m.pad_flaw = bool(d.pad_flaw)
    m.axle_flaw = [bool(x) for x in d.wheel_flaw]
    m.level = int(level)
    m.message = str(message)
    m.measurements_used = int(max(used, 0))
    m.measurements_rejected = int(max(rejected, 0))
    return m


def diagnosis_ack_s(msg: BrakeDiagnosis, topic: str, train_id: str, b: Bounds) -> float:
    """The newest sample a BrakeDiagnosis acknowledges: its stamp [s] (simulated time).

    ``brake_diagnostic`` stamps each train's diagnosis with the train's newest sample (0
    before any); the simulator keeps the samples after it for a restarted diagnosis.
    Rejected: another train, a stamp outside the run's horizon.
    """
    _train(msg, topic, train_id)
    return check_time(f"{topic}.header.stamp", from_time(msg.header.stamp), b)


def line_status_msg(k: Mapping[str, Any], step: int, t_s: float, finished: bool) -> LineStatus:
    """LineStatus from the simulator's KPI dict."""
    m = LineStatus()
    m.header.stamp = to_time(t_s)
    m.header.frame_id = "line"
    m.step = int(step)
    m.sim_time_s = float(t_s)
    m.trains = _int(k.get("trains"))
    m.trains_in_service = _int(k.get("trains_in_service"))
    m.completed_trains = _int(k.get("completed_trains"))
    m.atp_interventions = _int(k.get("atp_interventions"))
    m.atp_violations = _int(k.get("atp_violations"))
    m.min_separation_m = _float(k.get("min_separation_m"), -1.0)
    m.energy_kwh = _float(k.get("energy_kwh"), 0.0)
    m.max_delay_s = _float(k.get("max_delay_s"), 0.0)
    m.lockstep_misses = _int(k.get("lockstep_misses"))
    m.finished = bool(finished)
    return m


def _int(v: Any) -> int:
    """KPI value as int (None -> 0)."""
    return int(v) if v is not None else 0


def _float(v: Any, missing: float) -> float:
    """KPI value as a finite float (None/inf/NaN -> ``missing``)."""
    if v is None:
        return missing
    f = float(v)
    return f if math.isfinite(f) else missing


# ------------------------------------------------------------------ fleet lockstep (issue 13)
FLEET_STATE_FIELDS = ("position_m", "speed_mps", "acceleration_mps2", "current_station",
                      "next_station", "mode", "departure_time_s", "target_running_time_s",
                      "supervision_speed_mps", "movement_authority_m")
"""Per-train arrays of a FleetState (TrainState fields of the same names)."""

_FLEET_STATE_KEYS = ("x_m", "v_mps", "a_mps2", "current_station", "next_station", "mode",
                     "departure_time_s", "target_running_time_s", "atp_limit_mps",
                     "movement_authority_m")
"""Core state keys of :data:`FLEET_STATE_FIELDS`, in order."""


def fleet_state_msg(train_ids: Sequence[str], idx: "Sequence[int] | np.ndarray",
                    states: Mapping[str, np.ndarray], step: int, t_s: float,
                    echo: "Sequence[bool] | np.ndarray | None" = None) -> FleetState:
    """One FleetState of the trains ``idx`` (same values as :func:`state_msgs`).

    ``echo`` (per entry of ``idx``): the per-train state was published too this step.
    """
    m = FleetState()
    m.header.stamp = to_time(t_s)
    m.header.frame_id = "line"
    m.step = int(step)
    ix = np.asarray(idx, dtype=np.intp)
    m.train_id = [train_ids[i] for i in ix]
    n = ix.size
    # whole arrays as array('d'/'i'/'B') buffers: no per-value Python loop here, and the
    # C conversion of the publish copies them as buffers (issue 13)
    for field, key in zip(FLEET_STATE_FIELDS, _FLEET_STATE_KEYS):
        a = states.get(key)
        if field in ("current_station", "next_station"):
            setattr(m, field, array.array("i", np.asarray(a, dtype=np.int32)[ix].tobytes()))
        elif field == "mode":
            setattr(m, field, array.array("B", np.asarray(a, dtype=np.uint8)[ix].tobytes()))
        elif a is None:
            setattr(m, field, array.array("d", [math.nan]) * n)
        else:
            setattr(m, field, doubles(np.asarray(a, dtype=np.float64)[ix]))
    m.echo = [False] * n if echo is None else [bool(x) for x in echo]
    return m


def fleet_state_cdr(builder: cdr.FleetStateBuilder, idx: np.ndarray,
                    states: Mapping[str, np.ndarray], step: int, t_s: float,
                    echo: np.ndarray) -> bytes:
    """The serialized FleetState of the trains ``idx`` (:mod:`metro_atc.nodes.cdr`).

    The values of :func:`fleet_state_msg` (same fields, same conversions), built without
    a message object (issue 13: the simulator publishes it every step).  ``builder``: the
    layout of the train ids of ``idx`` (:class:`cdr.FleetStateBuilder`); ``echo`` per entry
    of ``idx``.
    """
    rows = {}
    for key in _FLEET_STATE_KEYS:
        a = states.get(key)
        if a is not None:
            rows[key] = np.asarray(a)[idx]
    return fleet_state_rows_cdr(builder, idx.size, rows, step, t_s, echo)


def fleet_state_rows_cdr(builder: cdr.FleetStateBuilder, n: int,
                         rows: Mapping[str, np.ndarray], step: int, t_s: float,
                         echo: np.ndarray) -> bytes:
    """:func:`fleet_state_cdr` of state arrays taken at its ``n`` trains already.

    ``rows``: the core state arrays of the trains of the message, entry by entry (e.g.
    :func:`metro_atc.core.plant.views.fleet_state_rows`); a key missing is NaN.
    """
    arrays: list[Any] = []
    for key in _FLEET_STATE_KEYS:
        a = rows.get(key)
        arrays.append(math.nan if a is None else a)
    arrays.append(np.asarray(echo, dtype=bool))
    if builder.n != n:
        raise ValueError(f"a FleetState layout of {builder.n} trains for {n}")
    return builder.build(t_s, step, arrays)


class _Entry:
    """One train of a fleet message seen as a per-train message (for the per-train rules)."""

    def __init__(self, header: Any, step: int, train_id: str, **fields: Any) -> None:
        self.header = header
        self.step = step
        self.train_id = train_id
        self.__dict__.update(fields)


def _fleet_arrays(msg: Any, topic: str, fields: Sequence[str]) -> list[Any]:
    """The per-train arrays of a fleet message, all as long as ``train_id`` (kind ``shape``)."""
    n = len(msg.train_id)
    out = []
    for f in fields:
        a = getattr(msg, f)
        if len(a) != n:
            raise Rejected("shape", f"{topic}.{f} has {len(a)} values for {n} trains")
        out.append(list(a))
    if len(set(msg.train_id)) != n:
        raise Rejected("train_id", f"{topic}: a train is listed more than once")
    return out


def fleet_state_entries(msg: FleetState, topic: str,
                        hosted: Mapping[str, Any]) -> list[tuple[str, Any]]:
    """The entries of a FleetState for the ``hosted`` trains, as TrainState-like views.

    The message's shape is checked here (every array as long as ``train_id``, no train
    twice: kind ``shape`` / ``train_id``); each entry is then validated by the receiver with
    :func:`state_from_msg`, exactly as a ``/<train>/state`` message (``echo``: a bool).
    """
    arrays = _fleet_arrays(msg, topic, FLEET_STATE_FIELDS + ("echo",))
    out = []
    for j, tid in enumerate(msg.train_id):
        if tid in hosted:
            vals = {f: a[j] for f, a in zip(FLEET_STATE_FIELDS + ("echo",), arrays)}
            vals["echo"] = bool(vals["echo"])
            mode = vals["mode"]
            vals["mode"] = mode[0] if isinstance(mode, bytes) else int(mode)
            out.append((tid, _Entry(msg.header, msg.step, tid, **vals)))
    return out


def fleet_command_msg(step: int, t_s: float, train_ids: Sequence[str], efforts: Sequence[float],
                      modes: Sequence[int]) -> FleetCommand:
    """One FleetCommand (the commands of one ATO process for step ``step``)."""
    m = FleetCommand()
    m.header.stamp = to_time(t_s)
    m.header.frame_id = "line"
    m.step = int(step)
    m.train_id = list(train_ids)
    m.effort = [float(u) for u in efforts]
    m.mode = [int(x) for x in modes]
    return m


def fleet_command_entries(msg: FleetCommand, topic: str,
                          index: Mapping[str, int]) -> list[tuple[int, Any]]:
    """The entries of a FleetCommand as (train index, TractionCommand-like view).

    Checked here: the shape (kind ``shape`` / ``train_id``) and that every train is one of
    ``index`` (kind ``train_id``); each entry is then validated by the receiver with
    :func:`traction_from_msg`, exactly as a ``/<train>/command`` message.
    """
    effort, mode = _fleet_arrays(msg, topic, ("effort", "mode"))
    out = []
    for j, tid in enumerate(msg.train_id):
        i = train_index(tid, index, topic)
        md = mode[j]
        out.append((i, _Entry(msg.header, msg.step, tid, effort=effort[j],
                              mode=md[0] if isinstance(md, bytes) else int(md))))
    return out


def fleet_command_efforts(msg: FleetCommand, topic: str, index: Mapping[str, int], step: int,
                          t_s: float) -> tuple[np.ndarray, np.ndarray | None] | None:
    """A FleetCommand validated as a whole, for lockstep step ``step`` at time ``t_s``.

    The simulator's fast path (issue 13): ``(train indices, efforts)`` when every entry
    passes :func:`traction_from_msg` (with ``late_echo``) as it would one by one, ``efforts``
    None for a command of an earlier step (stale duplicates, dropped without counting);
    None when some entry breaks a per-entry rule (effort, mode, step, stamp): the caller
    then validates entry by entry (:func:`fleet_command_entries`), which counts every
    rejected entry.  The message's shape and trains are checked here as there (kinds
    ``shape`` / ``train_id``, raised for the whole message).
    """
    effort, mode = _fleet_arrays(msg, topic, ("effort", "mode"))
    ix = np.fromiter((train_index(tid, index, topic) for tid in msg.train_id),
                     dtype=np.intp, count=len(msg.train_id))
    e = np.asarray(effort, dtype=np.float64)
    md = np.asarray([x[0] if isinstance(x, bytes) else int(x) for x in mode], dtype=np.int64)
    ok = bool(np.all(np.isfinite(e)) and np.all(np.abs(e) <= 1.0 + 1e-9)
              and np.all((md >= 0) & (md <= len(MODES) - 1)))
    if not ok:
        return None
    k = int(msg.step)
    if k < step:
        return ix, None
    if k != step:
        return None
    try:
        check_stamp(topic, from_time(msg.header.stamp), t_s)
    except Rejected:
        return None
    return ix, np.clip(e, -1.0, 1.0)


FALLBACK = None
"""What :func:`fleet_command_efforts_cdr` returns when the message must take the slow path."""


def fleet_command_efforts_cdr(data: bytes, topic: str, index: dict[bytes, int],
                              ix_cache: dict[tuple[bytes, ...], np.ndarray], step: int,
                              t_s: float) -> tuple[np.ndarray, np.ndarray | None] | None:
    """:func:`fleet_command_efforts` of a serialized FleetCommand (a raw subscription).

    ``index``: train id (UTF-8 bytes) -> train index; ``ix_cache``: the train indices of
    each train id list seen (filled here; the caller bounds it).  Returns what
    :func:`fleet_command_efforts` returns for a message all of whose entries pass, and
    :data:`FALLBACK` (None) for anything else: bytes that are not a well-formed FleetCommand
    (:mod:`metro_atc.nodes.cdr`), arrays of unequal lengths, an unknown or repeated train,
    an entry breaking a per-entry rule; the caller then deserializes the message and takes
    the object path, which rejects and counts exactly as for a message object.  Never
    raises.
    """
    m = cdr.read_fleet_command(data)
    if m is None:
        return FALLBACK
    n = len(m.train_id_raw)
    if m.effort.size != n or m.mode.size != n:
        return FALLBACK
    ix = ix_cache.get(m.train_id_raw)
    if ix is None:
        got = [index.get(b, -1) for b in m.train_id_raw]
        if min(got, default=0) < 0 or len(set(got)) != n:
            return FALLBACK
        ix = ix_cache[m.train_id_raw] = np.array(got, dtype=np.intp)
    e = m.effort
    # the largest |effort| is NaN when any is (NaN fails the comparison), inf when any is
    if n and not (float(np.abs(e).max()) <= 1.0 + 1e-9 and int(m.mode.max()) <= len(MODES) - 1):
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


def fleet_states_checked(msg: FleetState, topic: str, hosted: Mapping[str, Any],
                         b: Bounds) -> list[tuple[str, dict[str, Any], bool]] | None:
    """The hosted entries of a FleetState as validated state dicts, in one pass.

    The fast path of :func:`fleet_state_entries` + :func:`state_from_msg` (issue 13): the
    message's shape and every rule of :func:`state_from_msg` except the step window are
    checked entry by entry without building a view per entry; the dicts are those
    :func:`state_from_msg` returns, field for field (without ``again``, which the
    receiver's step window sets).  None when anything fails (a NaN fails every range): the
    caller then takes the per-entry path, which rejects exactly as before.  Returns
    (train id, state, echo) in the order of the message.
    """
    try:
        ids = msg.train_id
        n = len(ids)
        arrays = [getattr(msg, f) for f in FLEET_STATE_FIELDS]
        echo = msg.echo
        for a in arrays:  # a loop: no generator per message (issue 13)
            if len(a) != n:
                return None
        if len(echo) != n or len(set(ids)) != n:
            return None
        rows = [j for j, tid in enumerate(ids) if tid in hosted]
        if not rows:
            return []
        t = from_time(msg.header.stamp)
        k = int(msg.step)
        check_stamp(topic, t, k * b.control_period_s)
        check_time(f"{topic}.header.stamp", t, b)
    except (Rejected, TypeError, ValueError, AttributeError):
        return None
    xs, vs, accs, curs, nxts, modes, deps, tgts, sups, mas = arrays
    x0, x1, vmax, amax, hor = b.x_min_m, b.x_max_m, b.v_max_mps, b.a_max_mps2, b.horizon_s
    last, mmax = b.n_stations - 1, len(MODES) - 1
    out = []
    for j in rows:
        x, v, a, cur, nxt, md = xs[j], vs[j], accs[j], curs[j], nxts[j], modes[j]
        dep, tgt, sup, ma = deps[j], tgts[j], sups[j], mas[j]
        if isinstance(md, bytes):
            md = md[0]
        if not (type(x) is float and type(v) is float and type(a) is float  # noqa: E721
                and type(dep) is float and type(tgt) is float and type(sup) is float
                and type(ma) is float and type(cur) is int and type(nxt) is int
                and type(md) is int
                and x0 <= x <= x1 and 0.0 <= v <= vmax and -amax <= a <= amax
                and -1 <= cur <= last and -1 <= nxt <= last and 0 <= md <= mmax
                and (dep != dep or 0.0 <= dep <= hor) and (tgt != tgt or 0.0 <= tgt <= hor)
                and 0.0 <= sup <= vmax and (ma == math.inf or x0 <= ma <= x1)):
            return None
        out.append((ids[j], {"step": k, "t_s": t, "x_m": x, "v_mps": v, "a_mps2": a,
                             "current_station": cur, "next_station": nxt, "mode": md,
                             "departure_time_s": dep, "target_running_time_s": tgt,
                             "supervision_speed_mps": sup, "movement_authority_m": ma},
                    bool(echo[j])))
    return out
