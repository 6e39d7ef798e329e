"""Automatic train regulation in the closed loop of the ROS graph (Lin 2010a, Exp. 2, live).

``python -m metro_atc bench closed-loop [--json]`` runs ``python -m metro_atc run`` on
``taipei_blue_delay`` (the Blue line with a 180 s hold of the first train at the first
station) once per regulator (``none`` timetable, ``lqr``, ``dhp``, ``aoc``) and seed, every
node its own OS process, lockstep on simulated time, and prints the recovery KPIs side by
side with the paper's statements.  Each graph runs on its own ``ROS_DOMAIN_ID`` (runs may go
in parallel: ``--parallel``).  A run of the first simulated hour takes 3-6 min on 2 cores.

The paper (Lin 2010a, Fig. 8, Table I) compares LQR, DHP and AOC on its traffic model; it has
no timetable-only run and gives no per-KPI numbers besides AOC's 104 s worst terminal delay
and the cost improvements.  Here the plant is the line simulator (dynamics, ATP, ATO,
passengers), not the regulators' model, and the KPI is measured on the events.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any, Dict, List, Optional

import numpy as np

from metro_atc.bench.progress import progress_each
from metro_atc.bench.regulation import PAPER
from metro_atc.exit_codes import Exit
from metro_atc.jsonsafe import json_safe
from metro_atc.core.atr.registry import REGULATORS

DEFAULT_REGULATORS = ("none", "lqr", "dhp", "aoc")
KPIS = {
    "mean_schedule_deviation_s": lambda k: k["schedule_deviation_s"]["mean"],
    "rms_schedule_deviation_s": lambda k: k["schedule_deviation_s"]["rms"],
    "max_delay_s": lambda k: k["max_delay_s"],
    "max_terminal_delay_s": lambda k: k["max_terminal_delay_s"],
    "headway_deviation_rms_s": lambda k: k["headway_deviation_s"]["rms"],
    "running_time_deviation_rms_s": lambda k: k["running_time_deviation_s"]["rms"],
    "punctuality": lambda k: k["punctuality"],
    "recovery_time_s": lambda k: k["recovery_time_s"],
    "late_departures": lambda k: k["late_departures"],
    "passengers_left_behind": lambda k: k["passengers_left_behind"],
    "energy_kwh": lambda k: k["energy_kwh"],
    "atp_interventions": lambda k: k["atp_interventions"],
    "atp_violations": lambda k: k["atp_violations"],
    "skipped_stops": lambda k: k["skipped_stops"],
    "lockstep_misses": lambda k: k.get("lockstep_misses"),
    "wall_time_s": lambda k: k.get("wall_time_s"),
}


def run_graph(scenario: str, regulator: str, seed: int, duration_s: float, domain_id: int,
              out_dir: Optional[Path] = None, timeout_s: float = 3600.0,
              progress: bool = False) -> Optional[Dict[str, Any]]:
    """One ``python -m metro_atc run --json`` on ``domain_id``; its KPIs or None (stderr).

    ``progress``: the run's progress rows go to this process's stderr.
    """
    env = dict(os.environ)
    env.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    env["ROS_DOMAIN_ID"] = str(domain_id)
    with tempfile.TemporaryDirectory(prefix="metro_atc_bench_") as tmp:
        out = out_dir if out_dir is not None else Path(tmp)
        cmd = [sys.executable, "-m", "metro_atc", "run", "--scenario", scenario,
               "--regulator", regulator, "--seed", str(seed), "--duration", str(duration_s),
               "--json", "--no-plots" if out_dir is None else "--plots", "--out", str(out)]
        # progress: the run's own rows (simulated time, trains, real-time factor, ETA) go
        # straight to this process's stderr
        show = bool(progress)
        if show:
            cmd += ["--progress", "always"]
        try:
            r = subprocess.run(cmd, env=env, cwd=tmp, stdout=subprocess.PIPE,
                               stderr=None if show else subprocess.PIPE, text=True,
                               timeout=timeout_s)
        except subprocess.TimeoutExpired:
            print(f"closed-loop: {regulator} seed {seed} timed out", file=sys.stderr)
            return None
    # a run cut at duration_s before its service completed exits Exit.CUT: its KPIs stand
    if r.returncode not in (Exit.OK, Exit.CUT) or not r.stdout.strip():
        why = "see above" if show else (r.stderr or "").strip()[-300:]
        print(f"closed-loop: {regulator} seed {seed} failed ({r.returncode}): {why}",
              file=sys.stderr)
        return None
    return dict(json.loads(r.stdout.strip().splitlines()[-1]))


def summarise(runs: Dict[str, List[Dict[str, Any]]]) -> Dict[str, Any]:
    """Mean and std per KPI and regulator; improvement of the mean deviation vs ``none``."""
    out: Dict[str, Any] = {}
    for reg, ks in runs.items():
        row: Dict[str, Any] = {"runs": len(ks)}
        for name, get in KPIS.items():
            vals = np.array([float(v) for v in (get(k) for k in ks) if v is not None])
            row[name] = float(vals.mean()) if vals.size else None
            row[f"{name}_std"] = float(vals.std()) if vals.size else None
        out[reg] = row
    base = out.get("none", {}).get("mean_schedule_deviation_s")
    for reg, row in out.items():
        v = row.get("mean_schedule_deviation_s")
        row["improvement_vs_none_pct"] = (100.0 * (base - v) / base
                                          if base and v is not None else None)
    return out


def main(argv: Optional[List[str]] = None) -> int:
    """Command-line entry point (see the module docstring)."""
    ap = argparse.ArgumentParser(prog="closed-loop", description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default="taipei_blue_delay")
    ap.add_argument("--regulators", default=",".join(DEFAULT_REGULATORS),
                    help="comma-separated subset of " + ",".join(REGULATORS))
    ap.add_argument("--seeds", type=int, default=1, help="simulation seeds 0..N-1")
    ap.add_argument("--duration", type=float, default=3600.0,
                    help="simulated seconds per run (0: the scenario's end)")
    ap.add_argument("--parallel", type=int, default=2, help="graphs run at once")
    ap.add_argument("--domain-base", type=int, default=230,
                    help="first ROS_DOMAIN_ID (one per parallel run; Fast DDS allows <= 232, "
                         "the tests use 30..229)")
    ap.add_argument("--out", type=Path, default=None, help="keep each run's outputs here")
    ap.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    a = ap.parse_args(argv)
    regs = [r for r in a.regulators.split(",") if r]
    bad = [r for r in regs if r not in REGULATORS]
    if bad or a.seeds < 1 or a.parallel < 1 or not 0 <= a.domain_base <= 233 - a.parallel:
        ap.error(f"bad arguments: regulators {bad or 'ok'}, seeds {a.seeds}, "
                 f"parallel {a.parallel}, domain ids {a.domain_base}.."
                 f"{a.domain_base + a.parallel - 1} (must lie in 0..232)")
    jobs = [(r, s) for s in range(a.seeds) for r in regs]
    t0 = time.perf_counter()

    def one(idx: int) -> Optional[Dict[str, Any]]:
        reg, seed = jobs[idx]
        out = a.out / f"{reg}_seed{seed}" if a.out is not None else None
        return run_graph(a.scenario, reg, seed, a.duration,
                         a.domain_base + idx % a.parallel, out)

    with ThreadPoolExecutor(max_workers=a.parallel) as pool:
        results = list(progress_each("bench closed_loop", pool.map(one, range(len(jobs))),
                                     "runs", total=len(jobs)))
    runs: Dict[str, List[Dict[str, Any]]] = {r: [] for r in regs}
    for (reg, _), k in zip(jobs, results):
        if k is not None:
            runs[reg].append(k)
    summary = summarise(runs)
    result = {"bench": "closed-loop", "scenario": a.scenario, "duration_s": a.duration,
              "seeds": list(range(a.seeds)), "methods": summary, "paper": PAPER,
              "seconds": time.perf_counter() - t0}
    failed = sum(k is None for k in results)
    if a.json:
        print(json.dumps(json_safe(result)))
        return 1 if failed else 0
    print(f"ATR in the ROS graph: {a.scenario}, first {a.duration:.0f} s simulated, "
          f"seeds 0..{a.seeds - 1} (mean over seeds)")
    rows = [("mean sched. deviation s", "mean_schedule_deviation_s", 1),
            ("rms sched. deviation s", "rms_schedule_deviation_s", 1),
            ("max delay s", "max_delay_s", 0), ("max terminal delay s", "max_terminal_delay_s", 0),
            ("headway dev. rms s", "headway_deviation_rms_s", 1),
            ("punctuality (<= 60 s)", "punctuality", 3),
            ("recovery time s", "recovery_time_s", 0), ("late departures", "late_departures", 0),
            ("left behind pax", "passengers_left_behind", 0), ("energy kWh", "energy_kwh", 0),
            ("ATP interventions", "atp_interventions", 0),
            ("ATP violations", "atp_violations", 0),
            ("improvement vs none %", "improvement_vs_none_pct", 1)]
    print(f"  {'KPI':24s}" + "".join(f"{r:>12s}" for r in regs))
    for label, key, nd in rows:
        cells = []
        for r in regs:
            v = summary[r].get(key)
            cells.append(f"{v:12.{nd}f}" if v is not None else f"{'-':>12s}")
        print(f"  {label:24s}" + "".join(cells))
    print(f"  paper (Lin 2010a, on its traffic model, no timetable-only run): AOC worst terminal "
          f"delay {PAPER['aoc_worst_terminal_delay_s']:.0f} s; cost AOC vs LQR "
          f"+{PAPER['aoc_improvement_vs_lqr_pct']:.0f} %, vs DHP "
          f"+{PAPER['aoc_improvement_vs_dhp_pct']:.0f} %")
    if failed:
        print(f"  {failed} run(s) failed (see stderr)")
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
