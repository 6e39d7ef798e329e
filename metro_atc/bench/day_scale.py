"""Benchmark: cost of the ROS-free service day per step against the trains in service.

``python -m metro_atc bench day-scale [--trains 10 30 60 120] [--window-s 300] [--json]
[--rss-end-h 9] [--no-rss] [--graph [--domain-id 230]] [--tables DIR]``

**Cost growth.**  For each N a synthetic day on the Taipei Blue loop with the shipped day's
termini: one period whose headway keeps about N trains in service (the loop's cycle -- two
trips plus both turnback layovers -- over N, at least ``MIN_HEADWAY_S``, the shortest
headway a period table may give: about 100 trains at most), written as a period table
(:func:`synthetic_table`; ``--tables DIR`` keeps them) and loaded back as ``run
--scenario TABLE`` loads it, run until the
first trains are back at their origin (one cycle), then timed over ``--window-s``
simulated seconds with the brake sensor samples read every step: CPU microseconds of
this process (the figure to compare on a shared machine; the wall time is in the JSON) per
step of the whole loop (:meth:`metro_atc.core.service.dayplant.DayPlant.run`), of its
plant step (one compiled call for the fleet, sensors included), of its ATOs and of the
rest (interlocking, authorities, bookkeeping), and the same per train in service and step.
A flat per-train cost means no part of a step grows faster than the trains in service.
The trains in service are those the day reached (the terminus capacity bounds them at
short headways: the row says how many ran).

**Through the ROS graph** (``--graph``, after ``make setup``).  The same table run by
``python -m metro_atc run --scenario TABLE`` (every node its own process, lockstep) on
``--domain-id`` to the window's end (:func:`graph_row`): the simulator's progress lines at
the window's start and end (``--window-s`` whole progress periods, ``PROGRESS_PERIOD_S``)
give the wall time (their log stamps) and, read as each line appears, the CPU seconds of
every node process; per step and per train-step of the window (the ROS-free row's steps and
train-steps: the same day bit for bit), and each node process's peak resident memory.  The
machine's load averages go with each row: on a shared machine compare the CPU figures.

**Memory.**  The Taipei Blue day (``--trip-times plant``) to ``--rss-end-h`` hours in two
processes, with and without its stop / turnback / depot records
(``python -m metro_atc day --no-records``): resident set size at every simulated hour and
the peak (``getrusage``).  Nothing of the day but its records should grow with the
simulated time.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any, Dict, List, Optional

import yaml

from metro_atc.core.line.scenario import load_scenario
from metro_atc.core.safe_yaml import load_yaml_file
from metro_atc.core.service.day import HEADWAY_RANGE_S, day_file, load_day
from metro_atc.core.service.dayplant import DayPlant, service_day
from metro_atc.core.service.dayrun import day_plant, load_day_run

MIN_HEADWAY_S = HEADWAY_RANGE_S[0]
"""Shortest headway of a synthetic day [s]: the shortest a period table may give."""
START_S = 6.0 * 3600.0
"""First departure of a synthetic day [s after midnight] (a whole hour)."""
PROGRESS_PERIOD_S = 600.0
"""Simulated time between the simulator's progress lines [s] (its ``progress_period_s``
default): the graph's window runs from one line to a later one."""


MAX_TRAINS = 125
"""Most trains a synthetic day may target (its fleet, four times that, within a table's)."""


def cycle_s(dp: DayPlant) -> float:
    """A train's cycle on the loop [s]: both trips plus both termini's turnback layovers."""
    by_dir: Dict[str, float] = {}
    for b in dp.circ.blocks:
        for t in b.trips:
            by_dir.setdefault(t.origin, t.arrival_s - t.departure_s)
    return sum(by_dir.values()) + sum(t.min_turnback_s for t in dp.termini)


def synthetic_table(n_trains: int, window_s: float, path: Path, seed: int = 0) -> Path:
    """Write the period table of the synthetic day for ~``n_trains`` in service to ``path``.

    The shipped Taipei Blue table (termini, depots, transition, line) with its name, fleet
    and periods replaced: one period from ``START_S`` whose headway is the loop's cycle
    (:func:`cycle_s`, trip times ``plant``) over ``n_trains`` (at least ``MIN_HEADWAY_S``),
    lasting two cycles plus the window, rounded up to whole hours (the table counts hours).
    Both the ROS-free rows and the graph rows run this table (:func:`synthetic_day`).
    """
    raw = load_yaml_file(day_file())
    probe = service_day(load_scenario(raw["line"]), load_day(None), seed=seed,
                        trip_times="plant")
    cyc = cycle_s(probe)
    hw = max(MIN_HEADWAY_S, float(round(cyc / n_trains)))
    hours = math.ceil((2.0 * cyc + window_s) / 3600.0)
    raw.update(
        name=f"day_scale_{n_trains}", fleet=max(4 * n_trains, int(raw["fleet"])),
        sources=f"bench day-scale: the shipped {raw['name']} table with one synthetic "
                f"period keeping ~{n_trains} trains in service",
        periods=[{"name": f"scale{n_trains}", "start_h": START_S / 3600.0,
                  "end_h": START_S / 3600.0 + hours, "headway_s": hw, "flow_up": 1.0,
                  "flow_down": 1.0, "estimate": True,
                  "basis": "bench day-scale: a synthetic period"}])
    path.write_text(yaml.safe_dump(raw, sort_keys=False, width=99))
    return path


def synthetic_day(table: Path, seed: int = 0) -> DayPlant:
    """The day plant of a :func:`synthetic_table` (as ``run --scenario TABLE`` builds it)."""
    return day_plant(load_day_run(str(table)), seed=seed)


def window_s_of(dp: DayPlant, window_s: float) -> tuple[float, float]:
    """The timed window of a synthetic day [s after midnight].

    It starts one cycle after the first trip, at the next whole progress period (the
    simulator's progress lines time the graph's window).
    """
    first = min(b.trips[0].departure_s for b in dp.circ.blocks)
    t_on = PROGRESS_PERIOD_S * math.ceil((first + cycle_s(dp)) / PROGRESS_PERIOD_S)
    return t_on, t_on + window_s


def scale_row(n_trains: int, window_s: float, table: Path, seed: int = 0) -> Dict[str, Any]:
    """The timed window of the day of ``table`` ROS-free (see the module docstring)."""
    dp = synthetic_day(table, seed)
    first = min(b.trips[0].departure_s for b in dp.circ.blocks)
    t_on, _ = window_s_of(dp, window_s)
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
        "mean_in_service": ts / max(steps, 1), "steps": steps, "train_steps": ts,
        "train_steps_to_end": r1.train_steps,
        "wall_us_per_step": 1e6 * wall / max(steps, 1),
        "us_per_step": 1e6 * cpu / max(steps, 1),
        "us_per_train_step": 1e6 * cpu / max(ts, 1),
        "sensor_samples": r1.sensor_samples - z0,
        "atp_violations": r1.atp_violations, "route_conflicts": r1.route_conflicts}
    for k, v in split.items():
        row[f"{k}_us_per_step"] = 1e6 * v / max(steps, 1)
        row[f"{k}_us_per_train_step"] = 1e6 * v / max(ts, 1)
    return row


def _ros_log_time_s(line: str) -> float:
    """The wall time stamped on a ROS log line (``[INFO] [1795867539.012] [node]: ...``) [s]."""
    return float(line.split("]", 2)[1].strip(" ["))


def _follow(log_dir: Path, marks: List[float], done: Any,
            seen: Dict[float, Dict[str, Any]]) -> None:
    """Follow the simulator's log while the graph runs (until ``done`` is set).

    At each progress line at a time of ``marks`` [s]: its wall stamp and, read at once,
    the CPU seconds of every node process (``pids.json``).
    """
    from metro_atc.launcher import PROGRESS_RE, cpu_seconds
    log, offset, part = log_dir / "line_simulator.log", 0, ""
    while not done.is_set():
        try:
            with log.open("rb") as fh:
                fh.seek(offset)
                chunk = fh.read()
            pids = json.loads((log_dir / "pids.json").read_text())
        except (OSError, ValueError):
            done.wait(0.05)
            continue
        offset += len(chunk)
        lines = (part + chunk.decode("utf-8", errors="replace")).split("\n")
        part = lines.pop()
        for ln in lines:
            m = PROGRESS_RE.search(ln)
            if m is None or float(m[1]) not in marks:
                continue
            seen[float(m[1])] = {"wall_s": _ros_log_time_s(ln), "in_service": int(m[2]),
                                 "cpu_s": {n: cpu_seconds(int(pid))
                                           for n, pid in sorted(pids.items())}}
        done.wait(0.05)


def graph_row(n_trains: int, window_s: float, table: Path, domain_id: int,
              ros_free: Dict[str, Any], seed: int = 0,
              timeout_s: float = 7200.0) -> Dict[str, Any]:
    """The timed window of the day of ``table`` through the ROS graph (multi-process).

    One run of ``python -m metro_atc run --scenario TABLE`` on ``domain_id``
    (:func:`metro_atc.bench.closed_loop.run_graph`) to the window's end; while it runs,
    the simulator's progress lines at the window's start and end (:func:`window_s_of`,
    whole progress periods) give the wall time (their log stamps) and, read at once, the
    CPU seconds of every node process.  Steps and train-steps of the window are the
    ROS-free row's (``ros_free``: the graph's day is the ROS-free day bit for bit; the
    run's train-steps to its end are given next to the ROS-free ones).  The peak resident
    memory per node process is the run's.  The 1- and 5-minute load averages of the
    machine before and after the run go with the row.
    """
    import threading
    from metro_atc.bench.closed_loop import run_graph
    dp = synthetic_day(table, seed)
    dp.start()
    t_on, t_off = window_s_of(dp, window_s)
    load0 = os.getloadavg()
    seen: Dict[float, Dict[str, Any]] = {}
    done = threading.Event()
    with tempfile.TemporaryDirectory(prefix="metro_atc_day_scale_graph_") as tmp:
        out = Path(tmp)
        follow = threading.Thread(target=_follow, args=(out / "logs", [t_on, t_off], done,
                                                        seen), daemon=True)
        follow.start()
        try:
            k = run_graph(str(table.resolve()), "none", seed, t_off + 1.0 - dp.t_start,
                          domain_id, out_dir=out, timeout_s=timeout_s)
        finally:
            done.set()
            follow.join()
    load1 = os.getloadavg()
    if k is None:
        return {"target_trains": n_trains, "error": "the graph run failed (see stderr)"}
    if t_on not in seen or t_off not in seen:
        return {"target_trains": n_trains, "error": "no progress line at the window's "
                f"start {t_on:.0f} s or end {t_off:.0f} s in the simulator's log"}
    a, b = seen[t_on], seen[t_off]
    steps, ts = int(ros_free["steps"]), int(ros_free["train_steps"])
    wall = b["wall_s"] - a["wall_s"]
    cpu = {n: float(c1) - float(a["cpu_s"][n]) for n, c1 in b["cpu_s"].items()
           if c1 is not None and a["cpu_s"].get(n) is not None}
    cpu_all = sum(cpu.values())
    ato = sum(v for n, v in cpu.items() if n.startswith("ato"))
    return {
        "target_trains": n_trains, "window": [t_on, t_off],
        "mean_in_service": ts / max(steps, 1), "steps": steps, "train_steps": ts,
        "train_steps_to_end": k["day"].get("train_steps"),
        "ros_free_train_steps_to_end": ros_free["train_steps_to_end"],
        "wall_us_per_step": 1e6 * wall / max(steps, 1),
        "wall_us_per_train_step": 1e6 * wall / max(ts, 1),
        "cpu_us_per_step": 1e6 * cpu_all / max(steps, 1),
        "cpu_us_per_train_step": 1e6 * cpu_all / max(ts, 1),
        "ato_cpu_us_per_train_step": 1e6 * ato / max(ts, 1),
        "simulator_cpu_us_per_step": 1e6 * cpu.get("line_simulator", math.nan) / max(steps, 1),
        "node_cpu_s": cpu, "node_peak_rss_mb": k["node_peak_rss_mb"],
        "ato_processes": sum(1 for n in cpu if n.startswith("ato")),
        "lockstep_misses": k.get("lockstep_misses"),
        "atp_violations": k.get("atp_violations"),
        "route_conflicts": k["day"].get("route_conflicts"),
        "load_avg_1_5_min": [round(x, 2) for x in (load0[0], load0[1], load1[0], load1[1])]}


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
    ap.add_argument("--graph", action="store_true",
                    help="also time each day through the ROS graph (needs make setup)")
    ap.add_argument("--domain-id", type=int, default=230,
                    help="ROS_DOMAIN_ID of the graph runs (Fast DDS allows <= 232, the tests "
                         "use 30..229)")
    ap.add_argument("--tables", type=Path, default=None,
                    help="keep the synthetic period tables in this directory")
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args(argv)
    if any(n < 1 or n > MAX_TRAINS for n in a.trains):
        ap.error(f"--trains: each in [1, {MAX_TRAINS}]")
    if not 10.0 <= a.window_s <= 86400.0:
        ap.error("--window-s must lie in [10, 86400]")
    if a.graph and a.window_s % PROGRESS_PERIOD_S:
        ap.error(f"--graph: --window-s must be whole progress periods of the simulator "
                 f"({PROGRESS_PERIOD_S:.0f} s)")
    if not 0 <= a.domain_id <= 232:
        ap.error("--domain-id must lie in [0, 232]")
    rows, graph = [], []
    with tempfile.TemporaryDirectory(prefix="metro_atc_day_scale_") as tmp:
        where = Path(tmp) if a.tables is None else a.tables
        where.mkdir(parents=True, exist_ok=True)
        for n in a.trains:
            table = synthetic_table(n, a.window_s, where / f"day_scale_{n}_periods.yaml")
            rows.append(scale_row(n, a.window_s, table))
            if a.graph:
                graph.append(graph_row(n, a.window_s, table, a.domain_id, rows[-1]))
            if not a.json:
                print(f"day-scale: {n} trains done", file=sys.stderr, flush=True)
    rss = [] if a.no_rss else [rss_run(a.rss_end_h, True), rss_run(a.rss_end_h, False)]
    out = {"scale": rows, "graph": graph, "memory": rss, "window_s": a.window_s}
    failed = any("error" in g for g in graph)
    if a.json:
        print(json.dumps(out))
        return 1 if failed else 0
    print("CPU cost of the ROS-free day per step (Taipei Blue loop, sensors read) [us]")
    print(f"{'trains':>7s} {'in svc':>7s} {'step':>9s} {'plant':>8s} {'ato':>8s} "
          f"{'rest':>8s} | {'/train':>7s} {'plant':>7s} {'ato':>7s} {'rest':>7s}")
    for r in rows:
        print(f"{r['target_trains']:7d} {r['mean_in_service']:7.1f} {r['us_per_step']:9.0f} "
              f"{r['plant_us_per_step']:8.0f} {r['ato_us_per_step']:8.0f} "
              f"{r['rest_us_per_step']:8.0f} | {r['us_per_train_step']:7.1f} "
              f"{r['plant_us_per_train_step']:7.1f} {r['ato_us_per_train_step']:7.1f} "
              f"{r['rest_us_per_train_step']:7.1f}")
    if graph:
        print("the same days through the ROS graph: per step of the window, wall [us] and "
              "CPU of all node processes [us]; peak RSS [MB]")
        print(f"{'trains':>7s} {'in svc':>7s} {'wall':>9s} {'/train':>7s} {'cpu':>9s} "
              f"{'/train':>7s} {'sim rss':>8s} {'ato rss':>8s}  load 1/5 min")
    for g in graph:
        if "error" in g:
            print(f"{g['target_trains']:7d} {g['error']}")
            continue
        rss_mb = g["node_peak_rss_mb"]
        ato_mb = max((v for n, v in rss_mb.items() if n.startswith("ato") and v), default=0.0)
        print(f"{g['target_trains']:7d} {g['mean_in_service']:7.1f} "
              f"{g['wall_us_per_step']:9.0f} {g['wall_us_per_train_step']:7.1f} "
              f"{g['cpu_us_per_step']:9.0f} {g['cpu_us_per_train_step']:7.1f} "
              f"{rss_mb.get('line_simulator') or math.nan:8.0f} {ato_mb:8.0f}  "
              f"{g['load_avg_1_5_min']}")
    for m in rss:
        if "error" in m:
            print(f"memory ({'with' if m['records'] else 'without'} records): {m['error']}")
            continue
        hours = ", ".join(f"{h:g} h {mb:.0f}" for h, mb in m["rss_mb_per_hour"])
        print(f"memory {'with' if m['records'] else 'without'} records: peak "
              f"{m['peak_rss_mb']:.0f} MB; RSS per hour [MB]: {hours}")
    return 0 if all(not math.isnan(r["us_per_step"]) for r in rows) and not failed else 1


if __name__ == "__main__":
    raise SystemExit(main())
