"""Bench: Lin 2010a, Experiment 2 -- automatic train regulation on the Taipei Blue line.

Scenario: 180 s departure delay of one train at the first station (BL01 Dingpu), peak
headway 105 s, truth traffic model with control saturation, crowding-dependent dwell,
knock-on delays and exponential departure delays (:mod:`metro_atc.core.atr.traffic`); the
approximate (linear, Lin 2010a, eq. 5) model used by LQR and inside DHP/AOC lacks all of
them.  K = 40 adjustable services.  For every seed the neural regulators are trained from
scratch (same configuration for AOC and DHP) and all regulators are evaluated on the same
seeded disturbance realisations; we report mean +- std over seeds.  The bench trains for
800 epochs per method and seed by default on the ATR core's own line estimates
(:func:`metro_atc.core.atr.blue_line.taipei_blue`); the shipped weights (``metro_atc/data``,
1500 epochs, seed 0) were trained on the ``taipei_blue`` scenario as the ATS node models it
and are evaluated there, with LQR and no regulation on the same line (``shipped``).

Run:  python -m metro_atc.bench.regulation [--json] [--seeds 3] [--quick] [--out DIR]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any, Dict, List, Optional

import numpy as np
import torch

from metro_atc.bench.progress import progress_each
from metro_atc.core.atr.blue_line import LineData, taipei_blue
from metro_atc.core.atr.lines import get_line
from metro_atc.core.atr.cost import CostWeights
from metro_atc.core.atr.evaluation import incident_scenario, kpis, simulate
from metro_atc.core.atr.node_core import AtsRegulatorCore
from metro_atc.core.atr.problems import AtrProblem
from metro_atc.core.atr.regulators import (
    NeuralRegulator, Regulator, default_weights_path, make_regulator)
from metro_atc.core.atr.training import atr_train_config, train

INITIAL_DELAY_S = 180.0
KPI_KEYS = ("cost", "worst_terminal_delay_s", "running_time_dev_index", "headway_dev_index",
            "recovery_time_s", "max_abs_control_s")
PAPER: Dict[str, Any] = {
    "source": "Lin 2010a, Exp. 2, Table I case 4 and Fig. 8 (Taipei Blue line, 180 s initial "
              "delay, peak headway 105 s, saturation nonlinearity)",
    "aoc_improvement_vs_lqr_pct": 40.0,
    "aoc_improvement_vs_dhp_pct": 30.0,
    "dhp_improvement_vs_lqr_pct": 15.0,
    "aoc_worst_terminal_delay_s": 104.0,
    "running_time_dev_index_order": ["aoc", "dhp", "lqr"],
    "headway_dev_index_order": ["aoc", "dhp", "lqr"],
}


def evaluate(line: LineData, reg: Regulator, weights: CostWeights, p0: np.ndarray,
             seed: int, n_realisations: int) -> Dict[str, Any]:
    """Mean KPIs of a regulator over seeded disturbance realisations (+ first trajectory)."""
    rows = []
    first = None
    for r in range(n_realisations):
        sc = incident_scenario(line, INITIAL_DELAY_S, 10_000 * (seed + 1) + r, weights.horizon)
        traj = simulate(line, reg, sc["x0"], sc["w"], weights.horizon)
        if first is None:
            first = traj
        rows.append(kpis(traj, line, weights, p0))
    return {"kpis": {k: float(np.mean([row[k] for row in rows])) for k in KPI_KEYS},
            "trajectory": first}


def decision_timing(line: LineData, regs: Dict[str, Regulator], weights: CostWeights,
                    n: int = 300) -> Dict[str, float]:
    """Mean wall time [ms] of one Regulator.decide and of one node departure_command."""
    out: Dict[str, float] = {}
    x = np.zeros(line.n_stations)
    x[0] = INITIAL_DELAY_S
    for name, reg in regs.items():
        reg.decide(x, 0)
        t0 = time.perf_counter()
        for _ in range(n):
            reg.decide(x, 0)
        out[f"{name}_decide_ms"] = (time.perf_counter() - t0) / n * 1e3
    ids = [f"train_{i:02d}" for i in range(40)]
    core = AtsRegulatorCore(line, "lqr", cost=weights, train_ids=ids)
    core.regulator = regs.get("aoc", core.regulator)
    t = core.scheduled(5, 3, "departure")
    core.on_event(ids[5], 3, "departure", t + 30.0)
    t0 = time.perf_counter()
    for _ in range(n):
        core.departure_command(ids[5], 4)
    out["node_departure_command_ms"] = (time.perf_counter() - t0) / n * 1e3
    return out


def _stats(values: List[float]) -> Dict[str, float]:
    a = np.asarray(values, dtype=float)
    return {"mean": float(a.mean()), "std": float(a.std())}


def run(seeds: List[int], epochs: int, n_realisations: int, verbose: bool = False
        ) -> Dict[str, Any]:
    """Train (per seed) and evaluate none/LQR/DHP/AOC; returns results and plot data."""
    torch.set_num_threads(1)
    line, weights = taipei_blue(), CostWeights()
    problem = AtrProblem(line, weights)
    p0 = problem.p0_np
    fixed = {"none": make_regulator("none", line, weights), "lqr": make_regulator("lqr", line,
                                                                                  weights)}
    per: Dict[str, Dict[str, List[float]]] = {
        m: {k: [] for k in KPI_KEYS} for m in ["dhp", "aoc"] + list(fixed)}
    train_s: Dict[str, List[float]] = {"dhp": [], "aoc": []}
    trajectories: Dict[str, Any] = {}
    timing: Dict[str, float] = {}
    for s in progress_each("bench regulation", seeds, "seeds"):
        regs: Dict[str, Regulator] = dict(fixed)
        for m in ("dhp", "aoc"):
            res = train(m, problem, atr_train_config(s, epochs))
            train_s[m].append(res.seconds)
            regs[m] = NeuralRegulator(res.agent(problem), problem)
            if verbose:
                print(f"seed {s}: trained {m} in {res.seconds:.1f} s", flush=True)
        for m, reg in regs.items():
            ev = evaluate(line, reg, weights, p0, s, n_realisations)
            for k in KPI_KEYS:
                per[m][k].append(ev["kpis"][k])
            if s == seeds[0]:
                trajectories[m] = ev["trajectory"]
        if s == seeds[0]:
            timing = decision_timing(line, regs, weights)
    methods: Dict[str, Any] = {}
    lqr_cost = np.asarray(per["lqr"]["cost"])
    dhp_cost = np.asarray(per["dhp"]["cost"])
    for m, d in per.items():
        cost = np.asarray(d["cost"])
        row: Dict[str, Any] = {}
        for k in KPI_KEYS:
            st = _stats(d[k])
            row[k] = st["mean"]
            row[f"{k}_std"] = st["std"]
        imp = 100.0 * (lqr_cost - cost) / lqr_cost
        row["improvement_vs_lqr_pct"] = float(100.0 * (lqr_cost.mean() - cost.mean())
                                              / lqr_cost.mean())
        row["improvement_vs_lqr_pct_std"] = float(imp.std())
        if m.endswith("aoc"):
            ref = dhp_cost
            row["improvement_vs_dhp_pct"] = float(100.0 * (ref.mean() - cost.mean())
                                                  / ref.mean())
        if m in train_s:
            row["train_seconds"] = float(np.mean(train_s[m]))
            row["train_seconds_max"] = float(np.max(train_s[m]))
        row["per_seed_cost"] = [float(c) for c in cost]
        methods[m] = row
    return {"methods": methods, "timing": timing, "trajectories": trajectories,
            "shipped": shipped(seeds, n_realisations)}


def shipped(seeds: List[int], n_realisations: int) -> Dict[str, Any]:
    """Evaluate the shipped weights on the line they were trained for.

    That line is the ``taipei_blue`` scenario as the ATS node models it; same incident and
    realisations as the bench, no training here.
    """
    line, w = get_line("taipei_blue"), CostWeights()
    p0 = AtrProblem(line, w).p0_np
    regs = {m: make_regulator(m, line, w) for m in ("none", "lqr")}
    for m in ("dhp", "aoc"):
        path = default_weights_path(m, "taipei_blue")
        if path.is_file():
            regs[m] = make_regulator(m, line, w, path)
    rows: Dict[str, Any] = {}
    for m, reg in regs.items():
        ks = [evaluate(line, reg, w, p0, s, n_realisations)["kpis"] for s in seeds]
        rows[m] = {k: float(np.mean([x[k] for x in ks])) for k in KPI_KEYS}
    base = rows["lqr"]["cost"]
    for row in rows.values():
        row["improvement_vs_lqr_pct"] = 100.0 * (base - row["cost"]) / base
    return {"line": f"{line.name} scenario (bridge.atr_line_for)", "methods": rows}


def plot(trajectories: Dict[str, Any], line: LineData, out_dir: Path) -> List[str]:
    """Fig. 8-like PNG: departure deviation of every train at every station, per method."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    out_dir.mkdir(parents=True, exist_ok=True)
    names = [m for m in ("none", "lqr", "dhp", "aoc") if m in trajectories]
    grids = {}
    for m in names:
        x = trajectories[m]["x"]           # (K+1, N) staggered
        k_n, n = x.shape
        g = np.full((k_n, n), np.nan)       # rows: train index k-1-i + n, cols: station
        for k in range(k_n):
            for i in range(n):
                tr = k - 1 - i + n
                if 0 <= tr < k_n:
                    g[tr, i] = x[k, i]
        grids[m] = g
    vmax = max(float(np.nanmax(np.abs(g))) for g in grids.values())
    fig, axes = plt.subplots(1, len(names), figsize=(4.2 * len(names), 5), sharey=True)
    for ax, m in zip(np.atleast_1d(axes), names):
        im = ax.imshow(grids[m], aspect="auto", cmap="RdBu_r", vmin=-vmax, vmax=vmax,
                       origin="upper", interpolation="nearest")
        ax.set_title(f"{m.upper()}: departure deviation [s]")
        ax.set_xlabel("station (0 = BL01 Dingpu)")
    np.atleast_1d(axes)[0].set_ylabel("train (dispatch order; delayed train = row "
                                      f"{line.n_stations - 1})")
    fig.colorbar(im, ax=axes, shrink=0.8)
    fig.suptitle("Schedule deviation after a 180 s initial delay at the first station "
                 "(cf. Lin 2010a, Fig. 8)")
    f = out_dir / "regulation_fig8.png"
    fig.savefig(f, dpi=110)
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(7, 4))
    for m in names:
        ax.plot(trajectories[m]["x"][:, -1], label=m)
    ax.set_xlabel("stage k (services)")
    ax.set_ylabel("departure deviation at the terminal BL23 [s]")
    ax.set_title("Terminal-station delay per service")
    ax.legend()
    fig.tight_layout()
    f2 = out_dir / "regulation_terminal_delay.png"
    fig.savefig(f2, dpi=110)
    plt.close(fig)
    return [str(f), str(f2)]


def main(argv: Optional[List[str]] = None) -> int:
    """Command-line entry point; see the module docstring."""
    ap = argparse.ArgumentParser(prog="regulation", description=__doc__.splitlines()[0])
    ap.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    ap.add_argument("--seeds", type=int, default=3, help="number of training seeds")
    ap.add_argument("--seed", type=int, default=0, help="first seed")
    ap.add_argument("--epochs", type=int, default=None, help="training epochs per method")
    ap.add_argument("--realisations", type=int, default=5,
                    help="disturbance realisations per seed")
    ap.add_argument("--quick", action="store_true", help="1 seed, 300 epochs, 2 realisations")
    ap.add_argument("--out", type=Path, default=None, help="directory for PNG plots")
    ap.add_argument("--verbose", action="store_true")
    a = ap.parse_args(argv)
    n_seeds = 1 if a.quick else a.seeds
    epochs = a.epochs if a.epochs is not None else (300 if a.quick else 800)
    n_real = 2 if a.quick else a.realisations
    if n_seeds < 1 or epochs < 1 or n_real < 1:
        ap.error("--seeds, --epochs and --realisations must be >= 1")
    seeds = list(range(a.seed, a.seed + n_seeds))
    t0 = time.perf_counter()
    res = run(seeds, epochs, n_real, verbose=a.verbose and not a.json)
    line = taipei_blue()
    result: Dict[str, Any] = {
        "bench": "regulation",
        "methods": res["methods"],
        "paper": PAPER,
        "timing": res["timing"],
        "shipped": res["shipped"],
        "config": {"scenario": line.name, "initial_delay_s": INITIAL_DELAY_S,
                   "headway_s": line.headway_s, "horizon_services": CostWeights().horizon,
                   "cost_weights": {"q": CostWeights().q, "r": CostWeights().r,
                                    "x_scale_s": CostWeights().x_scale_s},
                   "seeds": seeds, "epochs": epochs, "realisations_per_seed": n_real},
        "seconds": time.perf_counter() - t0,
    }
    if a.out is not None:
        result["plots"] = plot(res["trajectories"], line, a.out)
    if a.json:
        print(json.dumps(result))
        return 0
    ms = res["methods"]
    print("Seed 000 Exp. 2 -- ATR on the Taipei Blue line, 180 s initial delay at BL01, "
          f"H = 105 s, K = {CostWeights().horizon} services, seeds {seeds}")
    print(f"  {'method':11s} {'cost':>16s} {'impr. vs LQR %':>16s} {'worst term. delay s':>20s} "
          f"{'run-time dev s':>15s} {'headway dev s':>14s} {'recovery s':>11s}")
    for m in [k for k in ("none", "lqr", "dhp", "aoc") if k in ms]:
        r = ms[m]
        print(f"  {m:11s} {r['cost']:8.1f} +-{r['cost_std']:6.1f} "
              f"{r['improvement_vs_lqr_pct']:7.1f} +-{r['improvement_vs_lqr_pct_std']:5.1f} "
              f"{r['worst_terminal_delay_s']:11.1f} +-{r['worst_terminal_delay_s_std']:6.1f} "
              f"{r['running_time_dev_index']:15.1f} {r['headway_dev_index']:14.1f} "
              f"{r['recovery_time_s']:11.0f}")
    print(f"  ours : AOC vs DHP {ms['aoc']['improvement_vs_dhp_pct']:.1f} %, AOC vs LQR "
          f"{ms['aoc']['improvement_vs_lqr_pct']:.1f} %, DHP vs LQR "
          f"{ms['dhp']['improvement_vs_lqr_pct']:.1f} %, AOC worst terminal delay "
          f"{ms['aoc']['worst_terminal_delay_s']:.0f} s")
    print("  paper: AOC vs DHP 30 %, AOC vs LQR 40 %, DHP vs LQR 15 %, AOC worst terminal "
          "delay 104 s; deviation indices AOC > DHP > LQR (Table I case 4, Fig. 8)")
    sh = res["shipped"]
    print(f"  shipped weights on {sh['line']}: " + ", ".join(
        f"{m} cost {r['cost']:.0f} ({r['improvement_vs_lqr_pct']:+.1f} % vs LQR, worst terminal "
        f"delay {r['worst_terminal_delay_s']:.0f} s)" for m, r in sh["methods"].items()))
    tm = res["timing"]
    print(f"  AOC training {ms['aoc']['train_seconds']:.1f} s (max "
          f"{ms['aoc']['train_seconds_max']:.1f} s) on 1 thread; one decision: "
          + ", ".join(f"{k} {v:.3f} ms" for k, v in tm.items()))
    if a.out is not None:
        print("  plots: " + ", ".join(result["plots"]))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
