"""Benchmark: speed of the ROS-free line plant core.

``python -m metro_atc.bench.perf [--json] [--out DIR] [--quick] [--seed N] [--scenario S]
[--per-step]``

Runs the scenario (default ``taipei_blue``: one peak hour of departures, 30 trains, plus the
run-out) headless with the reference driver :func:`simple_driver` in lockstep
(:meth:`LineSim.run_driven`: with the numba kernel, the steps between two discrete events
run several per compiled call; ``--per-step``: one ``step`` call per step, the same
results bit for bit) and reports
the core real-time factor ``core_rtf`` = simulated time / wall time (``core_rtf_cpu`` per
CPU second of this process: the figure to compare on a loaded machine; both also with the
sensor samples consumed, ``core_rtf_with_sensors[_cpu]``),
where the time goes (driver vs plant step, cProfile top functions), the cost of consuming
the brake sensor samples, the energy-balance closure and the safety KPIs.

``day``: the ROS-free two-direction service day (:mod:`metro_atc.core.service.dayplant`,
the Taipei Blue day with the plant's trip times) from its first pull-out to
``--day-end-h`` (default 08:00: two simulated hours, the ramp-up and the first hour of the
morning peak; ``--day-full``: the whole day; 0: skipped), the brake sensor samples read every
step: ``day.plant_rtf_cpu`` is the simulated span over the CPU time of its plant steps (the
fleet in one compiled call per step, sensors included: the day's ROS-free core),
``day.rtf`` / ``day.rtf_cpu`` over the whole loop's wall / CPU time (plant, the ATO of every
train, interlocking and bookkeeping).  ``day_graph``: the same span of the
``taipei_blue_day`` through the multi-process ROS graph (``python -m metro_atc run
--scenario taipei_blue_day --duration <span>``, the period table's trip times; the whole
day with ``--day-full``): its stepping loop's real-time factor, the trips run and the peak
memory of every node process (``--no-graph`` skips it).

``graph_rtf`` is the multi-process ROS graph's factor: ``python -m metro_atc run`` (all
four node kinds as separate processes, lockstep) on the same scenario for
``--graph-duration`` simulated seconds (default 1800 s: the ramp-up and the 105 s peak,
trains in service rising to ~18); ``--no-graph`` skips it (e.g. without a colcon build).
It is the launcher's whole wall time (five processes started, DDS discovery, the end);
``graph.loop_real_time_factor`` is its stepping loop alone.
"""

from __future__ import annotations

import argparse
import cProfile
import io
import json
import pstats
import sys
import time
from typing import Any

import numpy as np

from metro_atc.bench.progress import Progress, progress_enabled
from metro_atc.core.plant.driver import simple_driver
from metro_atc.core.plant.line import LineSim
from metro_atc.core.line.scenario import load_scenario

PROGRESS_CHUNK_S = 100.0
"""Simulated time between two progress rows of :func:`run_core` [s]."""
TARGET_CORE_RTF = 5000.0
"""Target for the core-only real-time factor."""
TARGET_GRAPH_RTF = 100.0
TARGET_DAY_GRAPH_RTF = 150.0
"""Target: the whole service day through the ROS graph in lockstep (a day in ~7 min)."""
DAY_SCENARIO = "taipei_blue_day"
"""Target for the ROS graph real-time factor (whole Blue line peak, 2 cores)."""
TARGET_CORE_RTF_SENSORS = 6000.0
"""Target: core real-time factor with the sensor samples consumed (quiet machine)."""
TARGET_DAY_CORE_RTF = 3000.0
"""Target: the service day's ROS-free core (plant step with sensors) real-time factor."""
DAY_END_H = 8.0
"""Default end of the ``day`` row [h after midnight] (from the first pull-out at ~05:58)."""


def run_day_core(end_h: float | None, seed: int) -> dict[str, Any]:
    """The Taipei Blue service day to ``end_h`` (None: the whole day), sensor samples read.

    Returns its speed figures (:meth:`metro_atc.core.service.dayplant.DayResult.speed`),
    trains, trips and safety counts.
    """
    from metro_atc.core.service.day import load_day
    from metro_atc.core.service.dayplant import service_day
    dp = service_day(load_scenario("taipei_blue"), load_day(None), seed=seed,
                     trip_times="plant")
    res = dp.run(None if end_h is None else end_h * 3600.0, sensors=True)
    return {**{k: round(v, 3) for k, v in res.speed().items()},
            "wall_s": round(res.wall_s, 1), "end_h": end_h,
            "trips_run": res.trips_run,
            "trips_planned": res.trips_planned, "fleet": res.fleet,
            "finished": res.finished, "sensor_samples": res.sensor_samples,
            "atp_violations": res.atp_violations, "route_conflicts": res.route_conflicts}


def energy_balance_error(sim: LineSim) -> float:
    """Largest per-train relative closure error of the mechanical energy balance [-].

    traction work = kinetic energy + grade work + resistance + curve + rail braking.
    """
    e = sim.energy_breakdown()
    resid = (e["traction_wheel"] - e["brake_rail"] - e["resistance"] - e["curve"]
             - e["grade"] - e["kinetic"])
    scale = np.maximum(e["traction_wheel"], 1.0)
    return float(np.max(np.abs(resid) / scale))


def run_core(scenario: str, seed: int, sim_limit_s: float | None, sensors: bool,
             profile: bool = False, label: str = "",
             per_step: bool = False) -> dict[str, Any]:
    """Run a scenario headless; returns timing, KPIs and (optionally) a profile.

    The reference driver runs through :meth:`LineSim.run_driven` (several steps per
    compiled call with the numba kernel; the samples of every step read when ``sensors``);
    ``per_step``: the loop ``step(simple_driver(sim))`` instead (same results, bit for bit;
    the one that times the driver apart).

    ``label``: progress rows on stderr (:mod:`metro_atc.bench.progress`) under this name.
    The plant step's compilation / cache load happens while the plant is built, before the
    timing.
    """
    sim = LineSim(load_scenario(scenario), seed=seed)
    limit = sim.duration_s if sim_limit_s is None else sim_limit_s
    prog = Progress(f"bench perf: {label}", limit, "s simulated", rate_name="rtf",
                    enabled=None if label else False)
    prof = cProfile.Profile() if profile else None
    n_samples = 0
    t_drv = 0.0
    w0 = time.perf_counter()
    c0 = time.process_time()
    if prof is not None:
        prof.enable()
    kernel_steps = 0
    while not per_step and not sim.done and sim.t < limit:
        run = sim.run_driven(min(limit, sim.t + PROGRESS_CHUNK_S), samples=sensors)
        n_samples += run.n_samples
        kernel_steps += run.kernel_steps
        if prog.enabled:
            prog.update(sim.t, f"{int(sim.active_mask().sum())} trains in service")
    while per_step and not sim.done and sim.t < limit:
        d0 = time.perf_counter()
        u = simple_driver(sim)
        t_drv += time.perf_counter() - d0
        res = sim.step(u)
        if prog.enabled and sim.step_count % 400 == 0:
            prog.update(sim.t, f"{int(sim.active_mask().sum())} trains in service")
        if sensors:
            blk = res.sensor_arrays
            if blk is not None:
                n_samples += blk.t.size * blk.trains.size
    if prof is not None:
        prof.disable()
    wall = time.perf_counter() - w0
    cpu = time.process_time() - c0
    out: dict[str, Any] = {
        "sim_time_s": sim.t, "wall_s": wall, "cpu_s": cpu, "steps": sim.step_count,
        "rtf": sim.t / wall, "rtf_cpu": sim.t / max(cpu, 1e-9),
        "us_per_step": wall / max(sim.step_count, 1) * 1e6,
        "driver_share": t_drv / wall if per_step else None,
        "kernel_step_share": kernel_steps / max(sim.step_count, 1), "trains": sim.n,
        "sensor_samples": n_samples,
        "kpis": sim.kpis(), "energy_balance_error": energy_balance_error(sim), "sim": sim,
        "plant_kernel": "numba",  # the only plant step (kept for the JSON's readers)
        "kernel_warmup_s": float(getattr(sim.stepper, "warm_s", 0.0)),
        "stop_correction_share": float(sim.energy.e_stop_corr.sum()
                                       / max(float(sim.energy.e_brake_rail.sum()), 1.0)),
    }
    if prof is not None:
        s = io.StringIO()
        pstats.Stats(prof, stream=s).sort_stats("tottime").print_stats(8)
        rows = []
        st = pstats.Stats(prof).sort_stats("tottime")
        for (fn, line, name), (_, nc, tt, ct, _) in list(st.stats.items()):  # type: ignore
            rows.append((tt, f"{fn.split('/')[-1]}:{line}({name})", nc, ct))
        rows.sort(reverse=True)
        out["profile_top"] = [{"function": r[1], "calls": r[2], "tottime_s": round(r[0], 4),
                               "cumtime_s": round(r[3], 4)} for r in rows[:8]]
    return out


def run_graph(scenario: str, seed: int, duration_s: float) -> dict[str, Any] | None:
    """Run the multi-process ROS graph for ``duration_s`` simulated seconds; speed KPIs.

    ``python -m metro_atc run --json`` on a private domain id (the closed-loop bench's
    runner); None (with the reason on stderr) when the graph cannot run here.
    """
    from metro_atc.bench.closed_loop import run_graph as run_one
    k = run_one(scenario, "none", seed, duration_s, domain_id=230, progress=progress_enabled())
    if k is None:
        return None
    keys = ("real_time_factor", "wall_time_s", "loop_real_time_factor", "loop_wall_s",
            "sim_time_s", "steps", "trains", "lockstep_misses", "atp_violations")
    return {key: k.get(key) for key in keys}


def run_day_graph(seed: int, span_s: float | None) -> dict[str, Any] | None:
    """The service day through the graph for ``span_s`` from its first step (None: whole).

    Speed, trips and each node process's peak memory; None (reason on stderr) when the
    graph cannot run here.
    """
    from metro_atc.bench.closed_loop import run_graph as run_one
    k = run_one(DAY_SCENARIO, "none", seed, 0.0 if span_s is None else span_s,
                domain_id=230, timeout_s=7200.0, progress=progress_enabled())
    if k is None:
        return None
    day = k.get("day") or {}
    rss = {n: v for n, v in (k.get("node_peak_rss_mb") or {}).items() if v is not None}
    return {"loop_real_time_factor": k.get("loop_real_time_factor"),
            "real_time_factor": k.get("real_time_factor"), "wall_time_s": k.get("wall_time_s"),
            "sim_span_s": float(k.get("sim_time_s", 0.0)) - float(k.get("sim_start_s", 0.0)),
            "lockstep_misses": k.get("lockstep_misses"),
            "atp_violations": k.get("atp_violations"), "finished": k.get("finished"),
            "trips_run": day.get("trips_run"), "trips_planned": day.get("trips_planned"),
            "route_conflicts": day.get("route_conflicts"),
            "node_peak_rss_mb": rss, "peak_rss_mb_max": max(rss.values(), default=None)}


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark; ``--json`` prints one JSON object."""
    ap = argparse.ArgumentParser(prog="metro_atc.bench.perf", description=__doc__.split("\n")[0])
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    ap.add_argument("--out", default=None, help="directory for the run's PNGs/KPIs/events")
    ap.add_argument("--quick", action="store_true",
                    help="first 900 s of simulated time only (the day row: to 06:15)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--scenario", default="taipei_blue")
    ap.add_argument("--graph-duration", type=float, default=1800.0,
                    help="simulated seconds of the ROS graph run (graph_rtf)")
    ap.add_argument("--no-graph", action="store_true", help="skip the ROS graph run")
    ap.add_argument("--per-step", action="store_true",
                    help="one step(simple_driver(sim)) call per step (the previous loop)")
    ap.add_argument("--day-end-h", type=float, default=DAY_END_H,
                    help="the day row runs the Taipei Blue day to this hour (0: skip it)")
    ap.add_argument("--day-full", action="store_true", help="the day row: the whole day")
    a = ap.parse_args(argv)
    if not (a.day_end_h == 0.0 or 6.0 < a.day_end_h <= 30.0):
        ap.error("--day-end-h must be 0 or in (6, 30]")
    limit = 900.0 if a.quick else None
    main_run = run_core(a.scenario, a.seed, limit, sensors=False, label="core 1/3",
                        per_step=a.per_step)
    sens_run = run_core(a.scenario, a.seed, limit, sensors=True,
                        label="core 2/3 (sensors)", per_step=a.per_step)
    prof_run = run_core(a.scenario, a.seed, 600.0, sensors=False, profile=True,
                        label="core 3/3 (cProfile)", per_step=a.per_step)
    if progress_enabled() and not a.no_graph:
        print("bench perf: graph run (python -m metro_atc run)", file=sys.stderr, flush=True)
    day_end = None if a.day_full else (6.25 if a.quick else a.day_end_h)
    if progress_enabled() and (day_end or a.day_full):
        print("bench perf: the service day (ROS-free)", file=sys.stderr, flush=True)
    day = run_day_core(day_end, a.seed) if (a.day_full or day_end) else None
    k = main_run["kpis"]
    graph = None if a.no_graph else run_graph(a.scenario, a.seed,
                                              300.0 if a.quick else a.graph_duration)
    if progress_enabled() and not a.no_graph and day is not None:
        print("bench perf: the service day through the graph", file=sys.stderr, flush=True)
    day_graph = None if a.no_graph or day is None else run_day_graph(
        a.seed, None if a.day_full else day["sim_span_s"])
    result: dict[str, Any] = {
        "scenario": a.scenario,
        "plant_kernel": main_run["plant_kernel"],
        "kernel_warmup_s": round(main_run["kernel_warmup_s"], 3),
        "core_rtf": round(main_run["rtf"], 1),
        "core_rtf_cpu": round(main_run["rtf_cpu"], 1),
        "core_us_per_step": round(main_run["us_per_step"], 1),
        "core_driver_share": (None if main_run["driver_share"] is None
                              else round(main_run["driver_share"], 3)),
        "core_kernel_step_share": round(main_run["kernel_step_share"], 4),
        "core_rtf_with_sensors": round(sens_run["rtf"], 1),
        "core_rtf_with_sensors_cpu": round(sens_run["rtf_cpu"], 1),
        "sensor_samples_per_s": round(sens_run["sensor_samples"] / sens_run["sim_time_s"], 1),
        "graph_rtf": graph["real_time_factor"] if graph else None,
        "graph": graph,
        "day": day,
        "day_graph": day_graph,
        "trains": main_run["trains"],
        "sim_time_s": round(main_run["sim_time_s"], 2),
        "steps": main_run["steps"],
        "wall_s": round(main_run["wall_s"], 3),
        "completed_trains": k["completed_trains"],
        "atp_violations": k["atp_violations"],
        "atp_interventions": k["atp_interventions"],
        "min_separation_m": k["min_separation_m"],
        "energy_kwh": round(k["energy_kwh"], 2),
        "energy_balance_error": main_run["energy_balance_error"],
        "energy_stop_correction_share": main_run["stop_correction_share"],
        "max_delay_s": k["max_delay_s"],
        "targets": {"core_rtf": TARGET_CORE_RTF, "graph_rtf": TARGET_GRAPH_RTF,
                    "core_rtf_with_sensors": TARGET_CORE_RTF_SENSORS,
                    "day_plant_rtf_cpu": TARGET_DAY_CORE_RTF,
                    "day_graph_loop_rtf": TARGET_DAY_GRAPH_RTF},
        "profile_top": prof_run["profile_top"],
        "quick": a.quick,
        "seed": a.seed,
    }
    if a.out:
        from metro_atc.plots import write_outputs
        write_outputs(main_run["sim"], a.out)
    if a.json:
        print(json.dumps(result))
        return 0
    print(f"line plant core benchmark -- scenario {a.scenario} (seed {a.seed})")
    print(f"{'quantity':34s} {'target':>18s} {'ours':>14s}")
    rows = [
        ("core real-time factor (wall)", f">= {TARGET_CORE_RTF:.0f}", f"{result['core_rtf']:.0f}"),
        ("core real-time factor (CPU time)", "", f"{result['core_rtf_cpu']:.0f}"),
        ("plant kernel (JIT / cache load [s])", "",
         f"{result['plant_kernel']} ({result['kernel_warmup_s']:.1f})"),
        ("  with sensor samples consumed", f">= {TARGET_CORE_RTF_SENSORS:.0f}",
         f"{result['core_rtf_with_sensors']:.0f}"),
        ("    (CPU time)", "", f"{result['core_rtf_with_sensors_cpu']:.0f}"),
        ("wall time per lockstep step [us]", "", f"{result['core_us_per_step']:.0f}"),
        ("  of which reference driver", "",
         "in the call" if result["core_driver_share"] is None
         else f"{100 * result['core_driver_share']:.0f} %"),
        ("steps in multi-step compiled calls", "",
         f"{100 * result['core_kernel_step_share']:.1f} %"),
        ("graph real-time factor", f">= {TARGET_GRAPH_RTF:.0f}",
         f"{result['graph_rtf']:.1f}" if result["graph_rtf"] is not None else "skipped"),
        ("  its stepping loop alone", "",
         f"{result['graph']['loop_real_time_factor']:.1f}"
         if result["graph"] and result["graph"].get("loop_real_time_factor") else "-"),
        ("day core RTF, sensors (CPU)", f">= {TARGET_DAY_CORE_RTF:.0f}",
         f"{day['plant_rtf_cpu']:.0f}" if day else "skipped"),
        ("  day to" + (" the end" if day and day["end_h"] is None
                       else f" {day['end_h']:g} h" if day else ""), "",
         f"{day['sim_span_s']:.0f} s sim" if day else "-"),
        ("  whole day loop RTF (wall / CPU)", "",
         f"{day['rtf']:.0f} / {day['rtf_cpu']:.0f}" if day else "-"),
        ("  CPU per train in service, step [us]", "",
         f"{day['cpu_us_per_train_step']:.1f}" if day else "-"),
        ("day through the graph, loop RTF", f">= {TARGET_DAY_GRAPH_RTF:.0f}",
         f"{day_graph['loop_real_time_factor']:.0f}" if day_graph else "skipped"),
        ("  trips run / planned", "",
         f"{day_graph['trips_run']} / {day_graph['trips_planned']}" if day_graph else "-"),
        ("  peak memory of a node [MB]", "",
         f"{day_graph['peak_rss_mb_max']:.0f}"
         if day_graph and day_graph["peak_rss_mb_max"] is not None else "-"),
        ("trains", ">= 25", f"{result['trains']}"),
        ("simulated time [s]", "", f"{result['sim_time_s']:.0f}"),
        ("completed trains", "all", f"{result['completed_trains']}"),
        ("ATP violations", "0", f"{result['atp_violations']}"),
        ("ATP interventions", "", f"{result['atp_interventions']}"),
        ("energy balance closure error", "<= 0.1 %",
         f"{100 * result['energy_balance_error']:.2e} %"),
        ("  braking work re-assigned at stops", "",
         f"{100 * result['energy_stop_correction_share']:.1e} %"),
        ("substation energy [kWh]", "", f"{result['energy_kwh']:.0f}"),
    ]
    for r in rows:
        print(f"{r[0]:34s} {r[1]:>18s} {r[2]:>14s}")
    print("where the time goes (cProfile, 600 s of simulated time, tottime):")
    for p in result["profile_top"]:
        print(f"  {p['tottime_s']:8.3f} s  {p['calls']:7d} calls  {p['function']}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
