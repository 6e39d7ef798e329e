"""Micro-bench of ``OnboardAto.control`` per train-step (the compiled step, its one path).

Records every ATO input of a ROS-free closed loop (``taipei_blue`` by default), then replays
them into fresh ATOs (one process's shared cache) ``--repeat`` times and prints the CPU time
(``time.thread_time``) per train-step of the steps in motion (not dwelling) and per step
overall, with the median, and checks that every replay gave the same efforts and modes.
Two code versions compare by running it once each (``PYTHONPATH`` choosing the version),
alternately::

    python test/ato_control_bench.py [--scenario taipei_blue] [--duration 1800] [--repeat 3]
"""

from __future__ import annotations

import argparse
import statistics
import time
from typing import Any


def record(scn: Any, duration_s: float) -> list[list[Any]]:
    """Every ATO's inputs of a closed loop, in order (departures and states)."""
    from metro_atc.core.ato.onboard import OnboardAto
    from metro_atc.core.closed_loop import run_closed_loop

    logs: dict[int, list[Any]] = {}
    orig_c, orig_d = OnboardAto.control, OnboardAto.on_departure

    def control(self: OnboardAto, s: dict[str, Any]) -> Any:
        logs.setdefault(id(self), []).append(("s", dict(s)))
        return orig_c(self, s)

    def on_departure(self: OnboardAto, *a: Any) -> Any:
        logs.setdefault(id(self), []).append(("d", a))
        return orig_d(self, *a)

    OnboardAto.control, OnboardAto.on_departure = control, on_departure  # type: ignore
    try:
        run_closed_loop(scn, duration_s=duration_s)
    finally:
        OnboardAto.control, OnboardAto.on_departure = orig_c, orig_d  # type: ignore
    return list(logs.values())


def replay(scn: Any, logs: list[list[Any]]) -> tuple[float, float, int, int, list]:
    """(CPU s of moving steps, CPU s of all steps, moving steps, steps, outputs)."""
    from metro_atc.core.ato.onboard import (OnboardAto, atp_model_for, envelope_limits,
                                            tsr_zones)
    from metro_atc.core.bridge import timetable_for, track_for, train_for

    train, track, tt = train_for(scn), track_for(scn), timetable_for(scn)
    limits, atp = envelope_limits(scn, train), atp_model_for(scn, train)
    shared: dict[str, Any] = {}
    t_mov = t_all = 0.0
    n_mov = n_all = 0
    out = []
    clock = time.thread_time
    for lg in logs:
        ato = OnboardAto(train, track, tt.station_positions_m,
                         control_period_s=float(scn.sim.control_period_s), limits=limits,
                         shared=shared, tsrs=tsr_zones(scn), atp=atp)
        for kind, a in lg:
            if kind == "d":
                ato.on_departure(*a)
                continue
            t0 = clock()
            u, mode, _ = ato.control(a)
            dt = clock() - t0
            out.append((u, mode))
            t_all += dt
            n_all += 1
            if a["mode"] != 1:
                t_mov += dt
                n_mov += 1
    return t_mov, t_all, n_mov, n_all, out


def main() -> None:
    """Command line (module docstring)."""
    from metro_atc.core.line.scenario import load_scenario

    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--scenario", default="taipei_blue")
    ap.add_argument("--duration", type=float, default=1800.0)
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args()
    scn = load_scenario(a.scenario)
    logs = record(scn, a.duration)
    replay(scn, logs)  # load the kernel (cache) outside the timing
    per: list[float] = []
    outs: list[list] = []
    for _ in range(a.repeat):
        t_mov, t_all, n_mov, n_all, out = replay(scn, logs)
        per.append(1e6 * t_mov / max(n_mov, 1))
        outs.append(out)
        print(f"moving {1e6 * t_mov / max(n_mov, 1):7.2f} us/train-step ({n_mov} steps), "
              f"all {1e6 * t_all / max(n_all, 1):7.2f} us ({n_all})")
    print(f"median moving: {statistics.median(per):.2f} us/train-step; "
          f"identical outputs: {all(o == outs[0] for o in outs)}")


if __name__ == "__main__":
    main()
