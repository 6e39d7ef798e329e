"""Scenario files: typed schema, YAML loading and validation with one-line errors.

A scenario is a YAML mapping whose structure is defined by the frozen dataclasses below
(they *are* the schema; ``metro_atc/scenarios/SCHEMA.md`` documents the same keys and
``test_plant_scenario.py`` checks the two agree).  Units follow the key suffix: ``_m``
metres, ``_s`` seconds, ``_kmh`` km/h (converted to m/s internally), ``_permille`` per
mille grade, ``_pph`` persons per hour, ``_n`` newtons, ``_hz`` hertz.

Errors are raised as :class:`ScenarioError` with a single line naming the file, the key path
and the expected type/range, e.g.
``scenario taipei_blue.yaml: trains.count: expected int in [1, 60], got 'x'``.
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any, Literal, Union

from metro_atc.core import laws
from metro_atc.core.line.adhesion import CURVES
from metro_atc.core.line.guarantee import level_guaranteed_decel
from metro_atc.core.line.vehicle import PRESETS, train_params_of_section
from metro_atc.core.safe_yaml import (YamlLimitError, load_yaml_file, load_yaml_text, one_line,
                                      short_repr)

__all__ = [
    "ScenarioError", "Scenario", "SCENARIO_NAMES", "load_scenario", "parse_scenario",
    "schema_keys",
]


class ScenarioError(ValueError):
    """Invalid scenario: the message is one line naming the key path and what was expected."""


def _f(default: Any = dataclasses.MISSING, lo: float | None = None, hi: float | None = None,
       doc: str = "", lo_open: bool = False) -> Any:
    """Dataclass field with schema metadata (range [lo, hi], documentation)."""
    meta = {"lo": lo, "hi": hi, "doc": doc, "lo_open": lo_open}
    if isinstance(default, list):
        items = list(default)
        return field(default_factory=lambda: list(items), metadata=meta)
    return field(default=default, metadata=meta)


INF = math.inf
MAX_ERROR_CHARS = 260
"""Longest scenario error message (one line; the launcher adds its prefix)."""
MAX_GRID_CELLS = 1_000_000
"""Memory budget of the plant's precomputed track/ATP grid [cells] (~160 bytes per cell:
the grid of a 1e7 m line at 1 m would need 1.5 GiB; THSR at 2 m has 1.8e5 cells)."""
_MAX_FLOAT_INT = 10 ** 300
"""Integers beyond this would overflow ``float()`` (checked before converting)."""

# --------------------------------------------------------------------------- schema


@dataclass(frozen=True, kw_only=True)
class SimSpec:
    """Simulation clock."""

    control_period_s: float = _f(0.25, 0.01, 5.0, "lockstep control period")
    physics_substeps: int = _f(1, 1, 50, "RK4 sub-steps per control period")
    duration_s: float = _f(7200.0, 1.0, 200_000.0, "hard stop of the run (sim time)")
    grid_m: float = _f(1.0, 0.1, 20.0, "resolution of the precomputed track/ATP grid")


@dataclass(frozen=True, kw_only=True)
class RollingStockSpec:
    """Rolling stock from data (every key null = the preset's value; see SCHEMA.md)."""

    rotating_allowance: float | None = _f(None, 0.0, 1.0, "rotating-mass allowance lambda "
                                          "(effective mass m (1 + lambda))")
    cars: int | None = _f(None, 1, 32, "cars in the consist")
    davis_a_n: float | None = _f(None, 0.0, 1e6, "running resistance A [N]")
    davis_b_n_per_mps: float | None = _f(None, 0.0, 1e6, "running resistance B [N/(m/s)]")
    davis_c_n_per_mps2: float | None = _f(None, 0.0, 1e5, "running resistance C [N/(m/s)^2]")
    traction_force_kn: float | None = _f(None, 1.0, 5000.0, "maximum tractive force [kN]")
    traction_power_kw: float | None = _f(None, 1.0, 1e5, "maximum traction power at the "
                                         "wheel [kW] (constant power above P/F)")
    accel_max_mps2: float | None = _f(None, 0.05, 3.0, "starting-acceleration cap [m/s^2]")
    service_brake_mps2: float | None = _f(None, 0.1, 3.0, "maximum service deceleration")
    service_brake_load_pax: float | None = _f(None, 0.0, 5000.0, "load up to which the "
                                              "service brake is load-weighed (default: "
                                              "capacity_pax, crush)")
    regen_force_kn: float | None = _f(None, 0.0, 5000.0, "maximum electric brake force [kN]")
    friction_brake_force_kn: float | None = _f(None, 0.0, 10000.0, "maximum friction "
                                               "(pneumatic) service brake force [kN]")
    regen_power_kw: float | None = _f(None, 0.0, 1e5, "maximum electric brake power [kW]")
    emergency_brake_mps2: float | None = _f(None, 0.1, 3.0, "guaranteed emergency "
                                            "deceleration (ATP braking model)")
    emergency_brake_actual_mps2: float | None = _f(None, 0.1, 4.0, "nominal emergency "
                                                   "deceleration (plant)")
    jerk_max_mps3: float | None = _f(None, 0.1, 10.0, "jerk limit")
    emergency_jerk_mps3: float | None = _f(None, 0.1, 50.0, "rate at which the emergency "
                                           "brake builds up [m/s^3]")
    regen_fade_speed_kmh: float | None = _f(None, 0.0, 50.0, "below this speed the electric "
                                            "brake fades out linearly [km/h]")
    axles_per_car: int | None = _f(None, 2, 8, "axles per car")
    motored_axle_fraction: float | None = _f(None, 0.0, 1.0, "share of motored axles "
                                             "(traction adhesion, electric brake)")
    wheel_radius_m: float | None = _f(None, 0.2, 0.7, "wheel rolling radius")
    wheel_inertia_kgm2: float | None = _f(None, 1.0, 2000.0, "wheelset inertia incl. discs "
                                          "[kg m^2]")
    brake_radius_m: float | None = _f(None, 0.05, 0.6, "effective disc-pad friction radius")
    pad_mu_nominal: float | None = _f(None, 0.05, 1.0, "nominal disc-pad friction coefficient")


@dataclass(frozen=True, kw_only=True)
class TrainsSpec:
    """Fleet: number of train services and the rolling stock."""

    count: int = _f(dataclasses.MISSING, 1, 60, "number of train services (train_01..)")
    preset: Literal["taipei_mrt_6car", "thsr_700t"] = _f("taipei_mrt_6car", doc="rolling stock")
    mass_kg: float | None = _f(None, 1e3, 2e6, "override: mass with mass_load_pax on board")
    mass_load_pax: float | None = _f(None, 0.0, 5000.0, "persons included in mass_kg "
                                     "(required with mass_kg; 0: mass_kg is the empty mass)")
    tare_mass_kg: float | None = _f(None, 1e3, 2e6, "empty mass (instead of mass_kg)")
    pax_mass_kg: float | None = _f(None, 30.0, 150.0, "mass of one passenger")
    length_m: float | None = _f(None, 5.0, 600.0, "override: train length")
    max_speed_kmh: float | None = _f(None, 10.0, 400.0, "override: design max speed")
    capacity_pax: float | None = _f(None, 1.0, 5000.0, "override: crush capacity")
    stock: RollingStockSpec = _f(RollingStockSpec(), doc="rolling stock from data")
    initial_load_pax: float = _f(0.0, 0.0, 5000.0, "passengers on board when entering")
    instrumented_car: int = _f(1, 1, 16, "car (1-based) carrying the brake sensors")


@dataclass(frozen=True, kw_only=True)
class StationSpec:
    """One station; ``position_m`` is the platform stop point of the train front."""

    name: str = _f(dataclasses.MISSING, doc="station name")
    position_m: float = _f(dataclasses.MISSING, -1e7, 1e7, "chainage of the stop point")
    code: str = _f("", doc="station code, e.g. BL12")


@dataclass(frozen=True, kw_only=True)
class GradientSpec:
    """Grade from ``start_m`` to the next entry (+ uphill in running direction)."""

    start_m: float = _f(dataclasses.MISSING, -1e7, 1e7, "segment start chainage")
    grade_permille: float = _f(dataclasses.MISSING, -60.0, 60.0, "grade [per mille]")


@dataclass(frozen=True, kw_only=True)
class SpeedLimitSpec:
    """Permanent speed limit from ``start_m`` to the next entry."""

    start_m: float = _f(dataclasses.MISSING, -1e7, 1e7, "segment start chainage")
    limit_kmh: float = _f(dataclasses.MISSING, 5.0, 400.0, "limit [km/h]")


@dataclass(frozen=True, kw_only=True)
class CurveSpec:
    """Horizontal curve (curve resistance, Roeckl formula)."""

    start_m: float = _f(dataclasses.MISSING, -1e7, 1e7, "curve start chainage")
    end_m: float = _f(dataclasses.MISSING, -1e7, 1e7, "curve end chainage")
    radius_m: float = _f(dataclasses.MISSING, 100.0, 1e5, "curve radius")


@dataclass(frozen=True, kw_only=True)
class TsrSpec:
    """Temporary speed restriction, in force for sim time [from_s, to_s)."""

    start_m: float = _f(dataclasses.MISSING, -1e7, 1e7, "zone start chainage")
    end_m: float = _f(dataclasses.MISSING, -1e7, 1e7, "zone end chainage")
    limit_kmh: float = _f(dataclasses.MISSING, 5.0, 400.0, "limit [km/h]")
    from_s: float = _f(0.0, 0.0, INF, "in force from")
    to_s: float = _f(INF, 0.0, INF, "in force until")


@dataclass(frozen=True, kw_only=True)
class LineSpec:
    """Track: stations, gradients, limits, curves, blocks, terminus."""

    stations: list[StationSpec] = _f(dataclasses.MISSING, doc="stations, increasing chainage")
    line_speed_kmh: float = _f(80.0, 5.0, 400.0, "limit where no speed_limits entry applies")
    speed_limits: list[SpeedLimitSpec] = _f([], doc="permanent limits (step function)")
    gradients: list[GradientSpec] = _f([], doc="grades (step function)")
    curves: list[CurveSpec] = _f([], doc="curves")
    temporary_speed_limits: list[TsrSpec] = _f([], doc="TSRs (also via incidents)")
    block_length_m: float = _f(400.0, 20.0, 10_000.0, "fixed-block length (fixed_block mode)")
    tail_track_m: float = _f(300.0, 50.0, 5000.0, "turnback tail track beyond the terminus")
    turnback_s: float = _f(120.0, 0.0, 3600.0, "time in the tail track before leaving service")
    turnback_sidings: int = _f(2, 1, 4, "parallel turnback sidings beyond the terminus")
    tail_speed_kmh: float = _f(40.0, 5.0, 400.0, "limit beyond the terminal stop point")
    stop_tolerance_m: float = _f(1.0, 0.05, 20.0, "a stop within +-tol of the stop point "
                                 "opens the doors")
    adhesion: Literal["dry", "wet"] = _f("dry", doc="rail condition (slip-adhesion curve)")


@dataclass(frozen=True, kw_only=True)
class SignallingSpec:
    """ATP / signalling parameters (Ke 2010, Fig. 1 braking-curve construction)."""

    mode: Literal["moving_block", "fixed_block"] = _f("moving_block", doc="separation mode")
    safety_margin_m: float = _f(50.0, 0.0, 5000.0, "margin behind the rear of the train ahead")
    response_time_s: float = _f(1.0, 0.0, 10.0, "ATP response time t_r (>= control period + "
                                "emergency-brake build-up)")
    guaranteed_decel_mps2: float | None = _f(None, 0.1, 3.0, "guaranteed emergency decel on "
                                             "level track (default: rolling stock & adhesion)")
    overspeed_margin_kmh: float = _f(5.0, 0.0, 30.0, "ceiling above the limit (supervision)")
    sbi_lead_s: float = _f(2.0, 0.0, 30.0, "service-brake intervention this long before EBI")
    tsr_notice_s: float = _f(120.0, 0.0, 3600.0, "ATP knows a TSR this long before it applies")


@dataclass(frozen=True, kw_only=True)
class PeriodSpec:
    """One timetable period (Lin 2010a, eq. 7-9 TSK duration): headway + passenger flow."""

    start_s: float = _f(dataclasses.MISSING, 0.0, 200_000.0, "period start (sim time)")
    headway_s: float = _f(dataclasses.MISSING, 30.0, 7200.0, "scheduled headway H_n")
    boarding_pph: list[float] = _f(dataclasses.MISSING, doc="boarding demand p_jn per station")
    name: str = _f("", doc="label")


@dataclass(frozen=True, kw_only=True)
class TimetableSpec:
    """Dispatching from the first station (timetable per Lin 2010a, eq. 10)."""

    first_departure_s: float = _f(60.0, 0.0, 200_000.0, "first departure at station 0")
    periods: list[PeriodSpec] = _f(dataclasses.MISSING, doc="periods, increasing start_s")
    running_time_margin: float = _f(0.07, 0.0, 1.0, "scheduled = minimum running time x (1+m)")


@dataclass(frozen=True, kw_only=True)
class PassengersSpec:
    """Dwell model: boarding/alighting rates, door overhead, capacity."""

    boarding_s_per_pax: float = _f(0.02, 0.0, 1.0, "t_b: train-wide boarding time per person")
    alighting_s_per_pax: float = _f(0.015, 0.0, 1.0, "train-wide alighting time per person")
    door_overhead_s: float = _f(12.0, 0.0, 300.0, "door open/close + dispatch overhead")
    min_dwell_s: float = _f(20.0, 0.0, 600.0, "minimum dwell")
    alight_fraction: list[float] = _f(dataclasses.MISSING, doc="share of the load alighting")


@dataclass(frozen=True, kw_only=True)
class DisturbanceSpec:
    """Stochastic disturbances (Lin 2010a: departure delays are exponential)."""

    departure_delay_prob: float = _f(0.3, 0.0, 1.0, "probability of a departure delay")
    departure_delay_mean_s: float = _f(5.0, 0.0, 600.0, "mean of the exponential delay")
    running_time_noise: float = _f(0.02, 0.0, 0.3, "std of the per-run traction level loss")


@dataclass(frozen=True, kw_only=True)
class IncidentSpec:
    """Scripted incident: ``hold`` (train at station), ``breakdown`` (train at time), ``tsr``."""

    kind: Literal["hold", "breakdown", "tsr"] = _f(dataclasses.MISSING, doc="incident kind")
    train: str = _f("", doc="train id (hold, breakdown)")
    station: str = _f("", doc="station code or name (hold)")
    at_s: float = _f(0.0, 0.0, INF, "start time (breakdown, tsr)")
    duration_s: float = _f(0.0, 0.0, INF, "hold / breakdown / tsr duration")
    start_m: float = _f(0.0, -1e7, 1e7, "tsr zone start")
    end_m: float = _f(0.0, -1e7, 1e7, "tsr zone end")
    limit_kmh: float = _f(25.0, 5.0, 400.0, "tsr limit")


@dataclass(frozen=True, kw_only=True)
class FaultSpec:
    """Injected fault on a train's instrumented car."""

    kind: Literal["pad_mu", "wheel", "sensor_dropout", "sensor_stuck"] = _f(
        dataclasses.MISSING, doc="fault kind")
    train: str = _f(dataclasses.MISSING, doc="train id")
    axle: int = _f(0, 0, 4, "axle 1..4 of the instrumented car; 0 = all axles")
    at_s: float = _f(0.0, 0.0, INF, "fault onset")
    duration_s: float = _f(INF, 0.0, INF, "fault duration")
    mu_b: float = _f(0.1, 0.0, 1.0, "pad_mu: degraded disk-pad friction coefficient")
    adhesion_factor: float = _f(0.5, 0.0, 1.0, "wheel: adhesion scale of the defective wheel")
    radius_factor: float = _f(1.0, 0.9, 1.1, "wheel: rolling radius scale (worn/flat wheel)")
    channel: Literal["wheel_omega", "clamp_force", "accel", "ref_speed", "all"] = _f(
        "all", doc="sensor faults: affected channel")


@dataclass(frozen=True, kw_only=True)
class SensorSpec:
    """Brake-by-wire sensors of each train's instrumented car (4 axles)."""

    rate_hz: float = _f(20.0, 0.1, 1000.0, "sample rate")
    trains: list[str] = _f([], doc="instrumented trains (empty: all)")
    wheel_omega_noise_radps: float = _f(0.02, 0.0, 10.0, "wheel speed noise std")
    clamp_force_noise_n: float = _f(100.0, 0.0, 1e5, "clamp force noise std")
    accel_noise_mps2: float = _f(0.02, 0.0, 5.0, "accelerometer noise std")
    ref_speed_noise_mps: float = _f(0.02, 0.0, 5.0, "reference speed noise std")


@dataclass(frozen=True, kw_only=True)
class EnergySpec:
    """Energy metering overrides (defaults from the rolling stock)."""

    traction_efficiency: float | None = _f(None, 0.1, 1.0, "substation-to-wheel efficiency")
    regen_efficiency: float | None = _f(None, 0.0, 1.0, "wheel-to-line regen efficiency")
    regen_receptivity: float = _f(1.0, 0.0, 1.0, "share of regen absorbed by the line")
    aux_power_kw: float | None = _f(None, 0.0, 5000.0, "auxiliary load per train in service")


@dataclass(frozen=True, kw_only=True)
class Scenario:
    """A complete scenario (the root of the YAML file)."""

    name: str = _f(dataclasses.MISSING, doc="scenario name")
    trains: TrainsSpec = _f(dataclasses.MISSING, doc="fleet")
    line: LineSpec = _f(dataclasses.MISSING, doc="track")
    timetable: TimetableSpec = _f(dataclasses.MISSING, doc="dispatching")
    passengers: PassengersSpec = _f(dataclasses.MISSING, doc="dwell model")
    description: str = _f("", doc="free text")
    sources: list[str] = _f([], doc="where the numbers come from / which are estimates")
    sim: SimSpec = _f(SimSpec(), doc="clock")
    signalling: SignallingSpec = _f(SignallingSpec(), doc="ATP")
    disturbances: DisturbanceSpec = _f(DisturbanceSpec(), doc="disturbances")
    incidents: list[IncidentSpec] = _f([], doc="scripted incidents")
    faults: list[FaultSpec] = _f([], doc="fault injection")
    sensors: SensorSpec = _f(SensorSpec(), doc="sensors")
    energy: EnergySpec = _f(EnergySpec(), doc="energy metering")
    source_file: str = field(default="", metadata={"internal": True})

    @property
    def train_ids(self) -> list[str]:
        """Train ids ``train_01`` .. ``train_NN``."""
        return [f"train_{i + 1:02d}" for i in range(self.trains.count)]

    def station_index(self, key: str) -> int:
        """Index of a station given its code or name (exact match); -1 if unknown."""
        for i, s in enumerate(self.line.stations):
            if key in (s.code, s.name) and key:
                return i
        return -1


# --------------------------------------------------------------------------- builder


def _type_name(tp: Any) -> str:
    """Human-readable name of a schema type."""
    origin = typing.get_origin(tp)
    if origin is Literal:
        return "one of " + ", ".join(repr(a) for a in typing.get_args(tp))
    if origin in (Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        return _type_name(args[0]) + " or null"
    if origin is list:
        return "list of " + _type_name(typing.get_args(tp)[0])
    if dataclasses.is_dataclass(tp):
        return "mapping"
    return getattr(tp, "__name__", str(tp))


def _range_text(meta: dict[str, Any]) -> str:
    lo, hi = meta.get("lo"), meta.get("hi")
    if lo is None and hi is None:
        return ""
    lo_s = "-inf" if lo is None else f"{lo:g}"
    hi_s = "inf" if hi is None else f"{hi:g}"
    return f" in [{lo_s}, {hi_s}]"


class _Builder:
    """Build the frozen dataclasses from parsed YAML, validating every value."""

    def __init__(self, src: str) -> None:
        self.src = src

    def err(self, path: str, msg: str) -> ScenarioError:
        """An error for key ``path`` (one line, at most ``MAX_ERROR_CHARS``)."""
        return ScenarioError(one_line(f"scenario {self.src}: {path}: {msg}", MAX_ERROR_CHARS))

    def value(self, tp: Any, raw: Any, path: str, meta: dict[str, Any]) -> Any:
        """Convert/validate one value of schema type ``tp``."""
        origin = typing.get_origin(tp)
        expect = _type_name(tp) + _range_text(meta)
        if origin in (Union, types.UnionType):
            args = [a for a in typing.get_args(tp) if a is not type(None)]
            if raw is None:
                return None
            return self.value(args[0], raw, path, meta)
        if origin is Literal:
            if raw not in typing.get_args(tp):
                raise self.err(path, f"expected {expect}, got {short_repr(raw)}")
            return raw
        if origin is list:
            if not isinstance(raw, list):
                raise self.err(path, f"expected {expect}, got {short_repr(raw)}")
            sub = typing.get_args(tp)[0]
            return [self.value(sub, r, f"{path}[{i}]", {}) for i, r in enumerate(raw)]
        if dataclasses.is_dataclass(tp):
            if not isinstance(raw, dict):
                raise self.err(path, f"expected mapping, got {short_repr(raw)}")
            return self.build(tp, raw, path)
        if tp is bool:
            if not isinstance(raw, bool):
                raise self.err(path, f"expected bool, got {short_repr(raw)}")
            return raw
        if tp is str:
            if not isinstance(raw, str):
                raise self.err(path, f"expected str, got {short_repr(raw)}")
            return raw
        if tp is int:
            ok = isinstance(raw, int) and not isinstance(raw, bool)
            if not ok or not self._in_range(raw, meta):
                raise self.err(path, f"expected {expect}, got {short_repr(raw)}")
            return int(raw)
        if tp is float:
            # range-checked on the raw number (an int of 400 digits overflows float())
            ok = isinstance(raw, (int, float)) and not isinstance(raw, bool)
            if not ok or raw != raw or not self._in_range(raw, meta) \
                    or (isinstance(raw, int) and abs(raw) > _MAX_FLOAT_INT):
                raise self.err(path, f"expected {expect}, got {short_repr(raw)}")
            return float(raw)
        raise self.err(path, f"unsupported schema type {tp!r}")  # pragma: no cover

    @staticmethod
    def _in_range(x: float | int, meta: dict[str, Any]) -> bool:
        """``x`` in [lo, hi] (exact for any int: no float conversion)."""
        lo, hi = meta.get("lo"), meta.get("hi")
        if lo is not None and x < lo:
            return False
        if hi is not None and x > hi:
            return False
        return True

    def build(self, cls: Any, raw: dict[str, Any], path: str) -> Any:
        """Build dataclass ``cls`` from mapping ``raw``; unknown keys are errors."""
        hints = typing.get_type_hints(cls)
        fields = {f.name: f for f in dataclasses.fields(cls) if not f.metadata.get("internal")}
        for key in raw:
            if key not in fields:
                p = f"{path}.{key}" if path else str(key)
                raise self.err(p, "unknown key (known: " + ", ".join(fields) + ")")
        kwargs: dict[str, Any] = {}
        for name, f in fields.items():
            p = f"{path}.{name}" if path else name
            if name in raw:
                kwargs[name] = self.value(hints[name], raw[name], p, dict(f.metadata))
            elif f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
                raise self.err(p, f"missing required key ({_type_name(hints[name])})")
        return cls(**kwargs)


def _default_text(f: Any) -> str:
    if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
        return "required"
    if f.default_factory is not dataclasses.MISSING:
        return "[]"
    if dataclasses.is_dataclass(f.default):
        return "(defaults)"
    return "null" if f.default is None else repr(f.default)


def schema_keys(cls: Any = Scenario,
                prefix: str = "") -> list[tuple[str, str, str, str, str]]:
    """Flattened schema: (key path, type, range, default, doc) per key (SCHEMA.md, tests)."""
    out: list[tuple[str, str, str, str, str]] = []
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        if f.metadata.get("internal"):
            continue
        tp = hints[f.name]
        path = f"{prefix}{f.name}"
        out.append((path, _type_name(tp), _range_text(dict(f.metadata)).strip(),
                    _default_text(f), str(f.metadata.get("doc", ""))))
        inner = tp
        if typing.get_origin(tp) is list:
            inner = typing.get_args(tp)[0]
            path = path + "[]"
        if dataclasses.is_dataclass(inner):
            out.extend(schema_keys(inner, path + "."))
    return out


# --------------------------------------------------------------------------- semantics


def _check(b: _Builder, s: Scenario) -> None:
    """Cross-field validation (ordering, lengths, references)."""
    st = s.line.stations
    n = len(st)
    if n < 2 or n > 200:
        raise b.err("line.stations", f"expected 2..200 stations, got {n}")
    for i in range(1, n):
        if st[i].position_m <= st[i - 1].position_m + 10.0:
            raise b.err(f"line.stations[{i}].position_m",
                        f"expected > stations[{i - 1}].position_m + 10, got {st[i].position_m}")
    names = [x.name for x in st]
    if len(set(names)) != n:
        raise b.err("line.stations", "station names must be unique")
    for key, items in (("line.speed_limits", s.line.speed_limits),
                       ("line.gradients", s.line.gradients)):
        starts = [it.start_m for it in items]
        for i in range(1, len(starts)):
            if starts[i] <= starts[i - 1]:
                raise b.err(f"{key}[{i}].start_m", "expected strictly increasing start_m")
    for i, c in enumerate(s.line.curves):
        if c.end_m <= c.start_m:
            raise b.err(f"line.curves[{i}].end_m", "expected end_m > start_m")
    for i, t in enumerate(s.line.temporary_speed_limits):
        if t.end_m <= t.start_m:
            raise b.err(f"line.temporary_speed_limits[{i}].end_m", "expected end_m > start_m")
        if t.to_s <= t.from_s:
            raise b.err(f"line.temporary_speed_limits[{i}].to_s", "expected to_s > from_s")
    per = s.timetable.periods
    if not per:
        raise b.err("timetable.periods", "expected at least one period")
    for i, p in enumerate(per):
        if len(p.boarding_pph) != n:
            raise b.err(f"timetable.periods[{i}].boarding_pph",
                        f"expected list of {n} floats (one per station), "
                        f"got {len(p.boarding_pph)}")
        for j, v in enumerate(p.boarding_pph):
            if not (isinstance(v, float) and 0.0 <= v <= 1e5):
                raise b.err(f"timetable.periods[{i}].boarding_pph[{j}]",
                            f"expected float in [0, 100000], got {short_repr(v)}")
        if i and p.start_s <= per[i - 1].start_s:
            raise b.err(f"timetable.periods[{i}].start_s", "expected strictly increasing start_s")
    af = s.passengers.alight_fraction
    if len(af) != n:
        raise b.err("passengers.alight_fraction",
                    f"expected list of {n} floats (one per station), got {len(af)}")
    for j, v in enumerate(af):
        if not 0.0 <= v <= 1.0:
            raise b.err(f"passengers.alight_fraction[{j}]",
                        f"expected float in [0, 1], got {short_repr(v)}")
    ids = set(s.train_ids)
    for i, inc in enumerate(s.incidents):
        if inc.kind in ("hold", "breakdown") and inc.train not in ids:
            raise b.err(f"incidents[{i}].train",
                        f"expected a train id train_01..train_{s.trains.count:02d}, "
                        f"got {short_repr(inc.train)}")
        if inc.kind == "hold" and s.station_index(inc.station) < 0:
            raise b.err(f"incidents[{i}].station",
                        f"expected a station code or name, got {short_repr(inc.station)}")
        if inc.kind == "tsr" and inc.end_m <= inc.start_m:
            raise b.err(f"incidents[{i}].end_m", "expected end_m > start_m")
        if inc.kind in ("hold", "breakdown", "tsr") and inc.duration_s <= 0.0:
            raise b.err(f"incidents[{i}].duration_s", "expected float > 0")
    for i, fl in enumerate(s.faults):
        if fl.train not in ids:
            raise b.err(f"faults[{i}].train",
                        f"expected a train id train_01..train_{s.trains.count:02d}, "
                        f"got {short_repr(fl.train)}")
    for i, tid in enumerate(s.sensors.trains):
        if tid not in ids:
            raise b.err(f"sensors.trains[{i}]", f"expected a train id, got {short_repr(tid)}")
    if s.signalling.response_time_s < s.sim.control_period_s:
        raise b.err("signalling.response_time_s",
                    f"expected >= sim.control_period_s ({s.sim.control_period_s}), "
                    f"got {s.signalling.response_time_s}")
    _check_extent(b, s)
    _check_budget(b, s)
    _check_stock(b, s)


def line_extent_m(s: Scenario, length_m: float) -> tuple[float, float]:
    """Chainage span of the line [m]: the plant's track.

    From a train length and 500 m before the first stop point to the buffer stop
    ``tail_track_m`` beyond the last.
    """
    st = s.line.stations
    return st[0].position_m - length_m - 500.0, st[-1].position_m + s.line.tail_track_m


def _check_extent(b: _Builder, s: Scenario) -> None:
    """Track data must lie on the line (:func:`line_extent_m`).

    Step functions (speed limits, grades) may start before the line (they apply from its
    start) but not beyond its end; curves and TSR zones lie within it.  The train length of
    the extent is known before the stock is
    resolved: the scenario's ``trains.length_m`` or the preset's).
    """
    length = s.trains.length_m
    lo, hi = line_extent_m(s, PRESETS[s.trains.preset].length_m if length is None else length)
    ext = f"the line spans [{lo:g}, {hi:g}] m (stations, tail track)"
    starts = [("line.speed_limits", i, e.start_m) for i, e in enumerate(s.line.speed_limits)]
    starts += [("line.gradients", i, e.start_m) for i, e in enumerate(s.line.gradients)]
    for key, i, x in starts:
        if x >= hi:
            raise b.err(f"{key}[{i}].start_m", f"{x:g} is beyond the end of the line: {ext}")
    zones = [(f"line.curves[{i}]", c.start_m, c.end_m) for i, c in enumerate(s.line.curves)]
    zones += [(f"line.temporary_speed_limits[{i}]", t.start_m, t.end_m)
              for i, t in enumerate(s.line.temporary_speed_limits)]
    zones += [(f"incidents[{i}]", c.start_m, c.end_m) for i, c in enumerate(s.incidents)
              if c.kind == "tsr"]
    for key, a, z in zones:
        if a < lo or z > hi:
            raise b.err(f"{key}.start_m" if a < lo else f"{key}.end_m",
                        f"[{a:g}, {z:g}] m is not on the line: {ext}")


# TrainsSpec keys of the rolling stock (the others are trains.stock.* or energy.*)
_TRAINS_STOCK_KEYS = ("mass_kg", "tare_mass_kg", "mass_load_pax", "pax_mass_kg", "length_m",
                      "max_speed_kmh", "capacity_pax")
_ENERGY_STOCK_KEYS = ("traction_efficiency", "regen_efficiency", "aux_power_kw")


def stock_key_path(key: str) -> str:
    """Scenario key path of a rolling-stock data key (``STOCK_KEYS`` of the vehicle model)."""
    if key in _TRAINS_STOCK_KEYS:
        return f"trains.{key}"
    if key in _ENERGY_STOCK_KEYS:
        return f"energy.{key}"
    return f"trains.stock.{key}"


CAR_LENGTH_MIN_M = 8.0
"""Shortest car of a train with two bogies [m] (estimate: bogie centres plus overhangs)."""
CRUSH_PAX_PER_M = 25.0
"""Largest crush load per metre of train [persons/m] (estimate: 8 standing persons per m^2
on a 3 m wide floor with no seats; the shipped stock has 3.3-15.6)."""


def _check_stock(b: _Builder, s: Scenario) -> None:
    """The resolved rolling stock is physical at every load from empty to crush.

    Refused: an empty mass <= 0; an initial load above the capacity; cars shorter than
    :data:`CAR_LENGTH_MIN_M` or a capacity above :data:`CRUSH_PAX_PER_M` per metre of train
    (a preset's figures the file's length cannot hold); a train that cannot
    start on the line's steepest up grade at crush load (tractive force at standstill,
    limited by the motored axles' peak adhesion, not above the Davis A term plus the grade
    force of the crush-loaded train); a nominal emergency brake below the ATP's guaranteed
    deceleration.
    """
    if s.trains.mass_kg is not None and s.trains.mass_load_pax is None:
        raise b.err("trains.mass_load_pax", "required with trains.mass_kg: the persons "
                    "mass_kg includes (0: mass_kg is the empty mass; or give tare_mass_kg)")
    try:
        p = train_params_of_section(s.trains, s.energy)
    except ValueError as exc:
        key, _, msg = str(exc).partition(": ")
        raise b.err(stock_key_path(key), msg) from None
    if p.tare_mass_kg <= 0.0:  # a preset's figures cannot do this; a guard for new presets
        raise b.err("trains.mass_kg", f"empty mass {p.tare_mass_kg:g} kg, expected > 0")
    load_key = "trains.mass_load_pax" if s.trains.mass_load_pax is not None else \
        "trains.capacity_pax"
    if p.nominal_load_pax > p.capacity_pax:
        raise b.err(load_key, f"the load mass_kg includes ({p.nominal_load_pax:g} persons) "
                    f"exceeds the capacity ({p.capacity_pax:g})")
    if s.trains.initial_load_pax > p.capacity_pax:
        raise b.err("trains.initial_load_pax", f"expected <= capacity_pax "
                    f"({p.capacity_pax:g}), got {s.trains.initial_load_pax:g}")
    # a preset's cars or capacity that the train's length cannot hold: refused, not kept
    if p.length_m / p.cars < CAR_LENGTH_MIN_M:
        raise b.err("trains.stock.cars", f"{p.cars} cars on a {p.length_m:g} m train is "
                    f"{p.length_m / p.cars:.3g} m per car, expected >= {CAR_LENGTH_MIN_M:g} m "
                    "(give the train's cars)")
    if p.capacity_pax / p.length_m > CRUSH_PAX_PER_M:
        raise b.err("trains.capacity_pax", f"{p.capacity_pax:g} persons on a {p.length_m:g} "
                    f"m train is {p.capacity_pax / p.length_m:.3g} per metre, expected <= "
                    f"{CRUSH_PAX_PER_M:g} (give the train's capacity)")
    curve = CURVES[s.line.adhesion]
    m_crush = p.mass_at_load(p.capacity_pax)
    n_ax = p.cars * p.axles_per_car
    n_mot = int(round(p.motored_axle_fraction * n_ax))
    if n_mot < 1 or n_ax - n_mot < 4:
        raise b.err("trains.stock.motored_axle_fraction",
                    f"{n_mot} motored axles of {n_ax}: expected >= 1 and a 4-axle trailer "
                    f"car (the instrumented brake car) (fraction {p.motored_axle_fraction:g})")
    if s.trains.instrumented_car > p.cars:
        raise b.err("trains.instrumented_car", f"expected <= cars ({p.cars}), "
                    f"got {s.trains.instrumented_car}")
    law = laws.plain  # one-off evaluations: the laws uncompiled (no numba at load time)
    # the plant's force limit at crush (the curve's force at its reference mass)
    f_start = min(law.traction_force(0.0, law.traction_mass(m_crush, p.mass_kg),
                                     *p.traction_law),
                  law.adhesion_limit(curve.mu_peak, law.axle_load(m_crush, n_ax)) * n_mot)
    up = max([0.0] + [g.grade_permille / 1000.0 for g in s.line.gradients])
    f_need = law.davis_resistance(0.0, p.davis_a_n, p.davis_b_n_per_mps,
                                  p.davis_c_n_per_mps2) + law.grade_force(up, m_crush)
    if f_start <= f_need:
        raise b.err("trains.stock.traction_force_kn",
                    f"the crush-loaded train ({m_crush / 1000.0:.4g} t, {p.capacity_pax:g} "
                    f"persons) cannot start on the steepest grade {1000.0 * up:g} permille: "
                    f"tractive force {f_start / 1000.0:.4g} kN <= resistance + grade "
                    f"{f_need / 1000.0:.4g} kN")
    b_guar = level_guaranteed_decel(s.signalling.guaranteed_decel_mps2, p, curve)
    if p.emergency_brake_actual_mps2 < b_guar:
        key = "signalling.guaranteed_decel_mps2" if s.signalling.guaranteed_decel_mps2 \
            is not None else "trains.stock.emergency_brake_actual_mps2"
        raise b.err(key, f"the nominal emergency brake {p.emergency_brake_actual_mps2:g} "
                    f"m/s^2 is below the ATP's guaranteed deceleration {b_guar:.4g} m/s^2")


_G = 9.80665
"""Gravity used by the grade check [m/s^2] (the plant's value; only a plausibility bound)."""


def _check_budget(b: _Builder, s: Scenario) -> None:
    """Checks that need arithmetic on validated values: grid memory, braking on the grade.

    The plant grids the line from the first stop (minus a train length and 500 m) to the
    tail track (plus 200 m) at ``sim.grid_m``; an explicit guaranteed deceleration must stay
    positive (> 0.05 m/s^2, the plant's floor) on the steepest downhill grade.
    """
    st = s.line.stations
    extent = (st[-1].position_m - st[0].position_m) + 600.0 + 700.0 + s.line.tail_track_m
    cells = extent / s.sim.grid_m
    if cells > MAX_GRID_CELLS:
        raise b.err("sim.grid_m", f"line of {extent / 1000.0:.0f} km at {s.sim.grid_m:g} m "
                    f"needs {cells:.3g} grid cells, above the budget of {MAX_GRID_CELLS:.0e} "
                    f"(coarser grid_m or a shorter line)")
    b_lvl = s.signalling.guaranteed_decel_mps2
    max_down = max([0.0] + [-g.grade_permille / 1000.0 for g in s.line.gradients])
    if b_lvl is not None and b_lvl - _G * max_down <= 0.05:
        raise b.err("signalling.guaranteed_decel_mps2",
                    f"expected > {0.05 + _G * max_down:.3f} (positive guaranteed braking on "
                    f"the steepest downhill grade {1000.0 * max_down:g} permille), got {b_lvl:g}")


# --------------------------------------------------------------------------- loading


def _package_dir() -> Path:
    return Path(str(resources.files("metro_atc").joinpath("scenarios")))


def _names() -> tuple[str, ...]:
    d = _package_dir()
    if not d.is_dir():  # pragma: no cover - broken install
        return ()
    return tuple(sorted(p.stem for p in d.glob("*.yaml")))


SCENARIO_NAMES: tuple[str, ...] = _names()
"""Names of the scenarios shipped in ``metro_atc/scenarios/*.yaml``."""


def parse_scenario(text: str, src: str = "<string>") -> Scenario:
    """Parse and validate scenario YAML text; ``src`` names it in error messages."""
    try:
        raw = load_yaml_text(text)
    except YamlLimitError as exc:
        raise ScenarioError(one_line(f"scenario {src}: {exc}", MAX_ERROR_CHARS)) from None
    return _from_raw(raw, src)


def _from_raw(raw: Any, src: str) -> Scenario:
    """Build and validate a scenario from parsed YAML."""
    if not isinstance(raw, dict):
        raise ScenarioError(one_line(f"scenario {src}: expected a mapping at the top level, "
                                     f"got {type(raw).__name__} {short_repr(raw)}",
                                     MAX_ERROR_CHARS))
    b = _Builder(src)
    scn: Scenario = b.build(Scenario, raw, "")
    _check(b, scn)
    return dataclasses.replace(scn, source_file=src)


def validate_scenario(scn: Scenario, src: str) -> Scenario:
    """Validate a scenario built in code (cross-field checks of a loaded one); ScenarioError.

    Returns ``scn`` with ``source_file`` = ``src``.
    """
    _check(_Builder(src), scn)
    return dataclasses.replace(scn, source_file=src)


def load_scenario(name_or_path: str | Path) -> Scenario:
    """Load a scenario by embedded name (see :data:`SCENARIO_NAMES`) or YAML file path."""
    key = str(name_or_path)
    path = Path(key)
    shown = short_repr(key) if len(key) > 60 or not key.isprintable() else key
    if key in SCENARIO_NAMES and not (path.suffix and path.is_file()):
        path = _package_dir() / f"{key}.yaml"
    elif path.is_dir():
        raise ScenarioError(one_line(f"scenario {shown}: is a directory, expected a YAML file",
                                     MAX_ERROR_CHARS))
    elif not path.exists():
        if path.suffix in (".yaml", ".yml") or "/" in key:
            raise ScenarioError(one_line(f"scenario {shown}: file not found", MAX_ERROR_CHARS))
        raise ScenarioError(one_line(f"unknown scenario {short_repr(key)}; known: "
                                     f"{', '.join(SCENARIO_NAMES)} (or a path to a YAML file)",
                                     MAX_ERROR_CHARS))
    try:
        raw = load_yaml_file(path)
    except YamlLimitError as exc:
        raise ScenarioError(one_line(f"scenario {path.name}: {exc}", MAX_ERROR_CHARS)) from None
    return _from_raw(raw, path.name)
