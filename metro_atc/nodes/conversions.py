"""All conversions between ROS messages and the ROS-free cores live here.

Incoming messages are validated (finite numbers, known train ids, sane ranges); a bad
message raises :class:`MessageRejected` with one line naming the topic field, which the
node logs (rate-limited) before dropping the message.
"""

from __future__ import annotations

import math
from typing import Any, Iterable, Mapping, Sequence

import numpy as np
from builtin_interfaces.msg import Time
from metro_atc_msgs.msg import (BrakeDiagnosis, BrakeSensorData, DepartureCommand, LineStatus,
                                TractionCommand, TrainEvent, TrainState)
from rosgraph_msgs.msg import Clock

REGULATOR_CODES = {"none": DepartureCommand.REGULATOR_NONE, "lqr": DepartureCommand.REGULATOR_LQR,
                   "dhp": DepartureCommand.REGULATOR_DHP, "aoc": DepartureCommand.REGULATOR_AOC,
                   "elqr": DepartureCommand.REGULATOR_ELQR}


class MessageRejected(ValueError):
    """An incoming message failed validation; the text names the offending field."""


def to_time(t_s: float) -> Time:
    """Simulation seconds -> builtin_interfaces/Time (floor to the nanosecond)."""
    ns = int(round(max(0.0, float(t_s)) * 1e9))
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def from_time(t: Time) -> float:
    """builtin_interfaces/Time -> seconds."""
    return float(t.sec) + 1e-9 * float(t.nanosec)


def clock_msg(t_s: float) -> Clock:
    """A /clock message for simulation time t_s [s]."""
    return Clock(clock=to_time(t_s))


def _finite(name: str, value: float) -> float:
    v = float(value)
    if not math.isfinite(v):
        raise MessageRejected(f"{name} is not finite ({value})")
    return v


def train_index(train_id: str, index: Mapping[str, int], topic: str) -> int:
    """Index of a train id, or :class:`MessageRejected` naming the unknown id."""
    try:
        return index[train_id]
    except KeyError:
        raise MessageRejected(f"{topic}: unknown train_id '{train_id}'") from None


def traction_from_msg(msg: TractionCommand, topic: str) -> tuple[int, float]:
    """Validate a TractionCommand; return (step, effort in [-1, 1])."""
    effort = _finite(f"{topic}.effort", msg.effort)
    if not -1.0 - 1e-9 <= effort <= 1.0 + 1e-9:
        raise MessageRejected(f"{topic}.effort={effort} outside [-1, 1]")
    return int(msg.step), float(np.clip(effort, -1.0, 1.0))


def traction_msg(train_id: str, step: int, t_s: float, effort: float,
                 mode: int) -> TractionCommand:
    """Build a TractionCommand."""
    m = TractionCommand(train_id=train_id, step=int(step), effort=float(effort), mode=int(mode))
    m.header.stamp = to_time(t_s)
    m.header.frame_id = "line"
    return m


def departure_from_msg(msg: DepartureCommand, topic: str,
                       n_stations: int) -> tuple[int, float, float, float]:
    """Validate a DepartureCommand; return (station, departure_s, running_s, dwell_limit_s).

    ``dwell_limit_s`` may be NaN (no dwell cut); every other time must be finite.
    """
    st = int(msg.station_index)
    if not 0 <= st < n_stations:
        raise MessageRejected(f"{topic}.station_index={st} outside [0, {n_stations - 1}]")
    dep = _finite(f"{topic}.departure_time_s", msg.departure_time_s)
    run = _finite(f"{topic}.target_running_time_s", msg.target_running_time_s)
    dwell = float(msg.dwell_limit_s)
    if math.isinf(dwell):
        raise MessageRejected(f"{topic}.dwell_limit_s={dwell} is not finite or NaN")
    if dep < 0.0 or run < 0.0 or dwell < 0.0:
        raise MessageRejected(f"{topic}: negative time in departure command")
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


def state_from_msg(msg: TrainState, topic: str) -> dict[str, Any]:
    """Validate a TrainState; return a plain dict of its fields."""
    return {"step": int(msg.step), "t_s": from_time(msg.header.stamp),
            "x_m": _finite(f"{topic}.position_m", msg.position_m),
            "v_mps": _finite(f"{topic}.speed_mps", msg.speed_mps),
            "a_mps2": _finite(f"{topic}.acceleration_mps2", msg.acceleration_mps2),
            "current_station": int(msg.current_station), "next_station": int(msg.next_station),
            "mode": int(msg.mode),
            "departure_time_s": float(msg.departure_time_s),
            "target_running_time_s": float(msg.target_running_time_s),
            "supervision_speed_mps": (float(msg.supervision_speed_mps)
                                      if math.isfinite(msg.supervision_speed_mps)
                                      else math.inf),
            "movement_authority_m": (float(msg.movement_authority_m)
                                     if math.isfinite(msg.movement_authority_m) else math.inf)}


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


def event_from_msg(msg: TrainEvent, topic: str) -> dict[str, Any]:
    """Validate a TrainEvent; return a plain dict."""
    if msg.kind not in (TrainEvent.KIND_ARRIVAL, TrainEvent.KIND_DEPARTURE):
        raise MessageRejected(f"{topic}.kind={msg.kind} is not ARRIVAL(1) or DEPARTURE(2)")
    return {"train_id": msg.train_id,
            "kind": "arrival" if msg.kind == TrainEvent.KIND_ARRIVAL else "departure",
            "station": int(msg.station_index),
            "t_s": _finite(f"{topic}.actual_time_s", msg.actual_time_s),
            "scheduled_s": float(msg.scheduled_time_s), "sequence": int(msg.sequence),
            "dwell_s": float(msg.dwell_s)}


def sensor_msg(s: Any, train_ids: Sequence[str]) -> BrakeSensorData:
    """BrakeSensorData from a core BrakeSensorSample (NaN channels pass through: dropouts)."""
    m = BrakeSensorData()
    m.header.stamp = to_time(s.t_s)
    m.header.frame_id = "line"
    m.train_id = train_ids[s.train_idx]
    m.wheel_angular_speed_radps = [float(x) for x in s.wheel_omega_radps]
    m.clamp_force_n = [float(x) for x in s.clamp_force_n]
    m.longitudinal_acceleration_mps2 = float(s.accel_x_mps2)
    m.reference_speed_mps = float(s.ref_speed_mps)
    m.car_mass_kg = float(getattr(s, "car_mass_kg", math.nan))
    return m


def sensor_from_msg(msg: BrakeSensorData, topic: str, n_axles: int) -> dict[str, Any]:
    """Validate the shape of a BrakeSensorData; return its channels as a plain dict.

    Raises :class:`MessageRejected` for a wrong number of axles.  Non-finite channel values
    are allowed (dropouts: the observer does not use them); ``car_mass`` is NaN when the
    load-weigh signal is missing or not positive.
    """
    w = np.asarray(msg.wheel_angular_speed_radps, dtype=float)
    c = np.asarray(msg.clamp_force_n, dtype=float)
    if w.shape != (n_axles,) or c.shape != (n_axles,):
        raise MessageRejected(f"{topic}: expected {n_axles} axles, got "
                              f"wheel_angular_speed_radps[{w.size}], clamp_force_n[{c.size}]")
    mass = float(msg.car_mass_kg)
    return {"t_s": from_time(msg.header.stamp), "omega": w, "clamp": c,
            "accel": float(msg.longitudinal_acceleration_mps2),
            "ref_speed": float(msg.reference_speed_mps),
            "car_mass": mass if math.isfinite(mass) and mass > 0.0 else math.nan}


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
