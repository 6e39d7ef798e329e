"""Benchmark: the ATO/ATS stack on a corpus of generated lines.

``python -m metro_atc bench lines --count N [--seed S] [--corpus C] [--incidents] [--regulator R]
[--planner P] [--tracker T] [--scenario FILE ...] [--jobs J] [--json]``

``python -m metro_atc bench lines --days ...``: two-direction service days on generated
lines instead (:mod:`metro_atc.bench.line_days`, the same bench as ``bench line-days``;
its own options, ``--incidents`` there being station holds).

Runs N lines of :func:`metro_atc.core.linegen.generate_line` (seeds S .. S+N-1, with a TSR
and a breakdown each under ``--incidents``), the TTOBench metro line (Songjiazhuang -
Yizhuang with the Beijing Subway train, :func:`metro_atc.bench.ttobench.metro_scenario`;
fault-free in both modes; ``--no-ttobench`` leaves it out) and any ``--scenario`` files or
embedded scenario names (e.g. ``taipei_blue``) through the
ROS-free closed loop :func:`metro_atc.core.closed_loop.run_closed_loop` (real ATO and ATS
cores, the plant, lockstep) and prints one row per line plus totals: ATP violations, missed
stops, ATP interventions per 100 stops, stop error p50/p95/max [m] of the stops the ATO
berthed, stops outside +-0.30 m, arrivals at a standstill forced by a breakdown or an ATP
emergency brake (``forced_stops``, not in the stop-error figures), time above the civil
limit [s], speed minima per TSR approach (``tsr_speed_minima_max``: hunting, the minima
not explained by a lower permanent limit, a station stop or a forced stop/hold,
:mod:`metro_atc.core.tsr_hunting`; ``tsr_speed_minima_raw_max``: all), ATP interventions
at a TSR's notice time (``atp_interventions_at_tsr_notice``, included in the
interventions), energy per train-km [kWh] and the
brake diagnosis of every train (:class:`metro_atc.core.brake.line_monitor.LineBrakeMonitor`:
false alarms = level rises of
trains without a brake fault; injected pad/wheel faults detected; trains whose brakes
were never judged, ``brake_trains_not_assessed``; ``--no-brake`` skips it).  The generated
lines are the extended corpus (:func:`metro_atc.core.linegen.generate_line` with
``extended=True``: light and heavy stock, dense, long and mixed interstations; each row
names its stock variant); ``--corpus classic`` runs the classic one.
Each row has the CPU time of its line (``cpu_s``, the process time of the worker).
``--jobs J`` runs the lines in J worker processes (the rows and totals are the same as
with one: every line is an independent deterministic run; rows keep the corpus order).
Exit code 1 when a line fails to run.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from typing import Any, Callable, Iterator, List, Optional, Tuple

import numpy as np

from metro_atc.bench.progress import progress_each
from metro_atc.bench.ttobench import metro_scenario
from metro_atc.core.closed_loop import STOP_WINDOW_M, run_closed_loop
from metro_atc.core.linegen import load_generated_named
from metro_atc.core.line.rolling_stock import train_params_for
from metro_atc.core.line.scenario import ScenarioError, load_scenario
from metro_atc.jsonsafe import json_safe


def totals(rows: List[dict[str, Any]], errors: List[float]) -> dict[str, Any]:
    """Totals over the rows; stop-error percentiles over every arrival of every line."""
    err = np.abs(np.asarray(errors, dtype=float))
    stops = int(sum(r["stops"] for r in rows))
    ints = int(sum(r["atp_interventions"] for r in rows))
    km = float(sum(r["train_km"] for r in rows))
    e = float(sum(r["energy_kwh"] for r in rows))
    return {
        "lines": len(rows), "stops": stops,
        "atp_violations": int(sum(r["atp_violations"] for r in rows)),
        "missed_stops": int(sum(r["missed_stops"] for r in rows)),
        "atp_interventions": ints,
        "atp_interventions_at_tsr_notice": int(sum(r.get("atp_interventions_at_tsr_notice", 0)
                                                   for r in rows)),
        "atp_interventions_per_100_stops": 100.0 * ints / max(stops, 1),
        "stop_error_p50_m": float(np.percentile(err, 50)) if err.size else math.nan,
        "stop_error_p95_m": float(np.percentile(err, 95)) if err.size else math.nan,
        "stop_error_max_m": float(err.max()) if err.size else math.nan,
        "stops_outside_0p30_m": int(np.count_nonzero(err > STOP_WINDOW_M)),
        "forced_stops": int(sum(r.get("forced_stops", 0) for r in rows)),
        "time_above_civil_limit_s": float(sum(r["time_above_civil_limit_s"] for r in rows)),
        "tsr_approaches": int(sum(r["tsr_approaches"] for r in rows)),
        "tsr_speed_minima_max": int(max([r["tsr_speed_minima_max"] for r in rows] or [0])),
        "tsr_speed_minima_raw_max": int(max([r.get("tsr_speed_minima_raw_max", 0) for r in rows]
                                            or [0])),
        "tsr_minima_explained": {c: int(sum(r.get("tsr_minima_explained", {}).get(c, 0)
                                            for r in rows))
                                 for c in sorted({c for r in rows
                                                  for c in r.get("tsr_minima_explained", {})})},
        "energy_kwh_per_train_km": e / max(km, 1e-9), "train_km": km,
        "unfinished": int(sum(not r["finished"] for r in rows)),
        **_brake_totals(rows),
    }


def _brake_totals(rows: List[dict[str, Any]]) -> dict[str, Any]:
    """Brake-diagnosis totals (empty when the diagnosis did not run)."""
    if not rows or "brake_false_alarms" not in rows[0]:
        return {}
    delays = [d for r in rows for d in r["brake_detect_after_brake_s"]]
    # false alarms only over lines where some brake was assessed (None: none was)
    judged = [r for r in rows if r.get("brake_false_alarms") is not None]
    return {k: (int(sum(r[k] for r in judged)) if judged else None)
            for k in ("brake_false_alarms", "brake_false_errors")} | {
        k: int(sum(r.get(k, 0) for r in rows))
        for k in ("brake_faults", "brake_faults_detected", "brake_trains_assessed",
                  "brake_alarms_not_assessed")} | {
        "brake_trains_not_assessed": int(sum(len(r.get("brake_trains_not_assessed", []))
                                             for r in rows)),
        "brake_detect_after_brake_max_s": max(delays) if delays else math.nan}


def _false_alarms(row: dict[str, Any]) -> str:
    """The row's brake false alarms as printed, with the trains assessed.

    'not assessed' where no train's brake was.
    """
    if "brake_false_alarms" not in row:
        return "-"
    fa = row["brake_false_alarms"]
    n, of = row.get("brake_trains_assessed", 0), len(row.get("brake_assessed", {}))
    return f"not assessed (0 of {of} trains)" if fa is None \
        else f"{fa} ({n} of {of} trains assessed)"


Job = Tuple[str, Any]
Outcome = Tuple[Optional[dict[str, Any]], List[float], str]


def run_job(job: Job, a: argparse.Namespace) -> Outcome:
    """Run one line of the corpus: (row or None, stop errors [m], failure text or '')."""
    kind, what = job
    c0 = time.process_time()
    try:
        stock = ""
        if kind == "gen":
            stock, scn = load_generated_named(what, incidents=a.incidents,
                                              extended=getattr(a, "corpus", "") == "extended")
        else:
            scn = metro_scenario() if kind == "ttobench" else load_scenario(what)
        res = run_closed_loop(scn, regulator=a.regulator, planner=a.planner,
                              tracker=a.tracker, seed=a.sim_seed, brake=not a.no_brake)
    except (ScenarioError, ValueError) as exc:
        return None, [], f"{what}: {exc}"
    row = res.row()
    row["line_km"] = float(np.ptp([s.position_m for s in scn.line.stations])) / 1000.0
    row["stations"] = len(scn.line.stations)
    row["trains"] = scn.trains.count
    row["stock"] = stock or scn.trains.preset
    row["empty_mass_t"] = round(train_params_for(scn).tare_mass_kg / 1000.0, 1)
    row["cpu_s"] = time.process_time() - c0
    return row, list(res.stop_errors_m), ""


def _run_job_star(args: Tuple[Callable[[Any, argparse.Namespace], Any], Any,
                              argparse.Namespace]) -> Any:
    """``fn(job, a)`` of one (fn, job, arguments) triple (a picklable pool task)."""
    fn, job, a = args
    return fn(job, a)


def collect(name: str, unit: str, outcomes: Iterator[Any], total: int, as_json: bool,
            line: Callable[[dict[str, Any]], str]
            ) -> Tuple[List[dict[str, Any]], List[float], List[str]]:
    """Rows, stop errors [m] and failures of a bench's jobs as they finish.

    ``outcomes``: (row or None, stop errors, failure text) per job (:func:`run_jobs`); a
    row's own ``failures`` (if any) count as failed.  Each row is printed as it comes:
    ``line(row)`` on stdout, or (``as_json``) one JSON row on stderr (progress).
    """
    rows: List[dict[str, Any]] = []
    errors: List[float] = []
    failed: List[str] = []
    for row, errs, failure in progress_each(name, outcomes, unit, total=total):
        if row is None:
            failed.append(failure)
            print(f"{name}: {failure}", file=sys.stderr)
            continue
        rows.append(row)
        errors.extend(errs)
        if row.get("failures"):
            failed.append(f"{row.get('day', row.get('scenario'))}: "
                          f"{', '.join(row['failures'])}")
        if as_json:
            print(json.dumps(json_safe(row)), file=sys.stderr, flush=True)
        else:
            print(line(row), flush=True)
    return rows, errors, failed


def run_jobs(jobs: List[Any], a: argparse.Namespace, n_workers: int,
             fn: Callable[[Any, argparse.Namespace], Any] = run_job) -> Iterator[Any]:
    """Outcomes ``fn(job, a)`` of ``jobs`` in their order, in ``n_workers`` processes (1: here).

    ``fn`` must be a module-level function (picklable); default :func:`run_job`.
    """
    if n_workers <= 1 or len(jobs) <= 1:
        for job in jobs:
            yield fn(job, a)
        return
    with ProcessPoolExecutor(max_workers=min(n_workers, len(jobs))) as ex:
        yield from ex.map(_run_job_star, [(fn, job, a) for job in jobs])


def line_of(row: dict[str, Any]) -> str:
    """One printed line of a line's row."""
    return (f"{row['scenario']:>18s} {row['stations']:3d} st {row['trains']:3d} tr "
            f"viol {row['atp_violations']} missed {row['missed_stops']} "
            f"int/100 {row['atp_interventions_per_100_stops']:5.1f} "
            f"err p50/p95/max {row['stop_error_p50_m']:.3f}/{row['stop_error_p95_m']:.3f}"
            f"/{row['stop_error_max_m']:.3f} m out {row['stops_outside_0p30_m']} "
            f"above {row['time_above_civil_limit_s']:6.1f} s "
            f"tsr-min {row['tsr_speed_minima_max']} "
            f"{row['energy_kwh_per_train_km']:.2f} kWh/train-km "
            f"brake-fa {_false_alarms(row)} {row['stock']} "
            f"({row['wall_s']:.1f} s, {row['cpu_s']:.1f} CPU s)")


def main(argv: Optional[List[str]] = None) -> int:
    """Command-line entry point (see the module docstring)."""
    args = list(sys.argv[1:] if argv is None else argv)
    # ``--days`` (the two-direction days, bench line-days) is dispatched by the command line
    # (metro_atc.cli): line_days uses this module, so it is not imported here
    ap = argparse.ArgumentParser(prog="python -m metro_atc bench lines",
                                 description=__doc__.splitlines()[0])
    ap.add_argument("--days", action="store_true",
                    help="two-direction service days on generated lines instead "
                    "(bench line-days; --days -h lists its options; dispatched by "
                    "python -m metro_atc bench)")
    ap.add_argument("--count", type=int, default=10, help="generated lines")
    ap.add_argument("--seed", type=int, default=0, help="seed of the first generated line")
    ap.add_argument("--corpus", choices=("extended", "classic"), default="extended",
                    help="generated lines: extended (light and heavy stock, dense, long and "
                    "mixed interstations; default) or classic (the four presets' variants)")
    ap.add_argument("--incidents", action="store_true", help="a TSR and a breakdown per line")
    ap.add_argument("--scenario", nargs="*", default=[],
                    help="extra scenario files or embedded names run after the generated lines")
    ap.add_argument("--no-ttobench", action="store_true",
                    help="leave the TTOBench metro line out of the corpus")
    ap.add_argument("--regulator", default="none")
    ap.add_argument("--planner", default="ectp")
    ap.add_argument("--tracker", default="fuzzy")
    ap.add_argument("--sim-seed", type=int, default=0, help="plant random seed")
    ap.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    ap.add_argument("--no-brake", action="store_true", help="skip the brake diagnosis")
    ap.add_argument("--jobs", type=int, default=1, help="worker processes (lines in parallel)")
    a = ap.parse_args(args)
    if a.count < 0:
        ap.error("--count must be >= 0")
    if a.jobs < 1:
        ap.error("--jobs must be >= 1")
    t0 = time.perf_counter()
    jobs: List[Any] = [("gen", a.seed + k) for k in range(a.count)] + \
        ([] if a.no_ttobench else [("ttobench", "ttobench")]) + \
        [("file", f) for f in a.scenario]
    outcomes = run_jobs(jobs, a, a.jobs)
    rows, errors, failed = collect("bench lines", "lines", outcomes, len(jobs), a.json,
                                   line_of)
    tot = totals(rows, errors)
    result = {"bench": "lines", "incidents": a.incidents, "regulator": a.regulator,
              "planner": a.planner, "tracker": a.tracker, "rows": rows, "totals": tot,
              "failed": failed, "seconds": time.perf_counter() - t0,
              "cpu_s": float(sum(r["cpu_s"] for r in rows)), "jobs": a.jobs}
    if a.json:
        print(json.dumps(json_safe(result)))
    else:
        print("totals: " + ", ".join(f"{k} {v:.3f}" if isinstance(v, float) else f"{k} {v}"
                                     for k, v in tot.items()))
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
