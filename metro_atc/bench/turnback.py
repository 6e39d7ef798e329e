"""Bench: Lin 2010a, Experiment 2 followed through the turnback (every ATS regulator).

A 180 s delay at the first station (BL01) of the Taipei Blue line at the 105 s peak
headway; each regulator of :data:`metro_atc.core.atr.registry.REGULATORS` acts on the truth
traffic model (:mod:`metro_atc.core.service.regulation`).  Reported: the delayed train's
arrival delay at the terminus BL23 against the 210 s turnback buffer of Lin 2010a and
against the buffers of the planned day's morning-peak turnbacks at BL23 (smallest and
median), the delay inherited by its next trip (down direction), and that trip's first
departure and terminal delay with the regulator acting on the down line (the turnback link
bounds its first departure).  Each direction has its own traffic model at the peak
(:func:`metro_atc.core.service.regulation.peak_lines`: the down line runs the stations
backwards with the down flow factor); AOC and DHP use the shipped weights trained on that
direction's model (found by traffic-model hash), ELQR its energy table for that direction's
runs.  A regulator without shipped weights for a direction is reported as not assessed
there, and shipped weights that fail their own validation are named.

Run:  python -m metro_atc.bench.turnback [--json] [--seed 0] [--delay 180]
Exit 0 when every regulator was assessed on both legs, 1 otherwise (stated on stdout / in
``next_trip_not_assessed``).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from typing import Dict, List, Optional

from metro_atc.core.atr.blue_line import LineData
from metro_atc.core.atr.lines import get_line
from metro_atc.core.atr.registry import REGULATORS, TRAINED
from metro_atc.core.atr.regulators import Regulator, make_regulator
from metro_atc.core.atr.regulators import shipped_weights
from metro_atc.core.atr.weights_store import validation_problem
from metro_atc.core.line.scenario import Scenario, load_scenario
from metro_atc.core.service.day import period_index, run_day, taipei_blue_day
from metro_atc.core.service.regulation import (INITIAL_DELAY_S, experiment_text, peak_lines,
                                               peak_period, turnback_experiment)

SCENARIO = "taipei_blue"
"""Scenario whose ATR line (and train, for ELQR's energy table) the bench regulates."""
METHODS = REGULATORS.names
"""Regulators assessed: all of them (Lin 2010a, Experiment 2 compares LQR, DHP and AOC)."""


def build(name: str, line: LineData, scn: Scenario) -> Regulator:
    """Regulator ``name`` for ``line`` (one direction's traffic model).

    Trained regulators: the shipped weights whose traffic-model hash is the line's
    (:func:`metro_atc.core.atr.regulators.shipped_weights`); FileNotFoundError when none
    is shipped for this line.  ``elqr``: its energy table for ``line``'s runs.
    """
    if name in TRAINED:
        path = shipped_weights(name, line)
        if path is None:
            raise FileNotFoundError(f"no shipped {name} weights for this direction's traffic "
                                    "model (hash)")
        return make_regulator(name, line, weights_path=path)
    return make_regulator(name, line, scenario=scn if name == "elqr" else None)


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
    peak = peak_period(plan)
    bufs = sorted(b.departure_s - a_.arrival_s - end.min_turnback_s
                  for blk in circ.blocks for a_, b in zip(blk.trips, blk.trips[1:])
                  if a_.destination == end.station
                  and period_index(plan.periods, a_.arrival_s) == peak)
    scn = load_scenario(SCENARIO)
    lines = peak_lines(plan, get_line(SCENARIO))
    line, down = lines["up"], lines["down"]
    regs: Dict[str, Regulator] = {}
    down_regs: Dict[str, Optional[Regulator]] = {}
    refused: Dict[str, str] = {}
    for m in METHODS:
        try:
            regs[m] = build(m, line, scn)
        except (ValueError, FileNotFoundError) as exc:
            print(f"turnback: regulator {m} cannot be built on the up line: {exc}",
                  file=sys.stderr)
            return 1
        try:
            down_regs[m] = build(m, down, scn)
        except (ValueError, FileNotFoundError) as exc:
            down_regs[m] = None
            refused[m] = str(exc)
    worse: Dict[str, str] = {}
    for d, ln in lines.items():
        for m in TRAINED:
            path = shipped_weights(m, ln)
            why = validation_problem(path) if path is not None else None
            if why is not None:
                worse[f"{m} ({d})"] = why
    res = turnback_experiment(regs, line, down_regs, down, end.min_turnback_s,
                              (bufs[0], statistics.median(bufs)), a.delay, a.seed)
    res["planned_day_peak_buffers_s"] = {"terminus": end.station,
                                         "period": plan.periods[peak].name,
                                         "count": len(bufs), "min": bufs[0],
                                         "median": statistics.median(bufs), "max": bufs[-1]}
    res["next_trip_not_assessed"] = refused
    res["weights_failing_validation"] = worse
    if a.json:
        print(json.dumps(res))
        return 0 if not refused else 1
    print(experiment_text(res))
    pb = res["planned_day_peak_buffers_s"]
    print(f"  planned day {plan.name}: {pb['count']} {pb['period']} turnbacks at "
          f"{pb['terminus']}, buffer min {pb['min']:.0f} s, median {pb['median']:.0f} s, max "
          f"{pb['max']:.0f} s (layover minus the {end.min_turnback_s:.0f} s minimum turnback)")
    for m, why in refused.items():
        print(f"  {m}: next trip not assessed: {why}")
    for m, why in worse.items():
        print(f"  {m}: warning: {why}")
    return 0 if not refused else 1


if __name__ == "__main__":
    raise SystemExit(main())
