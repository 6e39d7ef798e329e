"""Benchmark: brake-by-wire active safety diagnosis with a UKF (Lin 2010b).

``python -m metro_atc.bench.ukf [--json] [--out DIR] [--quick] [--seed N]``

Runs (1) the UKF verification problems (linear-KF equivalence, polar conversion,
falling body), (2) the paper's three cases for every driver signal and road mu of
Table II on its vehicle, (3) the same three kinds of case on the metro car, (4) the
single-core speed of the metro and paper observers.  Prints the paper's statements
beside our numbers, or one JSON object with ``--json``; ``--out`` writes PNG figures
like the paper's Fig. 5-7 (estimates vs targets over time) plus the metro ones.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from typing import Any, Optional

import numpy as np

from metro_atc.bench.progress import Progress
from metro_atc.core.brake import checks
from metro_atc.core.brake import experiments as ex

PAPER_STATEMENTS = {
    "none": "no flaw; mu_b_hat > 0.2 (Fig. 5d, true 0.38); forces close to targets",
    "pad": "flaw; mu_b_hat converges to 0.1 < 0.2 (Fig. 6)",
    "tyre": "flaw; Fx2-Fx4, Fyr, Fyf deviate from targets (Fig. 7)",
}
"""What the paper reports (for A1-B1 only; other conditions: 'works nicely')."""


def _round(x: Any) -> Any:
    if isinstance(x, float):
        return float(f"{x:.5g}")
    if isinstance(x, dict):
        return {k: _round(v) for k, v in x.items()}
    if isinstance(x, list):
        return [_round(v) for v in x]
    return x


def run(quick: bool, seed: int) -> dict[str, Any]:
    """Run every part of the benchmark and return the results (incl. plot data)."""
    cfg = (ex.ExperimentConfig(n_normal=10, n_fault=3, n_cal=15, seed=seed) if quick
           else ex.ExperimentConfig(seed=seed))
    t0 = time.perf_counter()
    prog = Progress("bench ukf", 5, "phases")
    prog.update(0, "now: UKF verification problems", force=True)
    lin = [checks.linear_equivalence(s) for s in range(3)]
    pm = checks.polar_moments()
    fb = checks.falling_body(n_runs=3 if quick else 10, n_steps=40, seed=seed)
    prog.update(1, "now: paper vehicle cases (Table II conditions)", force=True)
    paper = ex.paper_experiment(cfg)
    prog.update(2, "now: metro car cases", force=True)
    metro = ex.metro_experiment(cfg)
    prog.update(3, "now: metro observer speed", force=True)
    sp_m = ex.speed_metro(2000 if quick else 5000, seed)
    prog.update(4, "now: paper observer speed", force=True)
    sp_p = ex.speed_paper(1000 if quick else 2000, seed)
    prog.update(5, "done", force=True)
    out: dict[str, Any] = {
        "cases": paper["cases"] + metro["cases"],
        "false_alarms": paper["false_alarms"] + metro["false_alarms"],
        "missed_detections": paper["missed"] + metro["missed"],
        "runs": paper["runs"] + metro["runs"],
        "normal_seeds_per_condition": cfg.n_normal,
        "fault_seeds_per_condition": cfg.n_fault,
        "calibration_runs": paper["cal_runs"] + metro["cal_runs"],
        "thresholds": {
            "paper_force_residual_n": {str(mu): [float(v) for v in thr]
                                       for mu, thr in paper["thresholds_n"].items()},
            "paper_channels": ["Fx1", "Fx2", "Fx3", "Fx4", "Fyf", "Fyr"],
            "metro_normalised_residual": metro["threshold"],
            "metro_calibration_level": metro["cal_level"],
            "margin": ex.MARGIN, "mu_b_min": 0.2,
        },
        "speed": {
            "metro_ukf_steps_per_s": sp_m["ukf_steps_per_s"],
            "metro_observer_updates_per_s": sp_m["observer_updates_per_s"],
            "metro_ukf_steps_per_s_wall": sp_m["ukf_steps_per_s_wall"],
            "paper_ukf_steps_per_s_wall": sp_p["ukf_steps_per_s_wall"],
            "rates_are": "per CPU second of one process (time.process_time)",
            "metro_state_dim": int(sp_m["state_dim"]),
            "paper_ukf_steps_per_s": sp_p["ukf_steps_per_s"],
            "paper_state_dim": int(sp_p["state_dim"]),
            "paper_batch_ukf_steps_per_s": paper["observer_steps"]
            / paper["timing_s"]["observer"],
            "metro_batch_ukf_steps_per_s": metro["observer_steps"]
            / metro["timing_s"]["observer"],
        },
        "checks": {
            "kf_equivalence_max_rel_state_diff": max(d[0] for d in lin),
            "kf_equivalence_max_rel_cov_diff": max(d[1] for d in lin),
            "polar_mean_err_ut": float(np.max(np.abs(pm["ut_mean"] - pm["exact_mean"]))),
            "polar_mean_err_linearised": float(np.max(np.abs(pm["lin_mean"]
                                                             - pm["exact_mean"]))),
            "falling_body_alt_mae_ukf_ft": float(fb["ukf"][10:, 0].mean()),
            "falling_body_alt_mae_ekf_ft": float(fb["ekf"][10:, 0].mean()),
            "falling_body_vel_mae_ukf_fps": float(fb["ukf"][10:, 1].mean()),
            "falling_body_vel_mae_ekf_fps": float(fb["ekf"][10:, 1].mean()),
        },
        "timing_s": {"paper": paper["timing_s"], "metro": metro["timing_s"],
                     "total": time.perf_counter() - t0},
    }
    out["_plots"] = {"paper": paper["plot"], "metro": metro["plot"]}
    return out


def _fmt(x: Optional[float], f: str = "{:.2f}") -> str:
    return "-" if x is None else f.format(x)


def print_table(res: dict[str, Any]) -> None:
    """Readable report: the paper's statements beside our numbers."""
    print("Brake-by-wire active safety diagnosis with UKF (Lin 2010b)")
    print("UKF alpha=0.5 beta=2 kappa=3-L; paper observer L=26, metro observer L=19\n")
    c = res["checks"]
    print(f"UKF vs linear KF, max rel. diff: state {c['kf_equivalence_max_rel_state_diff']:.1e}"
          f", cov {c['kf_equivalence_max_rel_cov_diff']:.1e} (must be ~1e-15)")
    print(f"Polar conversion mean error: UT {c['polar_mean_err_ut']:.1e}, linearised "
          f"{c['polar_mean_err_linearised']:.1e}")
    print(f"Falling body (Athans 1968) MAE t>=10 s: altitude UKF "
          f"{c['falling_body_alt_mae_ukf_ft']:.0f} ft vs EKF "
          f"{c['falling_body_alt_mae_ekf_ft']:.0f} ft; speed UKF "
          f"{c['falling_body_vel_mae_ukf_fps']:.1f} vs EKF "
          f"{c['falling_body_vel_mae_ekf_fps']:.1f} ft/s\n")
    hdr = (f"{'case':62s} {'flaw':>5s} {'rate':>5s} {'t_det':>6s} {'mu_b':>5s} "
           f"{'mu_hat':>6s} {'t_conv':>6s} {'RMSE N':>7s}")
    print(hdr)
    print("-" * len(hdr))
    for case in res["cases"]:
        print(f"{case['name'][:62]:62s} {str(case['flaw']):>5s} {case['flaw_rate']:5.2f} "
              f"{_fmt(case['detect_time_s']):>6s} {case['mu_b_true']:5.2f} "
              f"{case['mu_b_final']:6.3f} {_fmt(case['mu_b_convergence_time_s']):>6s} "
              f"{case['force_rmse_n']:7.0f}")
    print("\nPaper (A1-B1 only, Figs. 5-7) beside ours (A1-B1, first run):")
    for case in res["cases"]:
        if case["vehicle"] == "paper" and case["name"].startswith("A1-B1"):
            ours = (f"flaw={case['flaw']} mu_b_hat={case['mu_b_final']:.3f} "
                    f"t_det={_fmt(case['detect_time_s'])} s causes={case['flaw_causes']}")
            print(f"  {case['fault']:5s} paper: {PAPER_STATEMENTS[case['fault']]}")
            print(f"        ours : {ours}")
    th = res["thresholds"]
    print("\nThresholds (1.5 x largest level sustained over the persistence time in "
          f"{res['calibration_runs']} calibration normal runs):")
    for mu, thr in th["paper_force_residual_n"].items():
        print(f"  paper force residuals [N], road mu {mu}: " + ", ".join(
            f"{n}={v:.0f}" for n, v in zip(th["paper_channels"], thr)))
    print(f"  metro normalised residual [-]: {th['metro_normalised_residual']:.3f}")
    print(f"\nFalse alarms {res['false_alarms']}, missed detections "
          f"{res['missed_detections']}, evaluated runs {res['runs']} (paper: none reported)")
    s = res["speed"]
    print(f"Speed (per CPU second, 1 core): metro UKF {s['metro_ukf_steps_per_s']:.0f} steps/s "
          f"(target >= 10000), metro observer incl. diagnosis "
          f"{s['metro_observer_updates_per_s']:.0f} updates/s, paper UKF (L=26) "
          f"{s['paper_ukf_steps_per_s']:.0f} steps/s; batched: paper "
          f"{s['paper_batch_ukf_steps_per_s']:.0f}, metro {s['metro_batch_ukf_steps_per_s']:.0f}"
          " steps/s")
    print(f"Total time {res['timing_s']['total']:.1f} s")


def write_plots(res: dict[str, Any], out_dir: str) -> list[str]:
    """Figures like the paper's Fig. 5-7 plus the metro cases; returns the file paths."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    os.makedirs(out_dir, exist_ok=True)
    files = []
    names = ["Fx1", "Fx2", "Fx3", "Fx4", "Fyf", "Fyr"]
    titles = {"none": "Fig. 5 - normal vehicle", "pad": "Fig. 6 - abnormal brake pad",
              "tyre": "Fig. 7 - abnormal front-right tyre"}
    for i, fault in enumerate(("none", "pad", "tyre")):
        d = res["_plots"]["paper"][fault]
        fig, axs = plt.subplots(4, 2, figsize=(11, 11), sharex=True)
        t = d["t"]
        for c in range(6):
            ax = axs.flat[c]
            ax.plot(t, d["target"][:, c], "k--", lw=1.2, label="target (vehicle-tyre model)")
            ax.plot(t, d["truth"][:, c], color="0.6", lw=1.0, label="truth (plant)")
            ax.plot(t, d["est"][:, c], "b", lw=1.0, label="UKF estimate")
            ax.set_ylabel(f"{names[c]} [N]")
            ax.grid(alpha=0.3)
        axs.flat[0].legend(fontsize=7)
        _mu_b_panel(axs.flat[6], t, d)
        axs.flat[6].legend(fontsize=7)
        ax = axs.flat[7]
        ax.plot(t, np.abs(d["res"]) / d["thr"][None, :])
        ax.axhline(1.0, color="r", ls="--")
        ax.set_ylabel("|low-passed residual| / threshold")
        for a in axs[-1]:
            a.set_xlabel("t [s]")
        fig.suptitle(f"{titles[fault]} (A1 straight brake, mu 0.85, 80 km/h)")
        fig.tight_layout()
        f = os.path.join(out_dir, f"fig{5 + i}_paper_{fault}.png")
        fig.savefig(f, dpi=90)
        plt.close(fig)
        files.append(f)
    for fault in ("none", "pad", "wheel"):
        d = res["_plots"]["metro"][fault]
        t = d["t"]
        fig, axs = plt.subplots(3, 2, figsize=(11, 8.5), sharex=True)
        for j in range(4):
            ax = axs.flat[j]
            ax.plot(t, d["target"][:, j] / 1e3, "k--", lw=1.0, label="adhesion target")
            ax.plot(t, d["truth"][:, j] / 1e3, color="0.6", lw=1.0, label="truth")
            ax.plot(t, d["est"][:, j] / 1e3, "b", lw=1.0, label="UKF estimate")
            ax.set_ylabel(f"F{j + 1} [kN]")
            ax.grid(alpha=0.3)
        axs.flat[0].legend(fontsize=7)
        _mu_b_panel(axs.flat[4], t, d)
        ax = axs.flat[5]
        ax.plot(t, np.abs(d["res"]))
        ax.axhline(d["thr"], color="r", ls="--")
        ax.set_ylabel("|normalised residual|")
        for a in axs[-1]:
            a.set_xlabel("t [s]")
        fig.suptitle(f"Metro car, service brake, dry rail: {fault}")
        fig.tight_layout()
        f = os.path.join(out_dir, f"metro_{fault}.png")
        fig.savefig(f, dpi=90)
        plt.close(fig)
        files.append(f)
    return files


def _mu_b_panel(ax: Any, t: np.ndarray, d: dict[str, Any]) -> None:
    """Pad friction estimate with its 2-sigma band, the true value and the 0.2 requirement."""
    ax.plot(t, d["mu_b"], "b", label="mu_b estimate")
    ax.fill_between(t, d["mu_b"] - 2 * d["mu_b_std"], d["mu_b"] + 2 * d["mu_b_std"],
                    color="b", alpha=0.15)
    ax.axhline(d["mu_b_true"], color="0.5", ls=":", label="true")
    ax.axhline(0.2, color="r", ls="--", label="requirement 0.2")
    ax.set_ylim(0, 0.6)
    ax.set_ylabel("mu_b [-]")


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point; returns the process exit code."""
    ap = argparse.ArgumentParser(prog="metro_atc bench ukf", description=__doc__.split("\n")[0])
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    ap.add_argument("--out", metavar="DIR", help="write PNG figures to DIR")
    ap.add_argument("--quick", action="store_true", help="reduced Monte-Carlo sizes")
    ap.add_argument("--seed", type=int, default=0, help="master seed")
    args = ap.parse_args(argv)
    res = run(args.quick, args.seed)
    files = write_plots(res, args.out) if args.out else []
    if args.json:
        payload = {k: v for k, v in res.items() if not k.startswith("_")}
        payload["figures"] = files
        sys.stdout.write(json.dumps(_round(payload)) + "\n")
    else:
        print_table(res)
        for f in files:
            print(f"wrote {f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
