"""Generated two-direction service days on generated lines (ROS-free).

:func:`generate_day` draws a line with :func:`metro_atc.core.linegen.generate_line` (the
extended corpus: light and heavy stock, dense, long and mixed interstations; 4-7 stations
unless given) and a day for it as a period table of the same schema as the shipped
``metro_atc/data/taipei_blue_day_periods.yaml``, validated by
:func:`metro_atc.core.service.day.parse_day` against the line's traffic model
(:func:`metro_atc.core.atr.lines.atr_line_for`).  What is drawn (SI unless a key says
otherwise; every figure an estimate of metro practice):

- **termini**: per terminus a scissors crossover before the platform (reversal at the
  platform, 60-150 s) or a tail track with one or two sidings beyond it (reversal in the
  siding, 30-90 s); a scissors whose crossover would lie on the neighbouring station's
  platform, or whose entry signal would stand within the ATO's authority margin of that
  platform's stop point (:func:`metro_atc.core.service.loop.check_crossovers`), becomes a
  tail track; crossover limit 25-40 km/h; platforms and sidings 10-20 m longer than the
  train; the
  minimum turnback is the layout's lower bound
  (:meth:`metro_atc.core.service.interlocking.Layout.min_turnback_s`) plus two minimum
  dwells (alighting, boarding), rounded up to 10 s; a turnback buffer of 0-60 s;
- **depots**: at both termini, or at the first one only (then the down direction starts a
  trip time plus a layover later, :func:`metro_atc.core.service.day.trips`);
- **periods**: three from 06:00, ``early`` (30-45 min), ``peak`` (60-75 min) and ``late``
  (30-45 min); the peak headway is the line's drawn headway raised until the fleet stays
  within ``max_fleet`` (cycle time / headway) and the termini turn trains with a berth to
  spare (layover + headway within the berths' time); off-peak headways 1.5-2.5 times the
  peak's; flow factors 0.4-0.6 off peak, 0.6-1.0 down in the peak; a 0-300 s transition;
- **stop tolerance**: the plant takes a standstill as the arrival within the
  platform-screen-door window (+-0.30 m, the ATO's berthing window) instead of the
  scenario default of 1.0 m: a train at rest further short creeps on;
- **fleet**: what the circulation of the plant-timed trips needs
  (:func:`metro_atc.core.service.day.run_day`), plus 0-1 spare;
- **incidents** (``incidents=True``): a hold of 60-240 s at an intermediate station of a
  peak trip in each direction.

The day runs on the plant with :func:`run_generated_day`
(:func:`metro_atc.core.service.dayplant.service_day`, the plant's trip times).  ``seed``
makes everything deterministic; the line is that of ``generate_line(seed, extended=True,
n_stations=...)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Dict, List, Mapping, Optional, Sequence, Tuple

import numpy as np

from metro_atc.core.atr.blue_line import LineData
from metro_atc.core.atr.lines import atr_line_for
from metro_atc.core.closed_loop import STOP_WINDOW_M
from metro_atc.core.line.rolling_stock import train_params_for
from metro_atc.core.line.scenario import Scenario, parse_scenario
from metro_atc.core.linegen import generate_line, scenario_yaml

from .day import DayError, DayPlan, _layout, parse_day, trip_time_s, trips
from .dayplant import Breakdown, DayPlant, DayResult, service_day
from .interlocking import Layout
from .loop import LoopError, build_loop

MAX_FLEET = 14
"""Largest fleet a generated day may need (keeps a day's wall time at seconds to minutes)."""
START_H = 6.0
"""First period's start [h after midnight]."""


@dataclass(frozen=True)
class GeneratedDay:
    """A generated line and its day: the scenario, the period table and the disturbances.

    ``table``: the period table mapping (schema of the shipped day YAML); ``plan``: it
    validated; ``holds[(trip id, station index)]`` [s]: incidents; ``stock``: the rolling
    stock variant of :data:`metro_atc.core.linegen.STOCKS`.
    """

    name: str
    scenario: Scenario
    line: LineData
    table: Dict[str, Any]
    plan: DayPlan
    stock: str
    holds: Dict[Tuple[str, int], float] = field(default_factory=dict)


def _ceil_to(x: float, step: float) -> float:
    return float(math.ceil(x / step - 1e-9) * step)


def _terminus(rng: np.random.Generator, code: str, kind: str, train_m: float,
              min_dwell_s: float, depot: bool) -> Dict[str, Any]:
    """A terminus entry of the period table (drawn figures, see the module docstring)."""
    plat = _ceil_to(train_m + float(rng.uniform(10.0, 20.0)), 10.0)
    out: Dict[str, Any] = {
        "station": code, "layout": kind,
        "reversal_s": float(rng.integers(12, 31) * 5) if kind == "scissors"
        else float(rng.integers(6, 19) * 5),
        "crossover_speed_kmh": float(rng.choice([25.0, 30.0, 35.0, 40.0])),
        "platform_m": plat}
    if kind == "tail_track":
        out["n_sidings"] = int(rng.integers(1, 3))
        out["siding_m"] = plat
    lay: Layout = _layout({**out, "min_turnback_s": 0.0}, code, "generated")
    out["min_turnback_s"] = _ceil_to(lay.min_turnback_s(0) + 2.0 * min_dwell_s, 10.0)
    out["turnback_buffer_s"] = float(rng.integers(0, 7) * 10)
    out["depot"] = f"depot {code}" if depot else None
    out["depot_station"] = code if depot else None
    return out


def _layouts(table: Mapping[str, Any]) -> Tuple[Layout, Layout]:
    """The two terminus layouts of a period table, read as :func:`parse_day` reads them."""
    a, b = (_layout(t, f"termini[{i}]", "generated") for i, t in enumerate(table["termini"]))
    return a, b


def generate_day(seed: int, incidents: bool = False, n_stations: Optional[int] = None,
                 stock: Optional[str] = None, spacing_kind: Optional[str] = None,
                 max_fleet: int = MAX_FLEET,
                 period_min: Optional[Tuple[float, float, float]] = None) -> GeneratedDay:
    """One generated line and its day (module docstring); deterministic in ``seed``.

    ``period_min``: the three periods' lengths [min] instead of the drawn ones (short days
    for tests).

    ValueError (one line, naming the period and the fleet or headway it needs) when the
    drawn line cannot carry a day: a fleet above ``max_fleet`` (the circulation's
    :class:`metro_atc.core.service.day.DayError`), a peak headway above 1200 s.
    """
    rng = np.random.default_rng([int(seed), 11, 7, 2026])
    n_st = int(n_stations) if n_stations is not None else int(rng.integers(4, 8))
    raw = generate_line(seed, extended=True, n_stations=n_st, stock=stock,
                        spacing_kind=spacing_kind)
    stock_name = raw["description"].split(", ")[2]
    # the plant takes a standstill within the platform-screen-door window as the arrival
    # (the ATO's berthing window): a train at rest further short creeps on to the stop point
    raw["line"]["stop_tolerance_m"] = STOP_WINDOW_M
    scn = parse_scenario(scenario_yaml(raw), src=f"<generated line {raw['name']}>")
    line = atr_line_for(scn)
    codes = [s.code for s in scn.line.stations]
    train_m = float(train_params_for(scn).length_m)
    min_dwell = float(scn.passengers.min_dwell_s)
    both_depots = bool(rng.uniform() < 0.6)
    kinds = [str(rng.choice(["scissors", "tail_track"])) for _ in range(2)]
    termini = [_terminus(rng, codes[0], kinds[0], train_m, min_dwell, True),
               _terminus(rng, codes[-1], kinds[1], train_m, min_dwell, both_depots)]
    for _ in range(3):  # a scissors the loop refuses (on a platform, too close): a tail track
        try:
            build_loop(scn, _layouts({"termini": termini}))
            break
        except LoopError as exc:  # A's refusal comes first (the loop checks A, then B)
            bad = [i for i in (0, 1) if termini[i]["layout"] == "scissors"
                   and f"terminus {codes[-1 if i else 0]} (scissors)" in str(exc)]
            if not bad:
                raise
            i = bad[0]
            termini[i] = _terminus(rng, codes[-1 if i else 0], "tail_track", train_m,
                                   min_dwell, termini[i]["depot"] is not None)
    lays = _layouts({"termini": termini})
    layover = [float(t["min_turnback_s"]) + float(t["turnback_buffer_s"]) for t in termini]
    # the peak headway: the line's, raised so that every terminus turns its trains with a
    # berth to spare (layover + one headway of waiting within the berths' time) and the
    # fleet stays within max_fleet
    h = float(raw["timetable"]["periods"][0]["headway_s"])
    for lay, lo in zip(lays, layover):
        h = max(h, _ceil_to(lo / max(len(lay.berths) - 1, 1), 10.0),
                _ceil_to(lay.min_headway_s(lo), 10.0))
    trip_s = trip_time_s(line, h, 1.0)
    cycle = 2.0 * trip_s + sum(layover)
    h = max(h, _ceil_to(1.15 * cycle / max_fleet, 10.0))
    if h > 1200.0:
        raise ValueError(f"generated day {seed}: period peak: a {cycle:.0f} s cycle needs a "
                         f"headway of {h:.0f} s for {max_fleet} trains (above 1200 s)")
    h_off = min(_ceil_to(h * float(rng.uniform(1.5, 2.5)), 10.0), 1800.0)
    mins = [float(rng.integers(6, 10) * 5), float(rng.integers(12, 16) * 5),
            float(rng.integers(6, 10) * 5)]
    if period_min is not None:
        mins = [float(m) for m in period_min]
    bounds = np.cumsum([START_H * 60.0] + mins) / 60.0
    off = (round(float(rng.uniform(0.4, 0.6)), 2), round(float(rng.uniform(0.4, 0.6)), 2))
    periods: List[Dict[str, Any]] = [
        {"name": "early", "headway_s": h_off, "flow_up": off[0], "flow_down": off[1]},
        {"name": "peak", "headway_s": h, "flow_up": 1.0,
         "flow_down": round(float(rng.uniform(0.6, 1.0)), 2)},
        {"name": "late", "headway_s": h_off, "flow_up": off[1], "flow_down": off[0]}]
    for p, a, b in zip(periods, bounds[:-1], bounds[1:]):
        p.update(start_h=round(float(a), 6), end_h=round(float(b), 6), estimate=True,
                 basis="generated (metro_atc.core.service.daygen)")
    # within the shortest period (parse_day refuses a transition as long as a period)
    trans = min(float(rng.integers(0, 7) * 50), 30.0 * min(mins))
    # one depot: the down direction starts once the first up train has turned at B
    down_off = 0.0 if both_depots else _ceil_to(trip_time_s(line, h_off, off[0]) * 1.1
                                                + layover[1] + 60.0, 60.0)
    table: Dict[str, Any] = {
        "name": f"gen_day_{int(seed):04d}{'_inc' if incidents else ''}",
        "sources": "generated (metro_atc.core.service.daygen); every figure an estimate",
        "line": line.name, "fleet": 500, "transition_s": trans, "down_offset_s": down_off,
        "termini": termini, "periods": periods}
    plan0 = parse_day(table, table["name"], line)
    # the fleet the plant-timed circulation needs, plus 0-1 spare
    need = service_day(scn, plan0, trip_times="plant").circ.fleet
    if need > max_fleet:  # the circulation's refusal names the period and the need
        table["fleet"] = max_fleet
        try:
            service_day(scn, parse_day(table, table["name"], line), trip_times="plant")
        except DayError as exc:
            raise ValueError(f"generated day {seed}: {exc} (at most {max_fleet})") from None
        raise ValueError(f"generated day {seed}: needs {need} trains, above {max_fleet}")
    table["fleet"] = need + int(rng.integers(0, 2))
    plan = parse_day(table, table["name"], line)
    holds: Dict[Tuple[str, int], float] = {}
    if incidents:
        holds = _holds(rng, plan, len(codes))
    return GeneratedDay(table["name"], scn, line, table, plan, stock_name, holds)


def _holds(rng: np.random.Generator, plan: DayPlan, n_st: int
           ) -> Dict[Tuple[str, int], float]:
    """A 60-240 s hold at an intermediate station of a peak trip in each direction."""
    peak = plan.periods[1]
    out: Dict[Tuple[str, int], float] = {}
    for d in ("up", "down"):
        cands = sorted(t.trip_id for t in trips(plan) if t.trip_id.startswith(d)
                       and peak.start_s <= t.departure_s < peak.end_s)
        if not cands or n_st < 3:
            continue
        trip = cands[int(rng.integers(0, len(cands)))]
        out[(trip, int(rng.integers(1, n_st - 1)))] = float(rng.integers(12, 49) * 5)
    return out


def day_plant(gd: GeneratedDay, seed: int = 0, breakdowns: Sequence[Breakdown] = ()
              ) -> DayPlant:
    """The plant of a generated day (plant trip times, its holds; nothing runs yet)."""
    return service_day(gd.scenario, gd.plan, seed=seed, trip_times="plant",
                       holds=gd.holds, breakdowns=breakdowns)


def run_generated_day(gd: GeneratedDay, seed: int = 0, max_wall_s: float = math.inf,
                      breakdowns: Sequence[Breakdown] = ()) -> DayResult:
    """Run a generated day on the plant to its last pull-in (or ``max_wall_s`` of wall time)."""
    return day_plant(gd, seed, breakdowns).run(max_wall_s=max_wall_s)


def day_row(gd: GeneratedDay, res: DayResult) -> Dict[str, Any]:
    """One bench row of a generated day's run (SI; stop errors of the ATO's berthings)."""
    err = np.abs(np.asarray(res.stop_errors_m, dtype=float))
    st = gd.scenario.line.stations
    row = res.row()
    row.update({
        "day": gd.name, "stock": gd.stock, "stations": len(st),
        "line_km": (st[-1].position_m - st[0].position_m) / 1000.0,
        "termini": "/".join(t.layout.name for t in gd.plan.termini),
        "depots": sum(t.depot is not None for t in gd.plan.termini),
        "peak_headway_s": min(p.headway_s for p in gd.plan.periods),
        "holds": len(gd.holds),
        "stop_error_p50_m": float(np.percentile(err, 50)) if err.size else math.nan,
        "stop_error_p95_m": float(np.percentile(err, 95)) if err.size else math.nan,
        "notes": list(res.notes[:3])})
    return row


def day_failures(res: DayResult) -> List[str]:
    """What makes a day's run fail: violations, conflicts, missed stops, trips not run."""
    out = []
    for key, n in (("ATP violations", res.atp_violations),
                   ("separation violations", res.separation_violations),
                   ("route conflicts", res.route_conflicts),
                   ("missed stops", res.missed_stops),
                   ("trips not run", res.trips_planned - res.trips_run),
                   ("trains not back in the depot", res.fleet - res.trains_in_depot)):
        if n:
            out.append(f"{n} {key}")
    if not res.finished:
        out.append("unfinished")
    return out


__all__ = ["GeneratedDay", "MAX_FLEET", "START_H", "day_failures", "day_plant", "day_row",
           "generate_day", "run_generated_day"]
