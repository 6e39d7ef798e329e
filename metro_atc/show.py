"""``python -m metro_atc show --scenario FILE [--json]``: the resolved scenario, with sources.

Prints the rolling stock every model uses (plant, ATO, ATP), the line and the signalling
after the defaults are applied, each value with where it came from: ``file`` (the scenario
gives it, with its key), ``preset NAME`` (the rolling-stock preset), ``preset NAME, scaled
to the file's mass`` (Davis A/B and the starting acceleration of a preset when the file
gives another mass), ``default`` (the schema's default) or ``derived``; then the timetable
summary (trains, first and last departure, fleet needed).  ROS-free; exit 0, or 2 with a
one-line error when the scenario is refused.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from metro_atc.core.line.adhesion import CURVES
from metro_atc.core.line.guarantee import level_guaranteed_decel
from metro_atc.core.line.rolling_stock import PRESETS, train_params_for
from metro_atc.core.line.scenario import (SCENARIO_NAMES, Scenario, ScenarioError,
                                          load_scenario, stock_key_path)
from metro_atc.core.line.vehicle import TrainParams, stock_data_of_spec
from metro_atc.core.safe_yaml import YamlLimitError, load_yaml_file

KMH = 3.6
"""m/s -> km/h."""

# (TrainParams attribute or derived name, meaning, unit, factor to the unit, data keys)
STOCK_ROWS: tuple[tuple[str, str, str, float, tuple[str, ...]], ...] = (
    ("mass_kg", "mass with the nominal load", "t", 1e-3, ("mass_kg", "tare_mass_kg")),
    ("tare_mass_kg", "empty mass", "t", 1e-3,
     ("tare_mass_kg", "mass_kg", "mass_load_pax", "pax_mass_kg")),
    ("nominal_load_pax", "load included in the mass", "persons", 1.0, ("mass_load_pax",)),
    ("pax_mass_kg", "mass of a passenger", "kg", 1.0, ("pax_mass_kg",)),
    ("capacity_pax", "crush capacity", "persons", 1.0, ("capacity_pax",)),
    ("length_m", "train length", "m", 1.0, ("length_m",)),
    ("cars", "cars", "", 1.0, ("cars",)),
    ("axles_per_car", "axles per car", "", 1.0, ("axles_per_car",)),
    ("motored_axle_fraction", "motored axles", "-", 1.0, ("motored_axle_fraction",)),
    ("max_speed_mps", "design maximum speed", "km/h", KMH, ("max_speed_kmh",)),
    ("rotary_allowance", "rotating-mass allowance", "-", 1.0, ("rotating_allowance",)),
    ("davis_a_n", "running resistance A", "N", 1.0, ("davis_a_n",)),
    ("davis_b_n_per_mps", "running resistance B", "N/(m/s)", 1.0, ("davis_b_n_per_mps",)),
    ("davis_c_n_per_mps2", "running resistance C", "N/(m/s)^2", 1.0, ("davis_c_n_per_mps2",)),
    ("traction_force_n", "tractive force at standstill", "kN", 1e-3,
     ("traction_force_kn", "accel_max_mps2")),
    ("a1_mps2", "starting acceleration at the nominal load", "m/s^2", 1.0,
     ("traction_force_kn", "accel_max_mps2")),
    ("v1_mps", "end of constant force", "km/h", KMH, ("traction_power_kw",)),
    ("v2_mps", "end of constant voltage (1e9: none)", "km/h", KMH, ("traction_power_kw",)),
    ("b2_mps", "traction b_2", "m/s", 1.0, ("traction_power_kw",)),
    ("b3_mps", "traction b_3", "m/s", 1.0, ("traction_power_kw",)),
    ("max_service_brake_mps2", "service deceleration", "m/s^2", 1.0,
     ("service_brake_mps2", "regen_force_kn", "friction_brake_force_kn")),
    ("service_brake_load_pax", "service brake load-weighed up to", "persons", 1.0,
     ("service_brake_load_pax",)),
    ("max_regen_power_w", "electric brake power", "kW", 1e-3, ("regen_power_kw",)),
    ("regen_fade_speed_mps", "electric brake fade-out below", "km/h", KMH,
     ("regen_fade_speed_kmh",)),
    ("emergency_brake_mps2", "guaranteed emergency deceleration", "m/s^2", 1.0,
     ("emergency_brake_mps2",)),
    ("emergency_brake_actual_mps2", "nominal emergency deceleration", "m/s^2", 1.0,
     ("emergency_brake_actual_mps2",)),
    ("max_jerk_mps3", "jerk limit", "m/s^3", 1.0, ("jerk_max_mps3",)),
    ("emergency_jerk_mps3", "emergency brake build-up", "m/s^3", 1.0, ("emergency_jerk_mps3",)),
    ("wheel_radius_m", "wheel radius", "m", 1.0, ("wheel_radius_m",)),
    ("wheel_inertia_kgm2", "wheelset inertia", "kg m^2", 1.0, ("wheel_inertia_kgm2",)),
    ("brake_radius_m", "disc-pad friction radius", "m", 1.0, ("brake_radius_m",)),
    ("pad_mu_nominal", "disc-pad friction coefficient", "-", 1.0, ("pad_mu_nominal",)),
    ("traction_efficiency", "traction efficiency", "-", 1.0, ("traction_efficiency",)),
    ("regen_efficiency", "regeneration efficiency", "-", 1.0, ("regen_efficiency",)),
    ("aux_power_w", "auxiliary power per train", "kW", 1e-3, ("aux_power_kw",)),
)
"""The rolling-stock figures shown (every TrainParams field; ``test_show`` checks it)."""

_MASS_SCALED = ("davis_a_n", "davis_b_n_per_mps", "a1_mps2")
"""Preset figures rescaled when the file gives another mass (train_params_from_data)."""


def _stock_value(p: TrainParams, attr: str) -> float:
    if attr == "traction_force_n":
        return p.mass_kg * p.a1_mps2
    if attr == "service_brake_load_pax" and p.service_brake_load_pax is None:
        return p.capacity_pax  # the default: load-weighed to crush
    return float(getattr(p, attr))


def stock_rows(scn: Scenario) -> list[dict[str, Any]]:
    """The resolved rolling stock: one dict (key, meaning, value, unit, source) per figure."""
    p = train_params_for(scn)
    preset = scn.trains.preset
    base = PRESETS[preset]
    given = {k for k, v in stock_data_of_spec(scn.trains, scn.energy).items() if v is not None}
    mass_given = p.mass_kg != base.mass_kg
    rows = []
    for attr, meaning, unit, factor, keys in STOCK_ROWS:
        used = [stock_key_path(k) for k in keys if k in given]
        if used:
            src = "file (" + ", ".join(used) + ")"
        elif attr in _MASS_SCALED and mass_given:
            src = f"preset {preset}, scaled to the file's mass"
        elif attr == "traction_force_n" and mass_given:
            src = f"preset {preset} (the preset's force)"
        else:
            src = f"preset {preset}"
        rows.append({"key": attr, "meaning": meaning, "value": _stock_value(p, attr) * factor,
                     "unit": unit, "source": src})
    return rows


def stock_line(scn: Scenario) -> str:
    """One compact line of the resolved rolling stock (``run`` logs it at start)."""
    p = train_params_for(scn)
    given = sum(v is not None for v in stock_data_of_spec(scn.trains, scn.energy).values())
    return (f"rolling stock {scn.trains.preset} + {given} file values: "
            f"{p.mass_kg / 1e3:.4g} t with {p.nominal_load_pax:g} persons "
            f"(empty {p.tare_mass_kg / 1e3:.4g} t, crush {p.capacity_pax:g}), "
            f"{p.length_m:g} m, {p.cars} cars, {p.max_speed_mps * KMH:.4g} km/h, "
            f"traction {p.mass_kg * p.a1_mps2 / 1e3:.4g} kN, service brake "
            f"{p.max_service_brake_mps2:g} m/s^2, emergency {p.emergency_brake_mps2:g} "
            f"guaranteed / {p.emergency_brake_actual_mps2:g} nominal m/s^2, aux "
            f"{p.aux_power_w / 1e3:g} kW (python -m metro_atc show: every value and its source)")


def _raw_keys(scn: Scenario) -> dict[str, Any]:
    """The parsed YAML of the scenario file ({} when it cannot be read again)."""
    name = scn.source_file
    path = Path(name)
    if not path.is_file():
        from importlib import resources
        stem = Path(name).stem
        if stem not in SCENARIO_NAMES:
            return {}
        path = Path(str(resources.files("metro_atc").joinpath("scenarios"))) / f"{stem}.yaml"
    try:
        raw = load_yaml_file(path)
    except (OSError, YamlLimitError):
        return {}
    return raw if isinstance(raw, dict) else {}


def _src(raw: dict[str, Any], section: str, key: str) -> str:
    sec = raw.get(section)
    return f"file ({section}.{key})" if isinstance(sec, dict) and key in sec else "default"


def line_rows(scn: Scenario, raw: dict[str, Any]) -> list[dict[str, Any]]:
    """The resolved line and signalling (value, unit, source) per figure."""
    ln, sg = scn.line, scn.signalling
    st = ln.stations
    rows: list[dict[str, Any]] = []

    def add(key: str, value: Any, unit: str, source: str) -> None:
        rows.append({"key": key, "value": value, "unit": unit, "source": source})
    add("stations", f"{len(st)}: {st[0].name} at {st[0].position_m:g} .. {st[-1].name} at "
        f"{st[-1].position_m:g}", "m", "file (line.stations)")
    gaps = np.diff([s.position_m for s in st])
    add("interstations", f"{gaps.min():g} .. {gaps.max():g}", "m", "derived")
    for key, unit in (("line_speed_kmh", "km/h"), ("tail_track_m", "m"), ("turnback_s", "s"),
                      ("turnback_sidings", ""), ("tail_speed_kmh", "km/h"),
                      ("block_length_m", "m"), ("stop_tolerance_m", "m"), ("adhesion", "")):
        add(f"line.{key}", getattr(ln, key), unit, _src(raw, "line", key))
    lims = [s.limit_kmh for s in ln.speed_limits]
    add("speed limits", f"{len(lims)} entries" + (f", {min(lims):g} .. {max(lims):g}"
                                                  if lims else ""), "km/h",
        "file (line.speed_limits)" if lims else "none")
    gr = [g.grade_permille for g in ln.gradients]
    add("gradients", f"{len(gr)} entries" + (f", steepest {min(gr):g} / +{max(gr):g}"
                                             if gr else ""), "permille",
        "file (line.gradients)" if gr else "none (level)")
    r_min = f", smallest radius {min(c.radius_m for c in ln.curves):g} m" if ln.curves else ""
    add("curves", f"{len(ln.curves)}{r_min}", "",
        "file (line.curves)" if ln.curves else "none")
    n_tsr = len(ln.temporary_speed_limits) + sum(i.kind == "tsr" for i in scn.incidents)
    add("temporary speed limits", n_tsr, "", "file" if n_tsr else "none")
    for key, unit in (("mode", ""), ("safety_margin_m", "m"), ("response_time_s", "s"),
                      ("overspeed_margin_kmh", "km/h"), ("sbi_lead_s", "s"),
                      ("tsr_notice_s", "s")):
        add(f"signalling.{key}", getattr(sg, key), unit, _src(raw, "signalling", key))
    add("signalling.guaranteed_decel_mps2",
        level_guaranteed_decel(sg.guaranteed_decel_mps2, train_params_for(scn),
                               CURVES[ln.adhesion]), "m/s^2",
        "file (signalling.guaranteed_decel_mps2)" if sg.guaranteed_decel_mps2 is not None
        else "derived: min(stock guaranteed emergency, 0.9 x locked-wheel adhesion, empty)")
    for key, unit in (("control_period_s", "s"), ("duration_s", "s"), ("grid_m", "m")):
        add(f"sim.{key}", getattr(scn.sim, key), unit, _src(raw, "sim", key))
    add("energy.regen_receptivity", scn.energy.regen_receptivity, "-",
        _src(raw, "energy", "regen_receptivity"))
    return rows


def timetable_summary(scn: Scenario) -> dict[str, Any]:
    """Trains, first / last departure, last arrival and the fleet needed.

    Fleet needed: the largest number of trains in service at once, a train being in service
    from its departure at the first station to the end of its turnback
    (arrival at the terminus + scheduled terminal dwell + ``line.turnback_s``).
    """
    from metro_atc.core.line.service import describe
    sv = describe(scn).service
    dep0 = np.asarray(sv.dispatch, dtype=float)
    arr = np.asarray(sv.sched_arr, dtype=float)[:, -1]
    dep = np.asarray(sv.sched_dep, dtype=float)[:, -1]
    end = np.where(np.isfinite(dep), dep, arr) + scn.line.turnback_s
    events = sorted([(float(t), 1) for t in dep0] + [(float(t), -1) for t in end])
    cur = peak = 0
    for _, d in events:
        cur += d
        peak = max(peak, cur)
    return {"trains": scn.trains.count, "first_departure_s": float(dep0.min()),
            "last_departure_s": float(dep0.max()), "last_arrival_s": float(arr.max()),
            "headways_s": [p.headway_s for p in scn.timetable.periods],
            "fleet_needed": peak,
            "running_time_s": float(np.sum(sv.sched_running_s)),
            "source": "file (timetable, trains.count); running times from the rolling stock"}


def resolved(scn: Scenario) -> dict[str, Any]:
    """The whole resolved view (stock, line, timetable) as plain data."""
    return {"scenario": scn.name, "file": scn.source_file, "preset": scn.trains.preset,
            "rolling_stock": stock_rows(scn), "line": line_rows(scn, _raw_keys(scn)),
            "timetable": timetable_summary(scn)}


def _fmt(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.6g}"
    return str(v)


def render(view: dict[str, Any]) -> str:
    """Text of :func:`resolved` (three aligned tables)."""
    out = [f"scenario {view['scenario']} ({view['file']}), rolling stock preset "
           f"{view['preset']}", "", "rolling stock:"]
    for r in view["rolling_stock"]:
        out.append(f"  {r['key']:<28} {_fmt(r['value']):>12} {r['unit']:<10} "
                   f"{r['meaning']}; {r['source']}")
    out += ["", "line and signalling:"]
    for r in view["line"]:
        out.append(f"  {r['key']:<34} {_fmt(r['value'])} {r['unit']}  [{r['source']}]")
    tt = view["timetable"]
    out += ["", "timetable:",
            f"  {tt['trains']} trains, first departure {tt['first_departure_s']:.0f} s, last "
            f"departure {tt['last_departure_s']:.0f} s, last arrival at the terminus "
            f"{tt['last_arrival_s']:.0f} s; headways "
            f"{', '.join(f'{h:g}' for h in tt['headways_s'])} s; scheduled running time "
            f"{tt['running_time_s']:.0f} s end to end",
            f"  fleet needed: {tt['fleet_needed']} trains in service at once"]
    return "\n".join(out)


def main(argv: Sequence[str] | None = None) -> int:
    """Command-line entry point (module docstring)."""
    ap = argparse.ArgumentParser(prog="python -m metro_atc show",
                                 description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", required=True, help="scenario name or YAML file")
    ap.add_argument("--json", action="store_true", help="print JSON instead of text")
    a = ap.parse_args(argv)
    try:
        scn = load_scenario(a.scenario)
        view = resolved(scn)
    except (ScenarioError, ValueError) as exc:
        print(f"metro_atc show: error: {exc}", file=sys.stderr)
        return 2
    print(json.dumps(view, indent=1) if a.json else render(view))
    return 0
