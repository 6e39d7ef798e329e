"""Bench: Lin 2010a, Experiment 2 followed through the turnback (none / LQR / AOC).

A 180 s delay at the first station (BL01) of the Taipei Blue line at the 105 s peak
headway; each regulator acts on the truth traffic model
(:mod:`metro_atc.core.service.regulation`).  Reported: the delayed train's arrival delay at
the terminus BL23 against the 210 s turnback buffer of Lin 2010a and against the buffers of
the planned day's morning-peak turnbacks at BL23 (smallest and median), the delay inherited
by its next trip (down direction), and that trip's first departure and terminal delay with
the regulator acting on the down line (the turnback link bounds its first departure).
AOC uses the shipped weights, trained on the ``taipei_blue`` scenario's up direction; they
are refused on the down line (traffic-model hash), so its next trip is not assessed.

Run:  python -m metro_atc.bench.turnback [--json] [--seed 0] [--delay 180]
"""

from __future__ import annotations

import argparse
import json
import statistics
from typing import Dict, List, Optional

from metro_atc.core.atr.lines import get_line
from metro_atc.core.atr.regulators import Regulator, make_regulator
from metro_atc.core.service.day import period_index, run_day, taipei_blue_day
from metro_atc.core.service.planned import directed_line
from metro_atc.core.service.regulation import (INITIAL_DELAY_S, experiment_text,
                                               turnback_experiment)

METHODS = ("none", "lqr", "aoc")
"""Regulators assessed (Lin 2010a, Experiment 2 compares LQR, DHP and AOC)."""


def main(argv: Optional[List[str]] = None) -> int:
    """Command-line entry point; see the module docstring."""
    ap = argparse.ArgumentParser(prog="turnback", description=__doc__.splitlines()[0])
    ap.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    ap.add_argument("--seed", type=int, default=0, help="disturbance seed")
    ap.add_argument("--delay", type=float, default=INITIAL_DELAY_S,
                    help="initial delay at the first station [s]")
    a = ap.parse_args(argv)
    if not 0.0 <= a.delay <= 3600.0:
        ap.error("--delay must lie in [0, 3600] s")
    plan = taipei_blue_day()
    circ, _ = run_day(plan)
    end = plan.termini[1]
    peak = next(n for n, p in enumerate(plan.periods) if p.headway_s == min(
        q.headway_s for q in plan.periods))
    bufs = sorted(b.departure_s - a_.arrival_s - end.min_turnback_s
                  for blk in circ.blocks for a_, b in zip(blk.trips, blk.trips[1:])
                  if a_.destination == end.station
                  and period_index(plan.periods, a_.arrival_s) == peak)
    line = get_line("taipei_blue")
    down = directed_line(line, "down")
    regs: Dict[str, Regulator] = {m: make_regulator(m, line) for m in METHODS}
    down_regs: Dict[str, Optional[Regulator]] = {}
    refused: Dict[str, str] = {}
    for m in METHODS:
        try:
            down_regs[m] = make_regulator(m, down)
        except (ValueError, FileNotFoundError) as exc:
            down_regs[m] = None
            refused[m] = str(exc)
    res = turnback_experiment(regs, line, down_regs, down, end.min_turnback_s,
                              (bufs[0], statistics.median(bufs)), a.delay, a.seed)
    res["planned_day_peak_buffers_s"] = {"terminus": end.station,
                                         "period": plan.periods[peak].name,
                                         "count": len(bufs), "min": bufs[0],
                                         "median": statistics.median(bufs), "max": bufs[-1]}
    res["next_trip_not_assessed"] = refused
    if a.json:
        print(json.dumps(res))
        return 0
    print(experiment_text(res))
    pb = res["planned_day_peak_buffers_s"]
    print(f"  planned day {plan.name}: {pb['count']} {pb['period']} turnbacks at "
          f"{pb['terminus']}, buffer min {pb['min']:.0f} s, median {pb['median']:.0f} s, max "
          f"{pb['max']:.0f} s (layover minus the {end.min_turnback_s:.0f} s minimum turnback)")
    for m, why in refused.items():
        print(f"  {m}: next trip not assessed: {why}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
