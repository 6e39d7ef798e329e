"""Bench: energy-aware automatic train regulation (Sheu 2011 abstract) on the Taipei Blue line.

Compares the plain LQR of Lin 2010a with the energy-aware LQR of
:mod:`metro_atc.core.atr.energy` (u = -K x + u_ff from the second-order expansion of the
energy-running-time curves E_j(R) of the ATO core's DP minimum-energy planner) for a few
energy weights w_E, on the ATR truth traffic model (control saturation, crowding dwell,
knock-on delays, exponential departure delays; :mod:`metro_atc.core.atr.evaluation`) of the
``taipei_blue`` scenario (:func:`metro_atc.core.bridge.atr_line_for`: geometry and running
times of the simulator's timetable, so that the ATR line and the energy curves describe the
same runs).  Four cases, K = 40 services each:

- ``incident``: 180 s departure delay at the first station plus exponential departure
  delays (Lin 2010a, Exp. 2; as ``bench regulation``), several seeds;
- ``disturbed``: exponential departure delays only, same seeds;
- ``undisturbed``: no delay, no disturbance (the energy-aware steady state alone);
- ``incident_linear``: the 180 s delay on the linear model both LQRs are designed on
  (no saturation, crowding, knock-on or disturbance): the reference where the plain LQR
  must have the lower schedule cost.

Per method: the schedule-deviation cost of Lin 2010a (:func:`~metro_atc.core.atr.evaluation.kpis`),
the traction energy per service [kWh] (E_j of the realised running times, see
``assumptions``), worst and mean terminal delay [s], recovery time [s].  Seed 003's energy
savings are not in the extraction (only its abstract), so no paper figures are printed.

Run:  python -m metro_atc bench energy-regulation [--json] [--seeds 5] [--weights 0.5,1,2,5]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from typing import Any, Dict, List, Optional

import numpy as np

from metro_atc.bench.progress import progress_each
from metro_atc.core.atr.blue_line import LineData
from metro_atc.core.atr.cost import CostWeights, terminal_matrix
from metro_atc.core.atr.energy import (
    ENERGY_SOURCES, J_PER_KWH, EnergyLqrRegulator, EnergyTable, energy_table_for, energy_term,
    run_adjustment)
from metro_atc.core.atr.evaluation import incident_scenario, kpis, simulate
from metro_atc.core.atr.regulators import Regulator, lqr_gain, make_regulator
from metro_atc.core.atr.traffic import linear_model, timetable_state
from metro_atc.core.bridge import ato_limits_for
from metro_atc.jsonsafe import json_safe

SCENARIO = "taipei_blue"
INITIAL_DELAY_S = 180.0
DEFAULT_WEIGHTS = (0.5, 1.0, 2.0, 5.0)
CASES = ("incident", "disturbed", "undisturbed", "incident_linear")
LINEAR_FLAGS = {"saturation": False, "knock_on": False, "crowding": False}
CHECK_RUNS = (0, 8)
KPI_KEYS = ("cost", "energy_kwh_per_service", "worst_terminal_delay_s",
            "mean_terminal_delay_s", "recovery_time_s", "mean_run_extension_s",
            "knock_on_run_fraction", "energy_term_w1")
ASSUMPTIONS = [
    "Sheu 2011: only the dissertation abstract is in the extraction (energy model folded into "
    "the regulation cost, 'considerable energy savings'); the energy model, cost and weights "
    "here are our reconstruction, no paper figures to compare",
    "E_j(R): traction energy at the wheel [J] of the DP minimum-energy profile (ATO core, "
    "metro_atc.core.ato.dp; lower convex hull of E + mu T optima) of run j for running time R, "
    "scenario train and track, ATO planning limits; regenerated braking energy not credited, "
    "auxiliary power not counted; fitted by a + b/(R - c) over [run_min, run_max]",
    "energy per service = sum over the K stages of E_j(realised running time) / K; realised "
    "running time = arrival - departure in the truth model (scheduled + saturated running "
    "adjustment, lengthened by knock-on waits); running times above run_max are charged the "
    "run_max energy (no credit for waiting, restart energy not counted)",
    "energy weight: U_E = U + w_E sum_j (E_j(R_j + du_run_j) - E_j(R_j)) / E_s with E_s the "
    "scheduled traction energy of one service, so w_E = 1 prices a whole service's traction "
    "energy like a 60 s deviation at two stations (U = 1/2 q (x/60 s)^2 per station)",
    "both LQRs use the linear Lin 2010a model without saturation; the energy-aware one expands "
    "E_j to second order at the scheduled running time (affine LQR: constant feed-forward "
    "offset); the steady-state offset asks for a shorter dwell at the first station, which "
    "the scenario's minimum dwell forbids (saturated to 0 in the truth model)",
    "ATR line from the taipei_blue scenario (metro_atc.core.bridge.atr_line_for), not the "
    "blue_line estimates used by 'bench regulation': the ATR line and the energy curves "
    "then describe the same runs",
    "disturbances: seeded exponential departure delays (incident_scenario), mean from the "
    "scenario; one realisation per seed",
]


def realised_running_times(line: LineData, traj: Dict[str, np.ndarray]
                           ) -> tuple[np.ndarray, np.ndarray]:
    """Running times [s] of every run in every stage (steps, N-1) and a knock-on mask.

    Mirrors the arrival of :func:`metro_atc.core.atr.traffic.truth_step`: departure from
    station i-1 + scheduled running time + saturated running adjustment, delayed to
    ``separation_min_s`` after the previous train left station i (knock-on).
    """
    dep = timetable_state(line, 0) + traj["x"][:-1]
    free = dep[:, :-1] + line.run_s + run_adjustment(line, traj["u_cmd"])
    arr = np.maximum(free, dep[:, 1:] + line.separation_min_s)
    return arr - dep[:, :-1], arr > free + 1e-9


def trajectory_kpis(line: LineData, table: EnergyTable, traj: Dict[str, np.ndarray],
                    weights: CostWeights, p0: np.ndarray) -> Dict[str, float]:
    """Seed 000 KPIs plus energy per service [kWh], mean terminal delay, run extension."""
    out = kpis(traj, line, weights, p0)
    r, knock = realised_running_times(line, traj)
    out["energy_kwh_per_service"] = float(np.sum(table.energy_j(r)) / r.shape[0] / J_PER_KWH)
    out["mean_terminal_delay_s"] = float(np.mean(traj["x"][:, -1]))
    out["mean_run_extension_s"] = float(np.mean(r - line.run_s))
    out["knock_on_run_fraction"] = float(np.mean(knock))
    # sum over the stages of the energy term of U_E at w_E = 1 (applied adjustments)
    out["energy_term_w1"] = float(np.sum(energy_term(line, table, traj["u_applied"], 1.0)))
    return out


def _case(line: LineData, case: str, seed: int, steps: int) -> Dict[str, np.ndarray]:
    if case in ("undisturbed", "incident_linear"):
        x0 = np.zeros(line.n_stations)
        x0[0] = INITIAL_DELAY_S if case == "incident_linear" else 0.0
        return {"x0": x0, "w": np.zeros((steps, line.n_stations))}
    delay = INITIAL_DELAY_S if case == "incident" else 0.0
    return incident_scenario(line, delay, 10_000 * (seed + 1), steps)


def dp_cross_check(scenario: str, line: LineData, table: EnergyTable) -> List[Dict[str, Any]]:
    """Table and fit vs :func:`metro_atc.core.ato.dp.solve_dp` at scheduled running times."""
    from metro_atc.core.ato.dp import solve_dp
    from metro_atc.core.ato.envelope import RunModel
    from metro_atc.core.bridge import timetable_for, track_for, train_for
    from metro_atc.core.line.scenario import load_scenario
    scn = load_scenario(scenario)
    pos = timetable_for(scn).station_positions_m
    train = train_for(scn)
    rows = []
    for j in [j for j in CHECK_RUNS if j < table.n_runs]:
        run_m = RunModel(train, track_for(scn), float(pos[j]), float(pos[j + 1]),
                         ato_limits_for(train))
        t0 = time.perf_counter()
        res = solve_dp(run_m, float(line.run_s[j]))
        rows.append({"run": j, "running_time_s": float(line.run_s[j]),
                     "solve_dp_kwh": res.energy_j / J_PER_KWH,
                     "solve_dp_hull_kwh": res.hull_energy_j / J_PER_KWH,
                     "table_kwh": float(table.tabulated_energy_j(line.run_s)[j]) / J_PER_KWH,
                     "fit_kwh": float(table.e_sched_j[j]) / J_PER_KWH,
                     "solve_dp_seconds": time.perf_counter() - t0})
    return rows


def run(seeds: List[int], w_list: List[float], source: str = "dp",
        scenario: str = SCENARIO) -> Dict[str, Any]:
    """Evaluate LQR and the energy-aware LQR per weight on the three cases."""
    t0 = time.perf_counter()
    from metro_atc.core.bridge import atr_line_for
    from metro_atc.core.line.scenario import load_scenario
    line = atr_line_for(load_scenario(scenario))
    table = energy_table_for(scenario, source)
    t_table = time.perf_counter() - t0
    weights = CostWeights()
    a, b = linear_model(line.c())
    p0 = terminal_matrix(a, weights.q)
    k_lqr = lqr_gain(a, b, weights.q, weights.r)
    regs: Dict[str, Regulator] = {"lqr": make_regulator("lqr", line, weights)}
    elqr: Dict[str, EnergyLqrRegulator] = {}
    for w in w_list:
        reg = EnergyLqrRegulator(line, table, weights, w_energy=w)
        regs[f"elqr_w{w:g}"] = reg
        elqr[f"elqr_w{w:g}"] = reg
    methods: Dict[str, Any] = {}
    for name, regulator in progress_each("bench energy_regulation", regs.items(),
                                         "regulators"):
        row: Dict[str, Any] = {"w_energy": getattr(regulator, "w_energy", 0.0), "cases": {}}
        for case in CASES:
            case_seeds = seeds if case in ("incident", "disturbed") else seeds[:1]
            vals: Dict[str, List[float]] = {k: [] for k in KPI_KEYS}
            for s in case_seeds:
                sc = _case(line, case, s, weights.horizon)
                flags = LINEAR_FLAGS if case == "incident_linear" else {}
                traj = simulate(line, regulator, sc["x0"], sc["w"], weights.horizon, **flags)
                kp = trajectory_kpis(line, table, traj, weights, p0)
                for k in KPI_KEYS:
                    vals[k].append(kp[k])
            res: Dict[str, Any] = {}
            for k in KPI_KEYS:
                res[k] = float(np.mean(vals[k]))
                res[f"{k}_std"] = float(np.std(vals[k]))
            res["per_seed_energy_kwh"] = vals["energy_kwh_per_service"]
            res["per_seed_cost"] = vals["cost"]
            row["cases"][case] = res
        if name in elqr:
            r = elqr[name]
            row["steady_state"] = {
                "u_ff_s": r.u_ff_s.tolist(), "x_ss_s": r.x_ss_s.tolist(),
                "u_ss_s": r.u_ss_s.tolist(), "terminal_lateness_s": float(r.x_ss_s[-1]),
                "run_extension_sum_s": float(np.sum(r.u_ss_s[1:])),
                "gain_change_max": float(np.max(np.abs(r.k - k_lqr))),
            }
        methods[name] = row
    base = methods["lqr"]["cases"]
    for name, row in methods.items():
        for case, res in row["cases"].items():
            b = base[case]
            res["energy_saved_vs_lqr_kwh"] = b["energy_kwh_per_service"] \
                - res["energy_kwh_per_service"]
            res["energy_saved_vs_lqr_pct"] = 100.0 * res["energy_saved_vs_lqr_kwh"] \
                / b["energy_kwh_per_service"]
            res["added_mean_terminal_delay_s"] = res["mean_terminal_delay_s"] \
                - b["mean_terminal_delay_s"]
            res["added_worst_terminal_delay_s"] = res["worst_terminal_delay_s"] \
                - b["worst_terminal_delay_s"]
            res["cost_increase_vs_lqr"] = res["cost"] - b["cost"]
            res["cost_increase_vs_lqr_pct"] = 100.0 * (res["cost"] - b["cost"]) / b["cost"] \
                if b["cost"] > 1e-6 else float("nan")
            # the performance index of Sheu 2011 (U_E at this method's w_E) for both
            w_e = float(row["w_energy"])
            res["energy_aware_cost"] = res["cost"] + w_e * res["energy_term_w1"]
            res["lqr_energy_aware_cost"] = b["cost"] + w_e * b["energy_term_w1"]
    return {"methods": methods, "table": table.summary(), "table_seconds": t_table,
            "dp_cross_check": dp_cross_check(scenario, line, table),
            "scheduled_energy_kwh_per_service": table.e_scale_j / J_PER_KWH,
            "line": line}


def main(argv: Optional[List[str]] = None) -> int:
    """Command-line entry point; see the module docstring."""
    ap = argparse.ArgumentParser(prog="energy-regulation", description=__doc__.splitlines()[0])
    ap.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    ap.add_argument("--seeds", type=int, default=5, help="number of disturbance seeds")
    ap.add_argument("--seed", type=int, default=0, help="first seed")
    ap.add_argument("--weights", default=",".join(f"{w:g}" for w in DEFAULT_WEIGHTS),
                    help="comma-separated energy weights w_E > 0")
    ap.add_argument("--scenario", default=SCENARIO,
                    help="embedded scenario name or YAML path (default taipei_blue)")
    ap.add_argument("--source", choices=ENERGY_SOURCES, default="dp",
                    help="planner of the energy curves (dp reference or ACTP n.d. ECTP family)")
    a = ap.parse_args(argv)
    try:
        w_list = [float(v) for v in a.weights.split(",") if v.strip()]
    except ValueError:
        ap.error(f"--weights: not a list of numbers: {a.weights!r}")
    if a.seeds < 1 or not w_list or any(not np.isfinite(w) or w <= 0.0 for w in w_list):
        ap.error("--seeds must be >= 1 and every weight finite and > 0")
    seeds = list(range(a.seed, a.seed + a.seeds))
    t0 = time.perf_counter()
    try:
        res = run(seeds, w_list, a.source, a.scenario)
    except (ValueError, OSError) as exc:       # unknown scenario, bad YAML, bad table
        print(f"energy-regulation: {exc}", file=sys.stderr)
        return 2
    line: LineData = res.pop("line")
    w = CostWeights()
    result: Dict[str, Any] = {
        "bench": "energy-regulation",
        "methods": res["methods"],
        "assumptions": ASSUMPTIONS,
        "table": res["table"],
        "scheduled_energy_kwh_per_service": res["scheduled_energy_kwh_per_service"],
        "config": {"scenario": a.scenario, "source": a.source, "initial_delay_s": INITIAL_DELAY_S,
                   "headway_s": line.headway_s, "horizon_services": w.horizon,
                   "cost_weights": {"q": w.q, "r": w.r, "x_scale_s": w.x_scale_s},
                   "energy_weights": w_list, "seeds": seeds},
        "table_seconds": res["table_seconds"],
        "dp_cross_check": res["dp_cross_check"],
        "seconds": time.perf_counter() - t0,
    }
    if a.json:
        print(json.dumps(json_safe(result), allow_nan=False))
        return 0
    tb = res["table"]
    print(f"Energy-aware ATR (Sheu 2011 abstract) on {a.scenario}: LQR vs energy-aware LQR, "
          f"K = {w.horizon} services, seeds {seeds}")
    print(f"  energy curves: {tb['source']} planner, {tb['n_runs']} runs x {tb['n_grid']} "
          f"running times, built in {res['table_seconds']:.1f} s ({tb['build_cpu_s']:.1f} s "
          f"CPU); fit ({tb['model']}) RMS {100 * tb['fit_rms_rel_mean']:.2f} % mean, max error "
          f"{100 * tb['fit_max_rel']:.2f} % of the run energy")
    for c in res["dp_cross_check"]:
        print(f"  check run {c['run']} at {c['running_time_s']:.1f} s: solve_dp "
              f"{c['solve_dp_kwh']:.3f} kWh (hull {c['solve_dp_hull_kwh']:.3f}), table "
              f"{c['table_kwh']:.3f}, fit {c['fit_kwh']:.3f}")
    print(f"  traction energy per service: scheduled {tb['service_energy_sched_kwh']:.1f} kWh, "
          f"flat-out {tb['service_energy_fast_kwh']:.1f} kWh, at run_max "
          f"{tb['service_energy_rmax_kwh']:.1f} kWh")
    for case in CASES:
        print(f"  case {case}:")
        print(f"    {'method':11s} {'cost':>13s} {'energy kWh/svc':>16s} {'saved %':>8s} "
              f"{'worst term. s':>13s} {'mean term. s':>12s} {'recovery s':>10s} "
              f"{'run ext. s':>10s}")
        for name, row in res["methods"].items():
            r = row["cases"][case]
            print(f"    {name:11s} {r['cost']:7.2f} +-{r['cost_std']:4.2f} "
                  f"{r['energy_kwh_per_service']:9.2f} +-{r['energy_kwh_per_service_std']:4.2f} "
                  f"{r['energy_saved_vs_lqr_pct']:8.2f} {r['worst_terminal_delay_s']:13.1f} "
                  f"{r['mean_terminal_delay_s']:12.1f} {r['recovery_time_s']:10.0f} "
                  f"{r['mean_run_extension_s']:+10.2f}")
    for case in ("undisturbed", "incident"):
        print(f"  trade-off ({case}, vs LQR): energy saved per service vs added delay")
        for name, row in res["methods"].items():
            if name == "lqr":
                continue
            r = row["cases"][case]
            print(f"    w_E = {row['w_energy']:<4g}: {r['energy_saved_vs_lqr_kwh']:+.2f} kWh "
                  f"({r['energy_saved_vs_lqr_pct']:+.2f} %), mean terminal delay "
                  f"{r['added_mean_terminal_delay_s']:+.1f} s, worst "
                  f"{r['added_worst_terminal_delay_s']:+.1f} s, schedule cost "
                  f"{r['cost_increase_vs_lqr']:+.2f}, U_E {r['energy_aware_cost']:.2f} "
                  f"(LQR {r['lqr_energy_aware_cost']:.2f})")
    print("  linear-model steady state of the energy-aware LQR (feed-forward offset):")
    for name, row in res["methods"].items():
        if name != "lqr":
            ss = row["steady_state"]
            print(f"    w_E = {row['w_energy']:<4g}: runs {ss['run_extension_sum_s']:+.1f} s in "
                  f"total, terminal lateness {ss['terminal_lateness_s']:.1f} s, first-station "
                  f"dwell {ss['u_ss_s'][0]:+.1f} s, max gain change "
                  f"{ss['gain_change_max']:.3f}")
    print(f"  ({result['seconds']:.1f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
