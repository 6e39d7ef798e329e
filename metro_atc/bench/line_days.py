"""Benchmark: two-direction service days on generated lines, on the ROS-free day plant.

``python -m metro_atc bench lines --days --count N [--seed S] [--incidents] [--stations K]
[--jobs J] [--max-wall-s W] [--json]`` (the same bench as ``bench line-days ...``)

Generates N days (:func:`metro_atc.core.service.daygen.generate_day`, seeds S .. S+N-1:
a generated line of the extended corpus with 4-7 stations, or K, both terminus layouts
drawn per terminus, depots at one or both termini, three periods over ~2-3 simulated hours,
the fleet the circulation needs; with ``--incidents`` a 60-240 s hold at a station in each
direction in the peak) and runs each through
:func:`metro_atc.core.service.dayplant.service_day` (the plant's trip times).  One row per
day: trips planned / run, trains back in the depot / fleet, ATP violations, separation
violations, route conflicts, missed stops, stop error p50/p95/max [m] of the ATO's
berthings, wall time; then totals (stop-error percentiles over every berthing of every day)
and what the days covered (terminus layouts at A and B, depots, stocks: counts of days;
stations, line length, peak headway and fleet: min and max).

Exit code 1 when a day fails to generate, or any day has an ATP or separation violation, a
route conflict, a missed stop, a trip not run, a train not back in the depot, or did not
finish (``--max-wall-s`` per day, default none); 0 otherwise.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from collections import Counter
from typing import Any, Callable, Dict, List, Optional, Tuple

import numpy as np

from metro_atc.bench.lines import collect, run_jobs
from metro_atc.core.service.daygen import (day_failures, day_row, generate_day,
                                           run_generated_day)
from metro_atc.jsonsafe import json_safe

Outcome = Tuple[Optional[Dict[str, Any]], List[float], str]

_SUMS = ("trips_planned", "trips_run", "fleet", "trains_in_depot", "atp_violations",
         "separation_violations", "route_conflicts", "missed_stops", "stops",
         "stops_outside_0p30_m", "forced_stops", "atp_interventions")


def run_day_job(seed: int, a: argparse.Namespace) -> Outcome:
    """Generate and run one day: (row or None, stop errors [m], failure text or '')."""
    c0 = time.process_time()
    try:
        gd = generate_day(seed, incidents=a.incidents, n_stations=a.stations)
    except ValueError as exc:
        return None, [], f"day {seed}: {exc}"
    res = run_generated_day(gd, seed=a.sim_seed, max_wall_s=a.max_wall_s)
    row = day_row(gd, res)
    row["seed"] = seed
    row["failures"] = day_failures(res)
    row["cpu_s"] = time.process_time() - c0
    return row, list(res.stop_errors_m), ""


def totals(rows: List[Dict[str, Any]], errors: List[float]) -> Dict[str, Any]:
    """Sums over the days; stop-error percentiles over every berthing [m]."""
    err = np.abs(np.asarray(errors, dtype=float))
    out: Dict[str, Any] = {"days": len(rows)}
    out.update({k: int(sum(r[k] for r in rows)) for k in _SUMS})
    out.update({
        "stop_error_p50_m": float(np.percentile(err, 50)) if err.size else math.nan,
        "stop_error_p95_m": float(np.percentile(err, 95)) if err.size else math.nan,
        "stop_error_max_m": float(err.max()) if err.size else math.nan,
        "unfinished": int(sum(not r["finished"] for r in rows)),
        "failed_days": int(sum(bool(r["failures"]) for r in rows)),
        "wall_s": float(sum(r["wall_s"] for r in rows)),
        "coverage": coverage(rows)})
    return out


def coverage(rows: List[Dict[str, Any]]) -> Dict[str, Any]:
    """What the days drew: layouts per terminus, depots, stocks (counts of days), ranges.

    Stations, line length [km], peak headway [s], fleet: (min, max) over the days.
    """
    def count(key: Callable[[Dict[str, Any]], Any]) -> Dict[str, int]:
        return dict(sorted(Counter(str(key(r)) for r in rows).items()))

    def span(k: str) -> List[float]:
        return [min(r[k] for r in rows), max(r[k] for r in rows)] if rows else []

    return {"terminus_a": count(lambda r: r["termini"].split("/")[0]),
            "terminus_b": count(lambda r: r["termini"].split("/")[1]),
            "depots": count(lambda r: r["depots"]), "stock": count(lambda r: r["stock"]),
            **{k: span(k) for k in ("stations", "line_km", "peak_headway_s", "fleet")}}


def day_line(row: Dict[str, Any]) -> str:
    """One printed line of a day's row."""
    return (f"{row['day']:>18s} {row['stations']:2d} st {row['line_km']:5.1f} km "
            f"{row['termini']:>25s} depots {row['depots']} "
            f"hw {row['peak_headway_s']:4.0f} s "
            f"trips {row['trips_run']}/{row['trips_planned']} "
            f"depot {row['trains_in_depot']}/{row['fleet']} "
            f"viol {row['atp_violations']} sep {row['separation_violations']} "
            f"conflicts {row['route_conflicts']} missed {row['missed_stops']} "
            f"err p50/p95/max {row['stop_error_p50_m']:.3f}/"
            f"{row['stop_error_p95_m']:.3f}/{row['stop_error_max_m']:.3f} m "
            f"{row['stock']} ({row['wall_s']:.1f} s)"
            + (f" FAILED: {', '.join(row['failures'])}" if row["failures"] else ""))


def main(argv: Optional[List[str]] = None,
         prog: str = "python -m metro_atc bench line-days") -> int:
    """Command-line entry point (see the module docstring); ``prog``: the name in usage."""
    ap = argparse.ArgumentParser(prog=prog,
                                 description=__doc__.splitlines()[0])
    ap.add_argument("--count", type=int, default=10, help="generated days")
    ap.add_argument("--seed", type=int, default=0, help="seed of the first generated day")
    ap.add_argument("--incidents", action="store_true",
                    help="a hold at a station in each direction in the peak")
    ap.add_argument("--stations", type=int, default=None,
                    help="stations per line (default: drawn, 4-7)")
    ap.add_argument("--sim-seed", type=int, default=0, help="plant random seed")
    ap.add_argument("--max-wall-s", type=float, default=math.inf,
                    help="wall-time limit per day [s] (a day cut by it fails)")
    ap.add_argument("--jobs", type=int, default=1, help="worker processes (days in parallel)")
    ap.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    a = ap.parse_args(argv)
    if a.count < 0:
        ap.error("--count must be >= 0")
    if a.jobs < 1:
        ap.error("--jobs must be >= 1")
    if a.stations is not None and not 3 <= a.stations <= 60:
        ap.error("--stations must be in [3, 60]")
    if not a.max_wall_s > 0.0:
        ap.error("--max-wall-s must be > 0")
    t0 = time.perf_counter()
    seeds = [a.seed + k for k in range(a.count)]
    outcomes = run_jobs(seeds, a, a.jobs, run_day_job)
    rows, errors, failed = collect("bench line-days", "days", outcomes, len(seeds), a.json,
                                   day_line)
    tot = totals(rows, errors)
    result = {"bench": "line-days", "incidents": a.incidents, "rows": rows, "totals": tot,
              "failed": failed, "seconds": time.perf_counter() - t0, "jobs": a.jobs}
    if a.json:
        print(json.dumps(json_safe(result)))
    else:
        print("totals: " + ", ".join(f"{k} {v:.3f}" if isinstance(v, float) else f"{k} {v}"
                                     for k, v in tot.items() if k != "coverage")
              + f", elapsed {result['seconds']:.1f} s ({a.jobs} jobs)")
        print("coverage: " + ", ".join(f"{k} {v}" for k, v in tot["coverage"].items()))
        for f in failed:
            print(f"failed: {f}")
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
