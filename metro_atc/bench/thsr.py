"""Seed 004 reproduction: fuzzy motion control of the Taiwan High Speed Rail (Table 5).

``python -m metro_atc.bench.thsr [--json] [--quick] [--tracker fuzzy|pi] [--dt S] [--out DIR]``

South-bound runs from Taipei to each of the other seven stations (Table 3 distances,
consecutive: 7.3 / 34.9 / 29.9 / 93.6 / 85.8 / 62.3 / 31.4 km), each a single non-stop run
on the Li n.d. 5-region reference motion curve, tracked by the 15-rule fuzzy controller on
RK4 dynamics (all seven runs simulated together, vectorised).  Reported: trip time [s], stop
accuracy |position - platform point| [m], speed RMSE against the reference [m/s], traction
energy [10^8 J] (mechanical, at the wheel), paper values beside.

Train: :data:`metro_atc.core.line.vehicle.THSR_700T` (576 t, 10 260 kW, 2 km/h/s, drag
0.31 x 64 m^2 at 1.17 kg/m^3, 300 km/h; rolling resistance and rotating mass estimated).
The paper's trip times imply a constant 2 km/h/s acceleration up to 300 km/h, which a
10.26 MW, 576 t train cannot deliver above ~115 km/h (123 kN at 300 km/h, Li n.d., Table 4,
against 80.6 kN of drag); our reference follows the train's traction capability, so our
long trips are longer.  The paper's energies equal ~1.256e5 N x distance for every run
(a constant force times distance), ours integrate the actual tractive force.
"""

from __future__ import annotations

import argparse
import json
import time
import timeit
from typing import Any, Optional

import numpy as np

from metro_atc.bench.progress import Progress
from metro_atc.jsonsafe import json_safe as _json_safe
from metro_atc.core.ato.envelope import RunModel
from metro_atc.core.ato.fuzzy import FuzzyController
from metro_atc.core.ato.reference_curve import ReferenceCurve
from metro_atc.core.ato.registry import TRACKERS
from metro_atc.core.ato.tracking import simulate_tracking
from metro_atc.core.line.vehicle import THSR_700T, Track

STATIONS = ("Taipei", "Banqiao", "Taoyuan", "Hsinchu", "Taichung", "Chiayi", "Tainan",
            "Zuoying")
"""THSR stations south-bound (Li n.d., Table 3)."""
SPACING_KM = (7.3, 34.9, 29.9, 93.6, 85.8, 62.3, 31.4)
"""Consecutive station distances [km] (Li n.d., Table 3)."""
PAPER_TABLE5 = (
    (249.8, 0.01420, 0.0474, 9.1664),
    (675.4, 0.08832, 0.0420, 52.9896),
    (1034.1, 0.06345, 0.0422, 90.5344),
    (2156.6, 0.00446, 0.0424, 208.0662),
    (3186.2, 0.07370, 0.0424, 315.8034),
    (3933.6, 0.00945, 0.0425, 394.0323),
    (4310.2, 0.00658, 0.0425, 433.4607),
)
"""Seed 004 Table 5: trip time [s], stop accuracy [m], RMSE [m/s], energy [1e8 J]."""


def _step_time_us() -> float:
    """Wall time of one tracking step (reference look-up + fuzzy law) for one train [us]."""
    run = RunModel(THSR_700T, Track.flat(300.0 / 3.6), 0.0, 7300.0)
    ref = ReferenceCurve(run)
    flc = FuzzyController()
    state = {"s": 100.0}

    def one() -> None:
        r = ref.speed(state["s"])
        flc.step(r, 20.0, 0.1)

    n = 2000
    return 1e6 * min(timeit.repeat(one, number=n, repeat=3)) / n


def _expected_time_s(ref: ReferenceCurve) -> float:
    """Trip time of the reference curve [s] (sum of ds / v, v floored at 1 m/s): ETA only."""
    v = np.maximum(ref.speed(ref.s_tab), 1.0)
    return float(np.sum(np.diff(ref.s_tab) / (0.5 * (v[1:] + v[:-1]))))


def main(argv: Optional[list[str]] = None) -> int:
    """Run the benchmark; ``--json`` prints one JSON object, else a table."""
    ap = argparse.ArgumentParser(prog="python -m metro_atc.bench.thsr", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    ap.add_argument("--quick", action="store_true", help="only the first two runs")
    ap.add_argument("--seed", type=int, default=1, help="unused (deterministic)")
    ap.add_argument("--tracker", choices=TRACKERS.names, default="fuzzy",
                    help=TRACKERS.help())
    ap.add_argument("--dt", type=float, default=0.1, help="control / RK4 step [s]")
    ap.add_argument("--out", default=None, help="directory for PNG plots")
    args = ap.parse_args(argv)
    n = 2 if args.quick else 7
    dist_m = np.cumsum(SPACING_KM)[:n] * 1000.0
    track = Track.flat(300.0 / 3.6)
    runs = [RunModel(THSR_700T, track, 0.0, float(d)) for d in dist_m]
    refs = [ReferenceCurve(r) for r in runs]
    tracker = TRACKERS[args.tracker].load()()
    prog = Progress("bench thsr", _expected_time_s(refs[-1]), "simulated s",
                    rate_name="rtf")

    def on_time(t_s: float, running: int) -> None:
        prog.update(t_s, f"{running} of {n} runs running")

    c0 = time.process_time()
    res = simulate_tracking(runs, refs, tracker, dt_s=args.dt, record=bool(args.out),
                            record_every=max(1, int(round(1.0 / args.dt))), on_time=on_time)
    cpu = time.process_time() - c0
    prog.update(max(r.trip_time_s for r in res), "done", force=True)
    out_runs: list[dict[str, Any]] = []
    for i, tr in enumerate(res):
        p = PAPER_TABLE5[i]
        out_runs.append({
            "to": STATIONS[i + 1], "distance_km": float(dist_m[i] / 1000.0),
            "trip_time_s": tr.trip_time_s, "stop_error_m": abs(tr.stop_error_m),
            "stop_error_signed_m": tr.stop_error_m, "speed_rmse_mps": tr.speed_rmse_mps,
            "energy_1e8_j": tr.energy_j / 1e8, "arrived": tr.arrived,
            "paper": {"trip_time_s": p[0], "stop_error_m": p[1], "speed_rmse_mps": p[2],
                      "energy_1e8_j": p[3]},
        })
    step_us = _step_time_us()
    result: dict[str, Any] = {
        "runs": out_runs, "tracker": args.tracker, "dt_s": args.dt, "compute_s": cpu,
        "tracking_step_us": step_us,
        "train": {"mass_t": THSR_700T.mass_kg / 1000.0, "power_kw": 10260.0,
                  "max_accel_mps2": THSR_700T.a1_mps2, "max_speed_kmh": 300.0},
        "plots": [],
    }
    if args.out:
        result["plots"] = _plot(args.out, res, [0, min(3, n - 1), n - 1], dist_m)
    if args.json:
        print(json.dumps(_json_safe(result), allow_nan=False))
        return 0
    print(f"Li n.d. THSR fuzzy motion control (tracker {args.tracker}, dt {args.dt} s): "
          "paper | ours")
    print(f"{'to':9s} {'km':>6s} {'trip s':>16s} {'stop m':>18s} {'RMSE m/s':>17s} "
          f"{'energy 1e8 J':>19s}")
    for r in out_runs:
        p = r["paper"]
        print(f"{r['to']:9s} {r['distance_km']:6.1f} {p['trip_time_s']:7.1f} | "
              f"{r['trip_time_s']:6.1f} {p['stop_error_m']:7.4f} | {r['stop_error_m']:7.5f} "
              f"{p['speed_rmse_mps']:7.4f} | {r['speed_rmse_mps']:7.4f} "
              f"{p['energy_1e8_j']:8.2f} | {r['energy_1e8_j']:8.2f}")
    print(f"simulation {cpu:.1f} s CPU; one tracking step {step_us:.1f} us")
    for p in result["plots"]:
        print("wrote", p)
    return 0


def _plot(out_dir: str, res: list[Any], which: list[int], dist_m: np.ndarray) -> list[str]:
    import os
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    os.makedirs(out_dir, exist_ok=True)
    paths = []
    for i in sorted(set(which)):
        r = res[i]
        fig, ax = plt.subplots(figsize=(9, 4))
        ax.plot(r.s / 1000.0, r.r * 3.6, "b-", lw=1.2, label="reference curve")
        ax.plot(r.s / 1000.0, r.v * 3.6, "r--", lw=1.0, label="fuzzy-controlled train")
        ax.set_xlabel("distance from Taipei [km]")
        ax.set_ylabel("speed [km/h]")
        ax.set_title(f"THSR Taipei -> {STATIONS[i + 1]} ({dist_m[i] / 1000:.1f} km)")
        ax.legend(fontsize=8)
        ax.grid(alpha=0.3)
        path = os.path.join(out_dir, f"thsr_{STATIONS[i + 1].lower()}.png")
        fig.tight_layout()
        fig.savefig(path, dpi=110)
        plt.close(fig)
        paths.append(path)
    return paths


if __name__ == "__main__":
    raise SystemExit(main())
