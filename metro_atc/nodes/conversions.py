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
import math
from typing import Any, Iterable, Mapping, Sequence

import numpy as np
from builtin_interfaces.msg import Time
from metro_atc_msgs.msg import (BrakeDiagnosis, BrakeSensorData, DepartureCommand, LineStatus,
                                TractionCommand, TrainEvent, TrainState)
from rosgraph_msgs.msg import Clock

from metro_atc.core.atr.registry import REGULATORS
from metro_atc.core.validate import (Bounds, Rejected, StepWindow, check_finite, check_index,
                                     check_range, check_stamp, check_time)

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
        mass = g("mass_kg")
        m.mass_kg = float(mass[i]) if mass is not None else math.nan
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
                                              msg.movement_authority_m, b),
           "mass_kg": _mass(f"{topic}.mass_kg", msg.mass_kg)}
    out["again"] = steps.accept(k, f"{topic}.step") == "again"
    return out


MASS_MIN_KG, MASS_MAX_KG = 1e3, 1e7
"""Range of a train's load-weigh mass [kg] (NaN: no signal)."""


def _mass(name: str, value: float) -> float:
    """Load-weigh mass of a train [kg]: NaN (no signal) or in the mass range."""
    v = float(value)
    if v != v:
        return v
    return check_range(name, v, MASS_MIN_KG, MASS_MAX_KG, "mass")


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
        # per-call overhead was most of the node's per-sample time); NaN passes
        for x in (v.tolist() if isinstance(v, np.ndarray) else (v,)):
            if x == x and not lo <= x <= hi:  # an infinity fails the range as well
                raise Rejected("range", f"{topic}.{name} outside [{lo:g}, {hi:g}]")
    mass = float(vals["car_mass_kg"])
    return {"t_s": t, "omega": w, "clamp": c,
            "accel": vals["longitudinal_acceleration_mps2"],
            "ref_speed": vals["reference_speed_mps"],
            "car_mass": mass if math.isfinite(mass) else math.nan}


def stamps_ns(t_s: Any) -> np.ndarray:
    """Simulation times [s] -> int64 nanoseconds, as :func:`to_time` rounds them."""
    return np.round(np.maximum(np.asarray(t_s, dtype=np.float64), 0.0) * 1e9).astype(np.int64)


def seconds_of_ns(ns: np.ndarray) -> np.ndarray:
    """int64 nanoseconds -> seconds, the same floats as :func:`from_time` of the Time."""
    ns = np.asarray(ns, dtype=np.int64)
    return (ns // 1_000_000_000).astype(np.float64) + 1e-9 * (ns % 1_000_000_000).astype(
        np.float64)


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


# ------------------------------------------------------------------ fleet messages
class Entry:
    """One train of a fleet message seen as a per-train message (for the per-train rules)."""

    def __init__(self, header: Any, step: int, train_id: str, **fields: Any) -> None:
        self.header = header
        self.step = step
        self.train_id = train_id
        self.__dict__.update(fields)


def fleet_arrays(msg: Any, topic: str, fields: Sequence[str]) -> list[Any]:
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
