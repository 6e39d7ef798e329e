"""Benchmark: cost of the ROS-free service day per step against the trains in service.

``python -m metro_atc bench day-scale [--trains 10 30 60 120] [--window-s 300] [--json]
[--rss-end-h 9] [--no-rss]``

**Cost growth.**  For each N a synthetic day on the Taipei Blue loop with the shipped day's
termini: one period whose headway keeps about N trains in service (the loop's cycle -- two
trips plus both turnback layovers -- over N, at least ``MIN_HEADWAY_S``), run until the
first trains are back at their origin (one cycle), then timed over ``--window-s``
simulated seconds with the brake sensor samples read every step: CPU microseconds of
this process (the figure to compare on a shared machine; the wall time is in the JSON) per
step of the whole loop (:meth:`metro_atc.core.service.dayplant.DayPlant.run`), of its
plant step (one compiled call for the fleet, sensors included), of its ATOs and of the
rest (interlocking, authorities, bookkeeping), and the same per train in service and step.
A flat per-train cost means no part of a step grows faster than the trains in service.
The trains in service are those the day reached (the terminus capacity bounds them at
short headways: the row says how many ran).

**Memory.**  The Taipei Blue day (``--trip-times plant``) to ``--rss-end-h`` hours in two
processes, with and without its stop / turnback / depot records
(``python -m metro_atc day --no-records``): resident set size at every simulated hour and
the peak (``getrusage``).  Nothing of the day but its records should grow with the
simulated time.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import subprocess
import sys
from typing import Any, Dict, List, Optional

from metro_atc.core.line.scenario import load_scenario
from metro_atc.core.service.day import DayPeriod, load_day
from metro_atc.core.service.dayplant import DayPlant, service_day

MIN_HEADWAY_S = 30.0
"""Shortest headway of a synthetic day [s] (a train every 30 s from each terminus)."""
START_S = 6.0 * 3600.0
"""First departure of a synthetic day [s after midnight]."""


def cycle_s(dp: DayPlant) -> float:
    """A train's cycle on the loop [s]: both trips plus both termini's turnback layovers."""
    by_dir: Dict[str, float] = {}
    for b in dp.circ.blocks:
        for t in b.trips:
            by_dir.setdefault(t.origin, t.arrival_s - t.departure_s)
    return sum(by_dir.values()) + sum(t.min_turnback_s for t in dp.termini)


def synthetic_day(n_trains: int, window_s: float, seed: int = 0) -> DayPlant:
    """The Taipei Blue loop with one period whose headway keeps ~``n_trains`` in service.

    The period lasts two cycles plus the window (the first trips' cycle, then the timed
    window, then a margin); trip times are the plant's (``trip_times="plant"``).
    """
    plan = load_day(None)
    scn = load_scenario("taipei_blue")
    probe = service_day(scn, plan, seed=seed, trip_times="plant")
    cyc = cycle_s(probe)
    hw = max(MIN_HEADWAY_S, round(cyc / n_trains))
    end = START_S + 2.0 * cyc + window_s
    period = DayPeriod(f"scale{n_trains}", START_S, end, float(hw), 1.0, 1.0, True,
                       "bench day-scale: a synthetic period")
    syn = dataclasses.replace(plan, periods=(period,), fleet=max(4 * n_trains, plan.fleet),
                              name=f"day_scale_{n_trains}")
    return service_day(scn, syn, seed=seed, trip_times="plant")


def scale_row(n_trains: int, window_s: float, seed: int = 0) -> Dict[str, Any]:
    """The timed window of :func:`synthetic_day` (see the module docstring)."""
    dp = synthetic_day(n_trains, window_s, seed)
    first = min(b.trips[0].departure_s for b in dp.circ.blocks)
    t_on = first + cycle_s(dp)
    r0 = dp.run(end_s=t_on, sensors=True)
    s0, w0, c0, n0, k0, z0 = (dict(r0.cpu_split_s), r0.wall_s, r0.cpu_s, r0.train_steps,
                              dp.step_no, r0.sensor_samples)
    r1 = dp.run(end_s=t_on + window_s, sensors=True)
    steps = dp.step_no - k0
    ts = r1.train_steps - n0
    wall, cpu = r1.wall_s - w0, r1.cpu_s - c0
    split = {k: r1.cpu_split_s[k] - s0.get(k, 0.0) for k in r1.cpu_split_s}
    row: Dict[str, Any] = {
        "target_trains": n_trains, "fleet": len(dp.trains),
        "headway_s": dp.circ.blocks and float(sorted(
            t.departure_s for b in dp.circ.blocks for t in b.trips
            if t.origin == dp.termini[0].code)[1] - first),
        "mean_in_service": ts / max(steps, 1), "steps": steps,
        "wall_us_per_step": 1e6 * wall / max(steps, 1),
        "us_per_step": 1e6 * cpu / max(steps, 1),
        "us_per_train_step": 1e6 * cpu / max(ts, 1),
        "sensor_samples": r1.sensor_samples - z0,
        "atp_violations": r1.atp_violations, "route_conflicts": r1.route_conflicts}
    for k, v in split.items():
        row[f"{k}_us_per_step"] = 1e6 * v / max(steps, 1)
        row[f"{k}_us_per_train_step"] = 1e6 * v / max(ts, 1)
    return row


def rss_run(end_h: float, records: bool) -> Dict[str, Any]:
    """``python -m metro_atc day --trip-times plant --end-h`` in a process of its own.

    Returns its resident set size per simulated hour [MB], its peak [MB] and its figures.
    """
    cmd = [sys.executable, "-m", "metro_atc", "day", "--trip-times", "plant",
           "--end-h", str(end_h)] + ([] if records else ["--no-records"])
    p = subprocess.run(cmd, capture_output=True, text=True, check=False)
    rows = [json.loads(x) for x in p.stdout.splitlines() if x.startswith("{")]
    if not rows:
        return {"records": records, "error": (p.stderr.strip().splitlines() or ["?"])[-1]}
    last = rows[-1]
    return {"records": records,
            "rss_mb_per_hour": [(r["t_h"], r["rss_mb"]) for r in rows[:-1] if "rss_mb" in r],
            "peak_rss_mb": last.get("peak_rss_mb"), "stops": last.get("stops"),
            "rtf": last.get("rtf"), "rtf_cpu": last.get("rtf_cpu"),
            "plant_rtf_cpu": last.get("plant_rtf_cpu")}


def main(argv: Optional[List[str]] = None) -> int:
    """Run the benchmark (see the module docstring); ``--json``: one JSON object."""
    ap = argparse.ArgumentParser(prog="python -m metro_atc bench day-scale",
                                 description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--trains", type=int, nargs="+", default=[10, 30, 60, 120])
    ap.add_argument("--window-s", type=float, default=300.0,
                    help="timed simulated seconds per row")
    ap.add_argument("--rss-end-h", type=float, default=9.0,
                    help="the memory runs stop at this hour of the day")
    ap.add_argument("--no-rss", action="store_true", help="skip the memory runs")
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args(argv)
    if any(n < 1 or n > 1000 for n in a.trains):
        ap.error("--trains: each in [1, 1000]")
    if not 10.0 <= a.window_s <= 86400.0:
        ap.error("--window-s must lie in [10, 86400]")
    rows = []
    for n in a.trains:
        rows.append(scale_row(n, a.window_s))
        if not a.json:
            print(f"day-scale: {n} trains done", file=sys.stderr, flush=True)
    rss = [] if a.no_rss else [rss_run(a.rss_end_h, True), rss_run(a.rss_end_h, False)]
    out = {"scale": rows, "memory": rss, "window_s": a.window_s}
    if a.json:
        print(json.dumps(out))
        return 0
    print("CPU cost of the ROS-free day per step (Taipei Blue loop, sensors read) [us]")
    print(f"{'trains':>7s} {'in svc':>7s} {'step':>9s} {'plant':>8s} {'ato':>8s} "
          f"{'rest':>8s} | {'/train':>7s} {'plant':>7s} {'ato':>7s} {'rest':>7s}")
    for r in rows:
        print(f"{r['target_trains']:7d} {r['mean_in_service']:7.1f} {r['us_per_step']:9.0f} "
              f"{r['plant_us_per_step']:8.0f} {r['ato_us_per_step']:8.0f} "
              f"{r['rest_us_per_step']:8.0f} | {r['us_per_train_step']:7.1f} "
              f"{r['plant_us_per_train_step']:7.1f} {r['ato_us_per_train_step']:7.1f} "
              f"{r['rest_us_per_train_step']:7.1f}")
    for m in rss:
        if "error" in m:
            print(f"memory ({'with' if m['records'] else 'without'} records): {m['error']}")
            continue
        hours = ", ".join(f"{h:g} h {mb:.0f}" for h, mb in m["rss_mb_per_hour"])
        print(f"memory {'with' if m['records'] else 'without'} records: peak "
              f"{m['peak_rss_mb']:.0f} MB; RSS per hour [MB]: {hours}")
    return 0 if all(not math.isnan(r["us_per_step"]) for r in rows) else 1


if __name__ == "__main__":
    raise SystemExit(main())
