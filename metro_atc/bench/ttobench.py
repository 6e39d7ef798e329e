"""TTOBench metro benchmark: every Yizhuang interstation against the independent optimum.

``python -m metro_atc bench ttobench [--json] [--factors 1.05,1.10,1.20] [--runs 0,2,10]
[--grid-m 2] [--out DIR] [--write-reference]``

Instance: TTOBench v1.5 track ``CN_Songjiazhuang_Yizhuang`` with train ``CN_Beijing_Subway``
(vendored, imported with :func:`metro_atc.ttobench.importer.import_ttobench`), the ATO's own
planning limits (:func:`metro_atc.core.bridge.ato_limits_for`: net acceleration <= 1 m/s^2,
braking curves at 80 % of the service brake, limits for the whole train length, programmed
station stopping).  For each interstation and trip time ``factor x`` the flat-out (FOTP)
running time: the independent LP optimum (:mod:`metro_atc.core.ato.oracle`), the DP, MMAS
(Ke 2010 parameters, seed 1; spread over seeds 1-5 on request), ECTP, FCTP and FOTP.
Reported per planner: traction energy at the wheel [kWh], at the substation [kWh] (traction
/ eta_traction - eta_regen x electric braking work within the electric brake's force and
power limits), gap to the optimum [%], running-time error [s], compute time [s] (CPU time,
of the process, not wall time: the figures stay meaningful on a loaded machine).
``--write-reference`` stores the per-instance optima in
``metro_atc/data/ttobench/reference_energies.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path
from typing import Any, Callable, Optional

import numpy as np
from numpy.typing import NDArray

from metro_atc.bench.progress import progress_each
from metro_atc.core.ato import coasting
from metro_atc.core.ato.dp import solve_dp
from metro_atc.core.ato.envelope import RunModel, profile_energy_time
from metro_atc.core.ato.mmas import MmasParams, solve_mmas
from metro_atc.core.ato.oracle import solve_oracle
from metro_atc.core.ato.sections import build_section_tables
from metro_atc.core import laws
from metro_atc.core.bridge import ato_limits_for, track_for, train_for
from metro_atc.core.line.scenario import Scenario, parse_scenario
from metro_atc.core.line.vehicle import TrainParams
from metro_atc.jsonsafe import json_safe
from metro_atc.ttobench.importer import data_dir, import_ttobench

FloatArray = NDArray[np.float64]
J_PER_KWH = 3.6e6
REGEN_MIN_SPEED_MPS = 0.1
"""Speed floor of the electric brake's power limit in TTOBench's energy [m/s]."""
TRACK = "CN_Songjiazhuang_Yizhuang"
TRAIN = "CN_Beijing_Subway"
FACTORS = (1.05, 1.10, 1.20)
"""Trip time / flat-out running time."""
PLANNERS = ("optimum", "dp", "mmas", "ectp", "fctp", "fotp")
REFERENCE_FILE = "reference_energies.json"
ASSUMPTIONS = (
    "train length 141 m (not in the TTOBench train; speed limits hold for the whole train); "
    "net acceleration <= 1 m/s^2 and braking <= 0.8 x (260 kN / 278 t) = 0.748 m/s^2 "
    "(the ATO's planning limits), braking curves to lower limits and to the stop at that "
    "deceleration; traction 310 kN up to 10 m/s then 3100 kW; Davis r0 + r2 v^2; no rotating "
    "mass (rho 0); trip time = factor x the flat-out (full traction, no coasting) running "
    "time under the same limits; substation = traction / 0.70 - 0.80 x electric braking work "
    "within 260 kN and 4333 kW")
"""What the reference energies assume (written into the reference file)."""


ASSUMED_LENGTH_M = 141.0
"""Train length of the Beijing Subway train [m]: not in TTOBench (assumption, stated)."""


def metro_scenario() -> Scenario:
    """The imported TTOBench metro instance (vendored files; length ``ASSUMED_LENGTH_M``)."""
    imp = import_ttobench(TRACK, TRAIN, length_m=ASSUMED_LENGTH_M)
    return parse_scenario(imp.yaml_text(), f"ttobench_{TRACK}.yaml")


def substation_kwh(run: RunModel, s: FloatArray, v: FloatArray) -> tuple[float, float]:
    """(traction at the wheel, net substation energy) [kWh] of a profile (s [m], v [m/s]).

    Substation = traction / eta_traction - eta_regen x electric braking work, the electric
    brake limited to min(service-brake force m b, regen power / v) (line receptivity 1),
    without fade (:func:`metro_atc.core.laws.electric_brake_force_max` with its fade speed at
    the speed floor ``REGEN_MIN_SPEED_MPS``).
    """
    p: TrainParams = run.train
    e_tr, _, force = profile_energy_time(run, s, v)
    ds = np.diff(s)
    vm = np.maximum(0.5 * (v[:-1] + v[1:]), REGEN_MIN_SPEED_MPS)
    # no fade: the law's fade factor min(v / v_fade, 1) is 1 from its fade speed up
    f_el = laws.electric_brake_force_max_array(np.ascontiguousarray(vm), p.mass_kg,
                                               p.max_service_brake_mps2, p.max_regen_power_w,
                                               REGEN_MIN_SPEED_MPS)
    regen = float(np.sum(np.minimum(np.maximum(-force, 0.0), f_el) * ds))
    sub = e_tr / p.traction_efficiency - p.regen_efficiency * regen
    return e_tr / J_PER_KWH, sub / J_PER_KWH


def _timed(fn: Callable[[], Any]) -> tuple[Any, float]:
    """Result of fn() and the CPU time [s] it took (process time: load-independent-ish)."""
    t0 = time.process_time()
    out = fn()
    return out, time.process_time() - t0


def run_instance(run: RunModel, factor: float, grid_m: float, seeds: tuple[int, ...] = (1,),
                 tables: Any = None) -> dict[str, Any]:
    """All planners on one run at ``factor`` x flat-out time; figures and profiles."""
    fo, t_fo = _timed(lambda: coasting.fotp(run, np.inf))
    target = factor * fo.time_s
    out: dict[str, Any] = {"target_s": target, "flat_out_s": fo.time_s, "factor": factor}
    profiles: dict[str, tuple[FloatArray, FloatArray]] = {}
    opt, t_opt = _timed(lambda: solve_oracle(run, target, grid_m))
    profiles["optimum"] = (opt.s_grid, opt.v_profile)
    rows: dict[str, dict[str, Any]] = {
        "optimum": {"energy_kwh": opt.energy_j / J_PER_KWH, "time_s": opt.time_s,
                    "compute_s": t_opt, "status": opt.status, "lp_solves": opt.iterations}}
    dp, t_dp = _timed(lambda: solve_dp(run, target))
    profiles["dp"] = (dp.s_grid, dp.v_profile)
    rows["dp"] = {"energy_kwh": dp.energy_j / J_PER_KWH, "time_s": dp.time_s, "compute_s": t_dp}
    tab, t_tab = (tables, 0.0) if tables is not None else _timed(
        lambda: build_section_tables(run))
    mm_e = []
    first = None
    for sd in seeds:
        mm, t_mm = _timed(lambda: solve_mmas(tab, target, MmasParams(seed=sd)))
        mm_e.append(mm.energy_j / J_PER_KWH)
        if first is None:
            first = (mm, t_mm)
    assert first is not None
    mm, t_mm = first
    profiles["mmas"] = (mm.s_grid, mm.v_profile)
    rows["mmas"] = {"energy_kwh": mm.energy_j / J_PER_KWH, "time_s": mm.time_s,
                    "compute_s": t_mm + t_tab, "compute_online_s": t_mm,
                    "compute_prework_s": t_tab, "seeds": list(seeds),
                    "energy_kwh_per_seed": mm_e,
                    "spread_pct": 100.0 * (max(mm_e) - min(mm_e)) / min(mm_e)}
    for name, fn in (("ectp", coasting.ectp), ("fctp", coasting.fctp)):
        r, t_r = _timed(lambda: fn(run, target))
        profiles[name] = (r.s_grid, r.v_profile)
        rows[name] = {"energy_kwh": r.energy_j / J_PER_KWH, "time_s": r.time_s,
                      "compute_s": t_r, "feasible": bool(r.feasible)}
    profiles["fotp"] = (fo.s_grid, fo.v_profile)
    rows["fotp"] = {"energy_kwh": fo.energy_j / J_PER_KWH, "time_s": fo.time_s,
                    "compute_s": t_fo}
    e_opt = rows["optimum"]["energy_kwh"]
    for name, r in rows.items():
        s, v = profiles[name]
        _, r["substation_kwh"] = substation_kwh(run, np.asarray(s), np.asarray(v))
        r["gap_pct"] = 100.0 * (r["energy_kwh"] / e_opt - 1.0)
        r["time_error_s"] = r["time_s"] - target
    out["planners"] = rows
    out["_profiles"] = profiles
    return out


def plot_run(path: str, run: RunModel, title: str,
             profiles: dict[str, tuple[FloatArray, FloatArray]],
             rows: dict[str, dict[str, Any]]) -> str:
    """Speed vs position of every planner with the limits and the envelope (PNG)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, (ax, axg) = plt.subplots(2, 1, figsize=(10, 6.5), sharex=True,
                                  gridspec_kw={"height_ratios": [3, 1]})
    s = run.s_env
    ax.plot(s, run.static_limit(s) * 3.6, "k-", lw=1.2, label="speed limit (whole train)")
    ax.plot(s, run.ceiling(s) * 3.6, "k:", lw=1, label="envelope (braking curves)")
    styles = {"optimum": ("k", 2.6, "-"), "dp": ("tab:green", 1.4, "-"),
              "mmas": ("tab:blue", 1.2, "--"), "ectp": ("tab:orange", 1.2, "-"),
              "fctp": ("tab:purple", 1.0, "-."), "fotp": ("tab:red", 1.0, ":")}
    for name, (x, v) in profiles.items():
        c, lw, ls = styles[name]
        r = rows[name]
        ax.plot(x, np.asarray(v) * 3.6, color=c, lw=lw, ls=ls, alpha=0.85 if name == "optimum"
                else 1.0, label=f"{name}: {r['energy_kwh']:.3f} kWh ({r['gap_pct']:+.2f} %), "
                f"{r['time_s']:.1f} s")
    ax.set_ylabel("speed [km/h]")
    ax.set_title(title, fontsize=10)
    ax.legend(fontsize=7.5, loc="lower center", ncol=2)
    ax.grid(alpha=0.3)
    ax.set_ylim(bottom=0)
    axg.plot(s, run.grade(s) * 1000.0, "k-", lw=1)
    axg.set_ylabel("grade [per mille]")
    axg.set_xlabel("position from departure [m]")
    axg.grid(alpha=0.3)
    fig.tight_layout()
    os.makedirs(os.path.dirname(path) or ".", exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def main(argv: Optional[list[str]] = None) -> int:
    """Run the benchmark; ``--json`` prints one JSON object, else a table."""
    ap = argparse.ArgumentParser(prog="python -m metro_atc bench ttobench", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    ap.add_argument("--factors", default=",".join(f"{f:.2f}" for f in FACTORS))
    ap.add_argument("--runs", default="", help="interstation indices (default: all)")
    ap.add_argument("--grid-m", type=float, default=2.0, help="oracle grid step [m] (2)")
    ap.add_argument("--seeds", default="1", help="MMAS seeds, e.g. 1,2,3,4,5 (spread)")
    ap.add_argument("--out", default=None, help="directory for the PNG")
    ap.add_argument("--plot-run", default="2:1.10", help="interstation:factor plotted")
    ap.add_argument("--write-reference", action="store_true",
                    help=f"write the optima into metro_atc/data/ttobench/{REFERENCE_FILE}")
    a = ap.parse_args(argv)
    factors = tuple(float(x) for x in a.factors.split(","))
    seeds = tuple(int(x) for x in a.seeds.split(","))
    scn = metro_scenario()
    train = train_for(scn)
    track = track_for(scn)
    limits = ato_limits_for(train)
    pos = [st.position_m for st in scn.line.stations]
    idx = [int(x) for x in a.runs.split(",")] if a.runs else list(range(len(pos) - 1))
    plot_i, plot_f = a.plot_run.split(":")
    results: list[dict[str, Any]] = []
    plots: list[str] = []
    for i in progress_each("bench ttobench", idx, "runs"):
        run = RunModel(train, track, pos[i], pos[i + 1], limits)
        tab = build_section_tables(run)
        for f in factors:
            r = run_instance(run, f, a.grid_m, seeds, tables=tab)
            prof = r.pop("_profiles")
            r.update({"interstation": i, "from_m": pos[i], "to_m": pos[i + 1]})
            results.append(r)
            if a.out and i == int(plot_i) and abs(f - float(plot_f)) < 1e-9:
                title = (f"TTOBench {TRACK} + {TRAIN}: {pos[i]:.0f} -> {pos[i + 1]:.0f} m, "
                         f"trip time {f:.2f} x flat-out = {r['target_s']:.1f} s")
                plots.append(plot_run(os.path.join(a.out, f"ttobench_{i}_{f:.2f}.png"), run,
                                      title, prof, r["planners"]))
            if not a.json:
                pl = r["planners"]
                print(f"{i:2d} {pos[i]:7.0f}->{pos[i + 1]:7.0f} x{f:.2f} T={r['target_s']:6.1f}s "
                      f"opt {pl['optimum']['energy_kwh']:7.3f} kWh | " + " ".join(
                          f"{n} {pl[n]['gap_pct']:+6.2f}% ({pl[n]['time_error_s']:+.2f}s)"
                          for n in PLANNERS[1:]), flush=True)
    summary: dict[str, Any] = {}
    for n in PLANNERS[1:]:
        gaps = [r["planners"][n]["gap_pct"] for r in results]
        terr = [abs(r["planners"][n]["time_error_s"]) for r in results]
        comp = [r["planners"][n]["compute_s"] for r in results]
        summary[n] = {"max_gap_pct": max(gaps), "mean_gap_pct": float(np.mean(gaps)),
                      "max_abs_time_error_s": max(terr),
                      "median_compute_s": float(np.median(comp))}
    out = {"instance": {"track": TRACK, "train": TRAIN, "library": "TTOBench v1.5",
                        "limits": {"accel_max_mps2": limits.accel_max_mps2,
                                   "brake_decel_mps2": limits.brake_decel_mps2},
                        "oracle_grid_m": a.grid_m},
           "summary": summary, "runs": results, "plots": plots}
    if a.write_reference:
        ref = {"source": "python -m metro_atc bench ttobench --write-reference "
                         f"(metro_atc.core.ato.oracle, LP on a {a.grid_m:g} m grid)",
               "instance": out["instance"],
               "energy_definition": "minimum traction energy at the wheel [kWh] for running "
                                    "time <= target_s (factor x flat-out), ATO planning limits",
               "assumptions": ASSUMPTIONS,
               "values": [{"interstation": r["interstation"], "from_m": r["from_m"],
                           "to_m": r["to_m"], "factor": r["factor"],
                           "target_s": round(r["target_s"], 3),
                           "energy_kwh": round(r["planners"]["optimum"]["energy_kwh"], 5),
                           "substation_kwh": round(r["planners"]["optimum"]["substation_kwh"],
                                                   5)}
                          for r in results]}
        path = Path(data_dir()) / REFERENCE_FILE
        src_path = Path(__file__).resolve().parents[1] / "data" / "ttobench" / REFERENCE_FILE
        target = src_path if src_path.parent.is_dir() else path
        target.write_text(json.dumps(ref, indent=1) + "\n", encoding="utf-8")
        out["reference_file"] = str(target)
    if a.json:
        print(json.dumps(json_safe(out), allow_nan=False))
    else:
        for n, sm in summary.items():
            print(f"{n:5s}: max gap {sm['max_gap_pct']:+.2f} %, mean {sm['mean_gap_pct']:+.2f} %,"
                  f" max |time error| {sm['max_abs_time_error_s']:.2f} s, median compute "
                  f"{sm['median_compute_s']:.2f} s")
        for p in plots:
            print("wrote", p)
    sys.stdout.flush()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
