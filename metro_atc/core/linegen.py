"""Generator of realistic random metro lines as scenario dicts (ROS-free).

:func:`generate_line` draws one line from a seed and returns a scenario mapping valid for
:func:`metro_atc.core.line.scenario.parse_scenario` (:func:`scenario_yaml` gives the YAML,
which ``python -m metro_atc run --scenario FILE`` runs as well).  What is drawn (SI unless
the scenario key says otherwise):

- **stations**: 6-15 (or ``n_stations``), spacing uniform in [0.5, 3] km (metro practice:
  0.5-1.5 km downtown, 2-3 km suburban);
- **vertical profile**: between the platforms, grade segments 150-700 m long with grades up
  to +-40 per mille (the rolling stock's ``max_grade_permille``), drawn as a bounded random
  walk so consecutive grades are related, elevation kept within +-35 m of the first
  platform (tunnel/viaduct transitions); every platform lies on a level or gentle (<= 2 per
  mille) section from 250 m before to 100 m beyond the stop point;
- **curves**: 0-2 per inter-station run with a curve speed limit of 40-60 km/h (5 km/h
  steps) and radius ``R = v^2 / 0.65`` (v in m/s: 0.65 m/s^2 of lateral acceleration, cant
  plus cant deficiency), at least 250 m from the platforms;
- **timetable**: one period, headway 90-300 s, 6-12 trains (or ``n_trains``), boarding demand
  2-12 k persons/h per station;
- **rolling stock**: the presets ``taipei_mrt_6car`` (optionally a 4-car variant through the
  length/mass/capacity overrides, or a +-10 % mass override) and ``thsr_700t`` (regional
  use; grades to +-20 per mille, line speed 130 km/h); in the extended corpus
  (``extended=True``, ``python -m metro_atc bench lines``) also light stock (two cars,
  20-40 m, 30-70 t empty) and heavy 8-car stock (300-450 t empty, 100-120 km/h),
  every figure given (:func:`drawn_stock`), and interstations dense (300-600 m), long
  (3-6 km, at most 8 stations) or mixed;
- **incidents** (``incidents=True``): one TSR of 25-40 km/h on 150-400 m between two
  stations (preferably on a descent), in force for 900 s from the second train's departure;
  a breakdown of one train for 60-150 s in mid-run.

Disturbances (departure delays, traction noise) keep the scenario defaults.  The generator
never reads files; ``seed`` makes it deterministic.
"""

from __future__ import annotations

import math
from typing import Any, Optional

import numpy as np
import yaml

from metro_atc.core.line.scenario import Scenario, parse_scenario

STOCKS: dict[str, dict[str, Any]] = {
    "taipei_mrt_6car": {"preset": "taipei_mrt_6car", "line_speed_kmh": 80.0,
                        "max_grade_permille": 40.0, "overrides": {}},
    "taipei_mrt_6car_heavy": {"preset": "taipei_mrt_6car", "line_speed_kmh": 80.0,
                              "max_grade_permille": 40.0,
                              "overrides": {"mass_kg": 235_000.0, "mass_load_pax": 1000.0}},
    "taipei_mrt_4car": {"preset": "taipei_mrt_6car", "line_speed_kmh": 80.0,
                        "max_grade_permille": 40.0,
                        "overrides": {"mass_kg": 143_000.0, "mass_load_pax": 1000.0,
                                      "length_m": 94.0, "capacity_pax": 1260.0}},
    "thsr_700t_regional": {"preset": "thsr_700t", "line_speed_kmh": 130.0,
                           "max_grade_permille": 20.0, "overrides": {}},
    "light_metro": {"preset": "taipei_mrt_6car", "line_speed_kmh": 70.0,
                    "max_grade_permille": 40.0, "overrides": {}},
    "heavy_metro_8car": {"preset": "taipei_mrt_6car", "line_speed_kmh": 110.0,
                         "max_grade_permille": 30.0, "overrides": {}},
}
"""Rolling-stock variants the generator draws from (presets plus overrides).  The first four
are the classic corpus; ``light_metro`` and ``heavy_metro_8car`` (extended corpus) get their
figures drawn per line by :func:`drawn_stock`."""

CLASSIC_STOCKS = ("taipei_mrt_6car", "taipei_mrt_6car_heavy", "taipei_mrt_4car",
                  "thsr_700t_regional")
"""The stocks of the classic corpus (drawn with probabilities 0.4, 0.2, 0.25, 0.15)."""

SPACINGS: dict[str, tuple[float, float]] = {
    "classic": (500.0, 3000.0), "dense": (300.0, 600.0), "long": (3000.0, 6000.0)}
"""Interstation ranges [m]: metro practice, dense downtown, long suburban / regional."""


def drawn_stock(name: str, rng: np.random.Generator) -> dict[str, Any]:
    """Scenario ``trains`` keys of a drawn light or heavy stock (every figure given).

    - ``light_metro``: two cars (a motor and a trailer car), 20-40 m, empty 30-70 t, 5
      persons per metre at crush
      load, 1.1-1.3 m/s^2 starting acceleration (empty), 60-80 km/h;
    - ``heavy_metro_8car``: 8 cars of 22-24 m, empty 300-450 t, 2 400-3 000 persons at
      crush load, 1.0 m/s^2 starting acceleration (empty), 100-120 km/h line speed.

    Traction force F = a_start x empty mass, constant up to 35-40 km/h then constant power
    (the electric brake's power limit too);
    Davis A and B of the Taipei 6-car (ACTP n.d., eq. 2) per kilogram, C from the frontal
    area (estimates); brakes: 1.0-1.1 m/s^2 service, 1.2 guaranteed / 1.4 nominal emergency.
    """
    if name == "light_metro":
        cars = 2
        length = round(float(rng.uniform(20.0, 40.0)), 1)
        tare = round(float(rng.uniform(30.0, 70.0)), 1) * 1000.0
        cap = round(5.0 * length, 0)
        a0, v1_kmh, vmax_kmh, c_n = float(rng.uniform(1.1, 1.3)), 35.0, 80.0, 3.0
        aux_kw = round(float(rng.uniform(20.0, 40.0)), 0)
    elif name == "heavy_metro_8car":
        cars = 8
        length = round(8 * float(rng.uniform(22.0, 24.0)), 1)
        tare = round(float(rng.uniform(300.0, 450.0)), 1) * 1000.0
        cap = round(float(rng.uniform(2400.0, 3000.0)), -1)
        a0, v1_kmh, vmax_kmh, c_n = 1.0, 40.0, 130.0, 12.0
        aux_kw = round(float(rng.uniform(250.0, 400.0)), 0)
    else:
        raise ValueError(f"no drawn figures for rolling stock {name!r}")
    f_n = a0 * tare
    return {
        "tare_mass_kg": tare, "mass_load_pax": 0.0, "length_m": length,
        "capacity_pax": cap, "max_speed_kmh": vmax_kmh,
        "stock": {"cars": cars, "traction_force_kn": round(f_n / 1000.0, 1),
                  "traction_power_kw": round(f_n * v1_kmh / 3.6 / 1000.0, 0),
                  "regen_power_kw": round(f_n * v1_kmh / 3.6 / 1000.0, 0),
                  "davis_a_n": round(0.020084 * tare, 1),
                  "davis_b_n_per_mps": round(5.04e-4 * tare, 2), "davis_c_n_per_mps2": c_n,
                  "service_brake_mps2": round(float(rng.uniform(1.0, 1.1)), 2),
                  "emergency_brake_mps2": 1.2, "emergency_brake_actual_mps2": 1.4},
        "aux": aux_kw,
    }


LAT_ACCEL_MPS2 = 0.65
"""Lateral acceleration allowed in curves (cant + cant deficiency) [m/s^2]."""


def _profile(rng: np.random.Generator, stations: list[float], max_g: float
             ) -> list[dict[str, float]]:
    """Grade step function: gentle at the platforms, a bounded random walk between."""
    grades: list[dict[str, float]] = [{"start_m": stations[0] - 2000.0, "grade_permille": 0.0}]
    elev = 0.0
    g_prev = 0.0
    for a, b in zip(stations[:-1], stations[1:]):
        x = a + 100.0
        grades.append({"start_m": x, "grade_permille": 0.0})
        end = b - 250.0
        x_free = x + 150.0
        if end - x_free < 150.0:
            continue  # short run: level between the platforms
        x = x_free
        while x < end - 1e-6:
            seg = float(rng.uniform(150.0, 700.0))
            if end - (x + seg) < 150.0:
                seg = end - x
            g = float(np.clip(g_prev + rng.normal(0.0, 0.6 * max_g), -max_g, max_g))
            # keep the elevation within +-35 m of the first platform
            room_up = (35.0 - elev) / seg * 1000.0
            room_down = (-35.0 - elev) / seg * 1000.0
            g = float(np.clip(g, max(room_down, -max_g), min(room_up, max_g)))
            g = round(g, 1)
            grades.append({"start_m": round(x, 1), "grade_permille": g})
            elev += g * seg / 1000.0
            g_prev = g
            x += seg
        g_st = float(np.clip(-elev / 350.0 * 1000.0, -2.0, 2.0))
        grades.append({"start_m": round(end, 1), "grade_permille": round(g_st, 1)})
        elev += g_st * 350.0 / 1000.0
        g_prev = 0.0
    grades.append({"start_m": stations[-1] + 100.0, "grade_permille": 0.0})
    return grades


def _curves(rng: np.random.Generator, stations: list[float], line_kmh: float
            ) -> tuple[list[dict[str, float]], list[dict[str, float]]]:
    """Curve speed limits (step function entries) and the curves themselves."""
    limits: list[dict[str, float]] = [{"start_m": stations[0] - 2000.0, "limit_kmh": line_kmh}]
    curves: list[dict[str, float]] = []
    for a, b in zip(stations[:-1], stations[1:]):
        lo, hi = a + 250.0, b - 250.0
        n = int(rng.integers(0, 3))
        x = lo
        for _ in range(n):
            length = float(rng.uniform(150.0, 500.0))
            if hi - x < length + 50.0:
                break
            start = float(rng.uniform(x, hi - length))
            v_kmh = float(rng.choice([40.0, 45.0, 50.0, 55.0, 60.0]))
            v_kmh = min(v_kmh, line_kmh)
            radius = max((v_kmh / 3.6) ** 2 / LAT_ACCEL_MPS2, 100.0)
            limits.append({"start_m": round(start, 1), "limit_kmh": v_kmh})
            limits.append({"start_m": round(start + length, 1), "limit_kmh": line_kmh})
            curves.append({"start_m": round(start, 1), "end_m": round(start + length, 1),
                           "radius_m": round(radius, 1)})
            x = start + length + 100.0
    return limits, curves


def generate_line(seed: int, incidents: bool = False, n_stations: Optional[int] = None,
                  n_trains: Optional[int] = None, stock: Optional[str] = None,
                  extended: bool = False, spacing_kind: Optional[str] = None
                  ) -> dict[str, Any]:
    """One random line as a scenario mapping (module docstring); deterministic in ``seed``.

    ``extended``: the extended corpus: the stock is drawn from every :data:`STOCKS` entry
    (light and heavy included) and the interstations from :data:`SPACINGS` or a mix of them
    (``spacing_kind`` forces one: ``classic``, ``dense``, ``long``, ``mixed``).  These draws
    come from a second random stream, so the classic corpus (``extended=False``) is the
    same line for line.
    """
    rng = np.random.default_rng([int(seed), 11])
    ext = np.random.default_rng([int(seed), 11, 2026])
    stock_name = stock if stock is not None else str(rng.choice(
        list(CLASSIC_STOCKS), p=[0.4, 0.2, 0.25, 0.15]))
    if extended and stock is None:
        stock_name = str(ext.choice(list(STOCKS)))
    if stock_name not in STOCKS:
        raise ValueError(f"unknown rolling stock {stock_name!r}; expected one of "
                         f"{', '.join(STOCKS)}")
    rs = STOCKS[stock_name]
    n_st = int(n_stations) if n_stations is not None else int(rng.integers(6, 16))
    if not 2 <= n_st <= 60:
        raise ValueError(f"n_stations must be in [2, 60], got {n_st}")
    spacing = rng.uniform(500.0, 3000.0, n_st - 1)
    if rs["preset"] == "thsr_700t":
        spacing = rng.uniform(2000.0, 3000.0, n_st - 1)  # a 304 m train, 130 km/h
    kind = spacing_kind if spacing_kind is not None else \
        str(ext.choice(["classic", "dense", "long", "mixed"])) if extended else "classic"
    if kind not in (*SPACINGS, "mixed"):
        raise ValueError(f"unknown spacing {kind!r}; expected one of "
                         f"{', '.join(SPACINGS)}, mixed")
    if kind != "classic" and rs["preset"] != "thsr_700t":
        if kind == "long" and n_stations is None:
            n_st = min(n_st, 8)  # a 3-6 km interstation line of 15 stations is 80 km
        kinds = [kind] * (n_st - 1) if kind != "mixed" else \
            [str(k) for k in ext.choice(list(SPACINGS), n_st - 1)]
        spacing = np.array([ext.uniform(*SPACINGS[k]) for k in kinds])
    drawn = drawn_stock(stock_name, ext) if not rs["overrides"] and \
        stock_name in ("light_metro", "heavy_metro_8car") else None
    pos = [0.0] + [round(float(x), 1) for x in np.cumsum(spacing)]
    line_kmh = float(rs["line_speed_kmh"])
    if drawn is not None and stock_name == "heavy_metro_8car":
        line_kmh = float(ext.choice([100.0, 110.0, 120.0]))
    grades = _profile(rng, pos, float(rs["max_grade_permille"]))
    limits, curves = _curves(rng, pos, line_kmh)
    headway = float(rng.integers(18, 61) * 5)  # 90 .. 300 s
    n_tr = int(n_trains) if n_trains is not None else int(rng.integers(6, 13))
    boarding = [round(float(x), -1) for x in rng.uniform(2000.0, 12000.0, n_st)]
    boarding[-1] = 0.0
    alight = [0.0] + [round(float(x), 2) for x in rng.uniform(0.1, 0.4, n_st - 2)] + [1.0]
    first_dep = 60.0
    # running time estimate for the duration: 45 s per km plus 40 s dwell per station
    t_line = 45.0 * pos[-1] / 1000.0 + 40.0 * n_st
    duration = first_dep + n_tr * headway + t_line + 900.0
    trains: dict[str, Any] = {"count": n_tr, "preset": rs["preset"], "initial_load_pax": 200}
    trains.update(rs["overrides"])
    energy: dict[str, Any] = {}
    if drawn is not None:
        energy["aux_power_kw"] = drawn.pop("aux")
        trains.update(drawn)
        trains["initial_load_pax"] = min(200, int(0.5 * drawn["capacity_pax"]))
    scn: dict[str, Any] = {
        "name": f"gen_{int(seed):04d}{'_inc' if incidents else ''}",
        "description": (f"generated line (metro_atc.core.linegen, seed {int(seed)}): "
                        f"{n_st} stations over {pos[-1] / 1000.0:.1f} km, {stock_name}, "
                        f"{kind} interstations, "
                        f"headway {headway:.0f} s"),
        "sources": ["all data generated (estimates of metro practice, see linegen docs)"],
        "sim": {"control_period_s": 0.25, "duration_s": round(duration, 0)},
        "trains": trains,
        "line": {
            "stations": [{"name": f"Station {j + 1}", "code": f"G{j + 1:02d}",
                          "position_m": x} for j, x in enumerate(pos)],
            "line_speed_kmh": line_kmh, "speed_limits": limits, "gradients": grades,
            "curves": curves,
            "tail_track_m": 400.0 if rs["preset"] == "thsr_700t" or
            stock_name == "heavy_metro_8car" else 300.0,
            "turnback_s": 60.0},
        "signalling": {"mode": "moving_block", "safety_margin_m": 50.0},
        "timetable": {"first_departure_s": first_dep, "periods": [
            {"name": "peak", "start_s": 0.0, "headway_s": headway,
             "boarding_pph": boarding}]},
        "passengers": {"boarding_s_per_pax": 0.02, "alighting_s_per_pax": 0.015,
                       "door_overhead_s": 12.0, "min_dwell_s": 20.0,
                       "alight_fraction": alight},
    }
    if energy:
        scn["energy"] = energy
    if incidents:
        scn["incidents"] = _incidents(rng, pos, grades, n_tr, headway, first_dep)
    return scn


def _incidents(rng: np.random.Generator, pos: list[float], grades: list[dict[str, float]],
               n_tr: int, headway: float, first_dep: float) -> list[dict[str, Any]]:
    """A TSR between two stations (on a descent if there is one) and a breakdown."""
    starts = np.array([g["start_m"] for g in grades])
    vals = np.array([g["grade_permille"] for g in grades])
    runs = [(a, b) for a, b in zip(pos[:-1], pos[1:]) if b - a >= 1000.0] or \
        [(pos[0], pos[1])]

    # prefer the run holding the steepest descent
    def steepest(r: tuple[float, float]) -> float:
        m = (starts >= r[0]) & (starts < r[1])
        return float(np.min(vals[m])) if np.any(m) else 0.0
    a, b = min(runs, key=steepest) if rng.uniform() < 0.7 else \
        runs[int(rng.integers(0, len(runs)))]
    length = float(rng.uniform(150.0, 400.0))
    lo, hi = a + 350.0, b - 450.0 - length
    start = float(rng.uniform(lo, hi)) if hi > lo else 0.5 * (a + b) - 0.5 * length
    out: list[dict[str, Any]] = [{
        "kind": "tsr", "at_s": first_dep + headway, "duration_s": 900.0,
        "start_m": round(start, 1), "end_m": round(start + length, 1),
        "limit_kmh": float(rng.choice([25.0, 30.0, 35.0, 40.0]))}]
    victim = int(rng.integers(1, max(n_tr - 1, 2)))
    t_run = first_dep + victim * headway + 45.0 * (pos[len(pos) // 2] / 1000.0) + 30.0
    out.append({"kind": "breakdown", "train": f"train_{victim + 1:02d}",
                "at_s": round(t_run, 0), "duration_s": float(rng.integers(60, 151))})
    return out


def scenario_yaml(scn: dict[str, Any]) -> str:
    """YAML text of a generated scenario mapping (``math.inf`` never appears)."""
    return yaml.safe_dump(scn, sort_keys=False, default_flow_style=None, width=99)


def load_generated(seed: int, incidents: bool = False, **kwargs: Any) -> Scenario:
    """:func:`generate_line` validated by the scenario loader."""
    return load_generated_named(seed, incidents, **kwargs)[1]


def load_generated_named(seed: int, incidents: bool = False, **kwargs: Any
                         ) -> tuple[str, Scenario]:
    """(rolling-stock variant name of :data:`STOCKS`, scenario) of :func:`load_generated`."""
    scn = generate_line(seed, incidents=incidents, **kwargs)
    name = next(k for k in sorted(STOCKS, key=len, reverse=True)
                if f", {k}, " in scn["description"])
    return name, parse_scenario(scenario_yaml(scn), src=f"<generated line {scn['name']}>")


def elevation_m(scn: dict[str, Any], x_m: float) -> float:
    """Elevation [m] at chainage x relative to the start of the grade profile."""
    g = scn["line"]["gradients"]
    h = 0.0
    for cur, nxt in zip(g, g[1:] + [{"start_m": math.inf}]):
        a, b = cur["start_m"], min(nxt["start_m"], x_m)
        if b > a:
            h += cur["grade_permille"] / 1000.0 * (b - a)
    return h
