"""Import TTOBench tracks, trains and journeys as a metro_atc scenario (and export back).

``python -m metro_atc import ttobench --track T.json --train R.json [--journey J.json]
--out scenario.yaml [--trains N] [--headway-s H] [--dwell-s D] [--margin M] [--drop FIELD]
[--length-m L]``

``T`` / ``R`` are file paths or the names of the vendored files (``CN_Songjiazhuang_Yizhuang``,
``CN_Beijing_Subway``).  Every TTOBench field is mapped onto a scenario key or refused with a
one-line :class:`TtobenchError` naming the field; a refused field can be left out on purpose
with ``--drop 'FIELD'`` (the output states it).  The field-by-field mapping is in
``metro_atc/ttobench/README.md``.  TTOBench tracks carry no timetable: the scenario gets one
from the defaults (headway, dwell, running-time margin, number of trains), stated in the
output.  :func:`export_ttobench` maps a scenario produced here back onto the TTOBench
formats (the round-trip test).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any, Optional, Sequence

import yaml

from metro_atc.core.line.scenario import LineSpec, Scenario, ScenarioError, parse_scenario
from metro_atc.core.line.vehicle import PRESETS

KMH_PER_MPS = 3.6


class TtobenchError(ValueError):
    """A TTOBench file that cannot be imported (one line naming the file and the field)."""


# field -> {unit: factor to the scenario unit}
_UNITS: dict[str, dict[str, float]] = {
    "mass": {"kg": 1.0, "t": 1000.0},
    "rho": {"%": 0.01, "-": 1.0},
    "length": {"m": 1.0},
    "num coaches": {"-": 1.0},
    "num seats": {"-": 1.0},
    "max traction power": {"kW": 1.0, "MW": 1000.0, "W": 1e-3},
    "max reg braking power": {"kW": 1.0, "MW": 1000.0, "W": 1e-3},
    "max traction force": {"kN": 1.0, "N": 1e-3},
    "max reg braking force": {"kN": 1.0, "N": 1e-3},
    "max pn braking force": {"kN": 1.0, "N": 1e-3},
    "max acceleration": {"m/s^2": 1.0},
    "max deceleration": {"m/s^2": 1.0},
    "max speed": {"km/h": 1.0, "m/s": KMH_PER_MPS},
    "rolling resistance r0": {"kN": 1e3},
    "rolling resistance r1": {"kN/(km/h)": 1e3 * KMH_PER_MPS},
    "rolling resistance r2": {"kN/(km/h)^2": 1e3 * KMH_PER_MPS ** 2},
    "efficiency traction": {"%": 0.01, "-": 1.0},
    "efficiency reg brake": {"%": 0.01, "-": 1.0},
}
"""Accepted units of the train's scalar fields and their factor to the scenario unit."""

PRESET = "taipei_mrt_6car"
"""The preset an imported train takes what TTOBench does not give from (stated per value)."""

_TRAIN_KEYS: dict[str, tuple[str, str]] = {
    "mass": ("trains", "mass_kg"),
    "rho": ("stock", "rotating_allowance"),
    "length": ("trains", "length_m"),
    "num coaches": ("stock", "cars"),
    "max traction power": ("stock", "traction_power_kw"),
    "max reg braking power": ("stock", "regen_power_kw"),
    "max traction force": ("stock", "traction_force_kn"),
    "max reg braking force": ("stock", "regen_force_kn"),
    "max pn braking force": ("stock", "friction_brake_force_kn"),
    "max acceleration": ("stock", "accel_max_mps2"),
    "max deceleration": ("stock", "service_brake_mps2"),
    "max speed": ("trains", "max_speed_kmh"),
    "rolling resistance r0": ("stock", "davis_a_n"),
    "rolling resistance r1": ("stock", "davis_b_n_per_mps"),
    "rolling resistance r2": ("stock", "davis_c_n_per_mps2"),
    "efficiency traction": ("energy", "traction_efficiency"),
    "efficiency reg brake": ("energy", "regen_efficiency"),
}
"""TTOBench train field -> (scenario section, key)."""

_REQUIRED_TRAIN = ("mass", "max traction power", "max reg braking power", "max traction force",
                   "max reg braking force", "max speed", "rolling resistance r0",
                   "rolling resistance r1", "rolling resistance r2")
_UNREPRESENTABLE = {
    "tunnel resistance": "the plant has no tunnel aerodynamics",
    "tunnels": "the plant has no tunnel aerodynamics",
    "ETCS braking data": "ATP uses the scenario's own braking model, not ETCS curves",
}
"""Fields that cannot be represented (import refused unless dropped with --drop)."""

VENDORED = ("CN_Songjiazhuang_Yizhuang", "CN_Beijing_Subway")
"""TTOBench files shipped with the package (``metro_atc/data/ttobench``)."""


def data_dir() -> Path:
    """Directory of the vendored TTOBench files."""
    return Path(str(resources.files("metro_atc").joinpath("data", "ttobench")))


def resolve(name_or_path: str) -> Path:
    """Path of a TTOBench file given its path or vendored name."""
    p = Path(name_or_path)
    if p.is_file():
        return p
    q = data_dir() / f"{name_or_path}.json"
    if name_or_path in VENDORED and q.is_file():
        return q
    raise TtobenchError(f"ttobench {name_or_path}: file not found (vendored: "
                        f"{', '.join(VENDORED)})")


def load_json(name_or_path: str) -> tuple[str, dict[str, Any]]:
    """(file name, parsed JSON object) of a TTOBench file; one-line errors."""
    path = resolve(name_or_path)
    try:
        raw = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        msg = str(exc).replace("\n", " ")
        raise TtobenchError(f"ttobench {path.name}: cannot read JSON: {msg}") from None
    if not isinstance(raw, dict):
        raise TtobenchError(f"ttobench {path.name}: expected a JSON object at the top level")
    return path.name, raw


def _num(src: str, key: str, x: Any) -> float:
    if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x):
        raise TtobenchError(f"ttobench {src}: {key}: expected a finite number, got {x!r}")
    return float(x)


def _radius(src: str, key: str, x: Any) -> float:
    if isinstance(x, str) and x.strip().lower() in ("infinity", "inf"):
        return math.inf
    return _num(src, key, x)


def _scalar(src: str, d: dict[str, Any], key: str) -> float:
    """Value of a ``{"unit": u, "value": x}`` field converted with :data:`_UNITS`."""
    item = d[key]
    if not isinstance(item, dict) or "value" not in item:
        raise TtobenchError(f"ttobench {src}: {key}: expected {{unit, value}}, got {item!r}")
    unit = item.get("unit")
    table = _UNITS[key]
    if unit not in table:
        raise TtobenchError(f"ttobench {src}: {key}: unit {unit!r} not supported "
                            f"(expected one of {', '.join(table)})")
    return _num(src, key, item["value"]) * table[unit]


def _pairs(src: str, d: dict[str, Any], key: str, units: dict[str, str], width: int
           ) -> list[list[Any]]:
    item = d[key]
    if not isinstance(item, dict) or not isinstance(item.get("values"), list):
        raise TtobenchError(f"ttobench {src}: {key}: expected {{units, values: [...]}}")
    got = item.get("units", {})
    for name, unit in units.items():
        if not isinstance(got, dict) or got.get(name) != unit:
            raise TtobenchError(f"ttobench {src}: {key}: unit of {name} must be {unit!r}, "
                                f"got {got.get(name) if isinstance(got, dict) else got!r}")
    rows = item["values"]
    for i, r in enumerate(rows):
        if not isinstance(r, list) or len(r) != width:
            raise TtobenchError(f"ttobench {src}: {key}[{i}]: expected a list of {width}")
    for i in range(1, len(rows)):
        if _num(src, f"{key}[{i}]", rows[i][0]) <= _num(src, f"{key}[{i - 1}]", rows[i - 1][0]):
            raise TtobenchError(f"ttobench {src}: {key}[{i}]: positions must increase strictly")
    return rows


@dataclass
class Imported:
    """Result of an import: the scenario mapping (YAML-ready) and the statements made."""

    scenario: dict[str, Any]
    notes: list[str] = field(default_factory=list)

    def yaml_text(self) -> str:
        """The scenario as YAML, the notes as a comment header."""
        head = "".join(f"# {n}\n" for n in self.notes)
        return head + yaml.safe_dump(self.scenario, sort_keys=False, width=99)


def _check_fields(src: str, d: dict[str, Any], known: set[str], drop: set[str],
                  notes: list[str]) -> None:
    for key in d:
        if key in _UNREPRESENTABLE:
            if key in drop:
                notes.append(f"dropped on request: {src} '{key}' ({_UNREPRESENTABLE[key]})")
                continue
            raise TtobenchError(f"ttobench {src}: '{key}' cannot be represented "
                                f"({_UNREPRESENTABLE[key]}); pass --drop '{key}' to import "
                                "without it")
        if key not in known:
            raise TtobenchError(f"ttobench {src}: unknown field '{key}'")


def map_track(src: str, d: dict[str, Any], drop: set[str], notes: list[str]
              ) -> tuple[list[float], dict[str, Any], str]:
    """(stop positions [m], scenario ``line`` mapping, track id) of a TTOBench track."""
    _check_fields(src, d, {"metadata", "altitude", "stops", "speed limits", "gradients",
                           "curvatures"} | set(_UNREPRESENTABLE), drop, notes)
    for key in ("metadata", "stops", "speed limits"):
        if key not in d:
            raise TtobenchError(f"ttobench {src}: missing required field '{key}'")
    meta = d["metadata"]
    if not isinstance(meta, dict) or not isinstance(meta.get("id"), str):
        raise TtobenchError(f"ttobench {src}: metadata.id: expected a string")
    st = d["stops"]
    if not (isinstance(st, dict) and st.get("unit") == "m"
            and isinstance(st.get("values"), list)):
        raise TtobenchError(f"ttobench {src}: stops: expected {{unit: 'm', values: [...]}}")
    stops = [_num(src, f"stops[{i}]", x) for i, x in enumerate(st["values"])]
    if len(stops) < 2 or stops[0] != 0.0 or any(b <= a for a, b in zip(stops, stops[1:])):
        raise TtobenchError(f"ttobench {src}: stops: expected >= 2 strictly increasing "
                            "positions starting at 0")
    lim = _pairs(src, d, "speed limits", {"position": "m", "velocity": "km/h"}, 2)
    line: dict[str, Any] = {
        "stations": [{"name": f"{meta['id']} stop {i}", "code": f"S{i:02d}",
                      "position_m": x} for i, x in enumerate(stops)],
        "line_speed_kmh": _num(src, "speed limits[0]", lim[0][1]),
        "speed_limits": [{"start_m": _num(src, f"speed limits[{i}]", p),
                          "limit_kmh": _num(src, f"speed limits[{i}]", v)}
                         for i, (p, v) in enumerate(lim)],
    }
    if "gradients" in d:
        gr = _pairs(src, d, "gradients", {"position": "m", "slope": "permil"}, 2)
        line["gradients"] = [{"start_m": _num(src, f"gradients[{i}]", p),
                              "grade_permille": _num(src, f"gradients[{i}]", g)}
                             for i, (p, g) in enumerate(gr)]
    else:
        notes.append(f"{src}: no gradients: level track")
    if "curvatures" in d:
        cv = _pairs(src, d, "curvatures", {"position": "m", "radius at start": "m",
                                           "radius at end": "m"}, 3)
        curves = []
        n_clothoid = 0
        for i, (p, r0, r1) in enumerate(cv):
            a = _num(src, f"curvatures[{i}]", p)
            b = _num(src, f"curvatures[{i + 1}]", cv[i + 1][0]) if i + 1 < len(cv) else stops[-1]
            ra = abs(_radius(src, f"curvatures[{i}]", r0))
            rb = abs(_radius(src, f"curvatures[{i}]", r1))
            r = min(ra, rb)
            n_clothoid += int(ra != rb)
            if math.isfinite(r) and b > a:
                curves.append({"start_m": a, "end_m": b, "radius_m": min(max(r, 100.0), 1e5)})
        line["curves"] = curves
        if n_clothoid:
            notes.append(f"{src}: {n_clothoid} clothoid sections mapped to constant curves of "
                         "their tighter radius (curve resistance on the safe side)")
    if "altitude" in d:
        notes.append(f"{src}: altitude is informational (the gradients give the forces)")
    return stops, line, str(meta["id"])


def map_train(src: str, d: dict[str, Any], drop: set[str], notes: list[str],
              length_m: Optional[float] = None) -> tuple[dict[str, Any], dict[str, Any], str]:
    """(scenario ``trains`` mapping, ``energy`` mapping, train id) of a TTOBench train.

    ``length_m``: the train length [m] when the file has none (most TTOBench trains); a
    file without it and no ``length_m`` is refused (the length sets the platform stop, the
    ATP's rear and the separation).
    """
    _check_fields(src, d, {"metadata"} | set(_UNITS) | set(_UNREPRESENTABLE), drop, notes)
    for key in _REQUIRED_TRAIN:
        if key not in d:
            raise TtobenchError(f"ttobench {src}: missing required field '{key}'")
    meta = d.get("metadata")
    if not isinstance(meta, dict) or not isinstance(meta.get("id"), str):
        raise TtobenchError(f"ttobench {src}: metadata.id: expected a string")
    trains: dict[str, Any] = {}
    stock: dict[str, Any] = {}
    energy: dict[str, Any] = {}
    sections = {"trains": trains, "stock": stock, "energy": energy}
    for key, (sec, name) in _TRAIN_KEYS.items():
        if key in d:
            x = _scalar(src, d, key)
            sections[sec][name] = int(round(x)) if name == "cars" else x
    if "num seats" in d:
        notes.append(f"{src}: num seats = {_scalar(src, d, 'num seats'):g} (informational; "
                     "capacity_pax is the crush capacity, kept from the preset)")
    # TTOBench's mass is the mass it simulates (no passengers): the scenario's trains run
    # empty, so that mass is the empty mass (mass_load_pax 0), kept to the kilogram
    trains["mass_load_pax"] = 0.0
    if "length" in d:
        if length_m is not None:
            raise TtobenchError(f"ttobench {src}: length: given by the file "
                                f"({trains['length_m']:g} m) and by --length-m; give one")
    elif length_m is None:
        raise TtobenchError(f"ttobench {src}: missing field 'length' (this train has none: "
                            "give it with --length-m)")
    else:
        if not (math.isfinite(length_m) and 5.0 <= length_m <= 600.0):
            raise TtobenchError(f"ttobench {src}: --length-m: expected a length in [5, 600] m, "
                                f"got {length_m!r}")
        trains["length_m"] = float(length_m)
        notes.append(f"{src}: no length in TTOBench: train length {length_m:g} m given with "
                     "the import (--length-m)")
    _fit_preset_to_length(src, trains, stock, notes)
    if "max pn braking force" not in d:
        stock["friction_brake_force_kn"] = 0.0
    notes.append(f"{src}: guaranteed / nominal emergency deceleration not in TTOBench: "
                 "1.2 / 1.4 m/s^2 from the taipei_mrt_6car preset")
    trains["stock"] = stock
    return trains, energy, str(meta["id"])


def map_journey(src: str, d: dict[str, Any], stops: list[float], notes: list[str]
                ) -> tuple[list[int], Optional[float]]:
    """(indices of the track stops served, longest scheduled dwell [s]) of a journey."""
    _check_fields(src, d, {"metadata", "timing points"}, set(), notes)
    tp = d.get("timing points")
    if not isinstance(tp, dict) or not isinstance(tp.get("values"), list):
        raise TtobenchError(f"ttobench {src}: timing points: expected {{units, values}}")
    rows = tp["values"]
    served: list[int] = []
    dwells: list[float] = []
    last_dep: dict[float, float] = {}
    for i, r in enumerate(rows):
        if not isinstance(r, list) or len(r) != 5:
            raise TtobenchError(f"ttobench {src}: timing points[{i}]: expected a list of 5")
        pos = _num(src, f"timing points[{i}]", r[0])
        stopping = r[3] == 0 and r[4] == 0
        if not stopping:
            raise TtobenchError(f"ttobench {src}: timing points[{i}]: passing points (time "
                                "windows at speed) cannot be represented: the scenario "
                                "timetable is headway + running-time margin")
        if pos not in stops:
            raise TtobenchError(f"ttobench {src}: timing points[{i}]: position {pos} is not a "
                                "stop of the track")
        if pos in last_dep and r[1] is not None:
            dwells.append(_num(src, f"timing points[{i}]", r[1]) - last_dep[pos])
        if r[1] is not None:
            last_dep[pos] = _num(src, f"timing points[{i}]", r[1])
        k = stops.index(pos)
        if not served or served[-1] != k:
            served.append(k)
    if len(served) < 2:
        raise TtobenchError(f"ttobench {src}: timing points: expected two or more stops")
    notes.append(f"{src}: stations = the journey's {len(served)} stopping points; its time "
                 "windows are replaced by the scenario timetable (headway + margin)")
    return served, (max(dwells) if dwells else None)


def _fit_preset_to_length(src: str, trains: dict[str, Any], stock: dict[str, Any],
                          notes: list[str]) -> None:
    """Cars and crush capacity (not in TTOBench) of the preset, scaled to the train's length.

    The preset's car length and persons per metre times the train's length [m] (at least 2
    cars); kept as they are, and not written, where they equal the preset's.
    """
    pre = PRESETS[PRESET]
    length = float(trains["length_m"])
    if "cars" not in stock:
        cars = max(2, int(round(length / (pre.length_m / pre.cars))))
        if cars != pre.cars:
            stock["cars"] = cars
            notes.append(f"{src}: no number of coaches: {cars} cars of the {PRESET} preset's "
                         f"{pre.length_m / pre.cars:.3g} m in {length:g} m")
    if "capacity_pax" not in trains:
        cap = float(round(pre.capacity_pax / pre.length_m * length))
        if cap != pre.capacity_pax:
            trains["capacity_pax"] = cap
            notes.append(f"{src}: no crush capacity: {cap:g} persons, the {PRESET} preset's "
                         f"{pre.capacity_pax / pre.length_m:.3g} per metre x {length:g} m")


def _trim_to_line(line: dict[str, Any], length_m: float, notes: list[str]) -> None:
    """Drop / clip the track data outside the scenario's line; stated in ``notes``.

    A journey may serve part of the track: the loader refuses data off [first stop -
    length - 500 m, last stop + tail track]
    (:func:`metro_atc.core.line.scenario.line_extent_m`).
    """
    tail = float(next(f.default for f in dataclasses.fields(LineSpec)  # type: ignore[arg-type]
                      if f.name == "tail_track_m"))
    st = line["stations"]
    lo = st[0]["position_m"] - length_m - 500.0
    hi = st[-1]["position_m"] + tail
    n = 0
    for key in ("speed_limits", "gradients"):
        if key in line:
            keep = [e for e in line[key] if e["start_m"] < hi]
            n += len(line[key]) - len(keep)
            line[key] = keep
    if "curves" in line:
        curves = []
        for c in line["curves"]:
            a, z = max(c["start_m"], lo), min(c["end_m"], hi)
            n += int((a, z) != (c["start_m"], c["end_m"]))
            if z > a:
                curves.append({**c, "start_m": a, "end_m": z})
        line["curves"] = curves
    if n:
        notes.append(f"{n} speed-limit, gradient or curve entries beyond the served line "
                     f"[{lo:g}, {hi:g}] m dropped or clipped")


def import_ttobench(track: str, train: str, journey: Optional[str] = None, *,
                    n_trains: int = 3, headway_s: float = 300.0, dwell_s: float = 30.0,
                    margin: float = 0.10, drop: Sequence[str] = (),
                    length_m: Optional[float] = None) -> Imported:
    """Scenario mapping of a TTOBench track + train (+ journey); raises TtobenchError.

    ``length_m``: the train length [m] for a train file without one (:func:`map_train`).
    """
    drop_set = set(drop)
    bad = drop_set - set(_UNREPRESENTABLE)
    if bad:
        raise TtobenchError(f"ttobench: --drop accepts {', '.join(sorted(_UNREPRESENTABLE))}; "
                            f"got {', '.join(sorted(bad))}")
    notes: list[str] = []
    t_src, t_raw = load_json(track)
    r_src, r_raw = load_json(train)
    stops, line, track_id = map_track(t_src, t_raw, drop_set, notes)
    trains, energy, train_id = map_train(r_src, r_raw, drop_set, notes, length_m)
    served = list(range(len(stops)))
    if journey is not None:
        j_src, j_raw = load_json(journey)
        served, j_dwell = map_journey(j_src, j_raw, stops, notes)
        if j_dwell is not None:
            dwell_s = j_dwell
        line["stations"] = [line["stations"][k] for k in served]
    _trim_to_line(line, float(trains["length_m"]), notes)
    n_st = len(line["stations"])
    length = line["stations"][-1]["position_m"] - line["stations"][0]["position_m"]
    # duration: every train's journey at >= 8 m/s average plus dwells, turnback and a margin
    run_s = length / 8.0 + n_st * (dwell_s + 30.0)
    duration = 60.0 + (n_trains - 1) * headway_s + run_s + 900.0
    notes.append(f"timetable: not in the TTOBench files; defaults: {n_trains} trains every "
                 f"{headway_s:g} s, dwell >= {dwell_s:g} s (no passengers), scheduled running "
                 f"time = flat-out x {1 + margin:.2f}")
    scn = {
        "name": f"ttobench_{track_id}",
        "description": (f"TTOBench track {track_id} with train {train_id} (imported by "
                        "python -m metro_atc import ttobench)"),
        "sources": [f"TTOBench v1.5, {t_src} and {r_src} (Kouzoupis, Pendharkar, Corman, "
                    "OR Forum 4:67, 2023; BSD 2-Clause)"] + notes,
        "sim": {"control_period_s": 0.25, "duration_s": float(min(duration, 200_000.0))},
        "trains": {"count": int(n_trains), "preset": PRESET, **trains},
        "line": line,
        "signalling": {"mode": "moving_block", "safety_margin_m": 50.0},
        "timetable": {"first_departure_s": 60.0, "running_time_margin": float(margin),
                      "periods": [{"name": "base", "start_s": 0.0, "headway_s": float(headway_s),
                                   "boarding_pph": [0.0] * n_st}]},
        "passengers": {"door_overhead_s": float(dwell_s), "min_dwell_s": float(dwell_s),
                       "alight_fraction": [0.0] * (n_st - 1) + [1.0]},
        "disturbances": {"departure_delay_prob": 0.0, "running_time_noise": 0.0},
        "energy": energy,
    }
    out = Imported(scn, notes)
    try:
        parse_scenario(out.yaml_text(), f"ttobench_{track_id}.yaml")
    except ScenarioError as exc:
        raise TtobenchError(f"ttobench {t_src} + {r_src}: not representable: {exc}") from None
    return out


def export_ttobench(scn: Scenario) -> tuple[dict[str, Any], dict[str, Any]]:
    """(track, train) TTOBench objects of a scenario's line and rolling-stock data.

    Only what the import maps is exported (stops, limits, gradients, curves; the train's
    data keys); the inverse of :func:`import_ttobench` for the round-trip test.
    """
    ln = scn.line
    x0 = ln.stations[0].position_m
    track: dict[str, Any] = {
        "metadata": {"id": scn.name.removeprefix("ttobench_"), "library version": "TTOBench v1.5"},
        "stops": {"unit": "m", "values": [s.position_m - x0 for s in ln.stations]},
        "speed limits": {"units": {"position": "m", "velocity": "km/h"},
                         "values": [[s.start_m - x0, s.limit_kmh] for s in ln.speed_limits]},
    }
    if ln.gradients:
        track["gradients"] = {"units": {"position": "m", "slope": "permil"},
                              "values": [[g.start_m - x0, g.grade_permille]
                                         for g in ln.gradients]}
    tr = scn.trains
    st = tr.stock
    inv: dict[str, float | None] = {
        "mass": tr.mass_kg, "length": tr.length_m, "max speed": tr.max_speed_kmh,
        "rho": st.rotating_allowance, "num coaches": st.cars,
        "max traction power": st.traction_power_kw, "max reg braking power": st.regen_power_kw,
        "max traction force": st.traction_force_kn, "max reg braking force": st.regen_force_kn,
        "max pn braking force": st.friction_brake_force_kn,
        "max acceleration": st.accel_max_mps2, "max deceleration": st.service_brake_mps2,
        "rolling resistance r0": st.davis_a_n, "rolling resistance r1": st.davis_b_n_per_mps,
        "rolling resistance r2": st.davis_c_n_per_mps2,
        "efficiency traction": scn.energy.traction_efficiency,
        "efficiency reg brake": scn.energy.regen_efficiency,
    }
    train: dict[str, Any] = {"metadata": {"id": "exported", "library version": "TTOBench v1.5"}}
    for key, val in inv.items():
        if val is None:
            continue
        unit, factor = next(iter(_UNITS[key].items()))
        train[key] = {"unit": unit, "value": float(val) / factor}
    return track, train


def main(argv: Sequence[str] | None = None) -> int:
    """CLI: ``python -m metro_atc import ttobench ...`` (see the module docstring)."""
    ap = argparse.ArgumentParser(prog="python -m metro_atc import ttobench",
                                 description="TTOBench track + train (+ journey) -> scenario")
    ap.add_argument("--track", required=True, help="track JSON (path or vendored name)")
    ap.add_argument("--train", required=True, help="train JSON (path or vendored name)")
    ap.add_argument("--journey", help="journey JSON (stopping points select the stations)")
    ap.add_argument("--out", required=True, help="scenario YAML to write")
    ap.add_argument("--trains", type=int, default=3, help="number of trains (default 3)")
    ap.add_argument("--headway-s", type=float, default=300.0, help="headway [s] (300)")
    ap.add_argument("--dwell-s", type=float, default=30.0, help="dwell [s] (30)")
    ap.add_argument("--margin", type=float, default=0.10,
                    help="scheduled running time = flat-out x (1 + margin) (0.10)")
    ap.add_argument("--length-m", type=float, default=None,
                    help="train length [m] when the train file has none (else refused)")
    ap.add_argument("--drop", action="append", default=[],
                    help="leave out an unrepresentable field on purpose (repeatable)")
    a = ap.parse_args(list(argv) if argv is not None else None)
    try:
        imp = import_ttobench(a.track, a.train, a.journey, n_trains=a.trains,
                              headway_s=a.headway_s, dwell_s=a.dwell_s, margin=a.margin,
                              drop=a.drop, length_m=a.length_m)
        Path(a.out).write_text(imp.yaml_text(), encoding="utf-8")
    except (TtobenchError, OSError) as exc:
        print(f"metro_atc import: {exc}", file=sys.stderr)
        return 2
    for n in imp.notes:
        print(n)
    print(f"wrote {a.out}")
    return 0
