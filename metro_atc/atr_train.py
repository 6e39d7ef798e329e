r"""``python -m metro_atc train {aoc,dhp} [--scenario NAME] (--out FILE | --cache)``.

Trains ATR regulator weights.

Trains the AOC or DHP regulator of Lin 2010a (Exp. 2 setting: initial delays of 60-300 s at
the first station -- for half of the episodes anywhere on the line --, truth traffic model
with saturation, crowding, knock-on delays and exponential departure delays) on the ATR
line of ``--scenario`` (for a scenario: the model the ``ats_regulator`` node builds of it)
and writes a small weights file the node loads, stamped with the line's traffic-model hash
(the node refuses it on any other line); ``--cache`` writes it where ``run`` looks
(:mod:`metro_atc.core.atr.weights_store`).  ``--direction up|down`` trains on that direction
of the line at the peak of a service day (``--day``, default the shipped Taipei Blue day):
the line as seen running that way, with the peak period's flow factor of that direction
(:func:`metro_atc.core.service.regulation.peak_lines`); its own traffic-model hash.
Progress on stderr, then the file written and, if the weights' own validation cost is above
the timetable's, a warning with the figures (``run`` refuses such weights unless
``--accept-worse-regulator``).  Deterministic for a given --seed on one CPU thread.

The shipped defaults were produced with::

    python -m metro_atc.atr_train aoc --scenario taipei_blue --seed 0 \\
        --out metro_atc/data/aoc_taipei_blue.pt
    python -m metro_atc.atr_train dhp --scenario taipei_blue --seed 0 --epochs 600 \\
        --out metro_atc/data/dhp_taipei_blue.pt

and the down direction's (``metro_atc/data/<method>_taipei_blue_down.pt``) with
``--direction down`` (the exact commands: ``metro_atc/data/README.md`` and each file's
``info.command``).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import List, Optional

import torch

from metro_atc.core.atr.cost import CostWeights
from metro_atc.core.atr.fingerprint import line_hash
from metro_atc.core.atr.lines import get_line
from metro_atc.core.atr.registry import TRAINED
from metro_atc.core.atr.weights_store import (DEFAULT_EPOCHS, cached_path, train_weights,
                                              validation_problem)
from metro_atc.core.service.day import load_day
from metro_atc.core.service.regulation import DIRECTIONS, peak_lines


def main(argv: Optional[List[str]] = None) -> int:
    """Parse arguments, train, write the weights file; returns a process exit code."""
    ap = argparse.ArgumentParser(prog="metro_atc train",
                                 description="train ATR regulator weights (Lin 2010a AOC/DHP)")
    ap.add_argument("method", choices=TRAINED)
    ap.add_argument("--scenario", default="taipei_blue",
                    help="line: a scenario name or file (the ATS node's model of it), "
                         "blue_line_estimates or small<N>")
    dest = ap.add_mutually_exclusive_group(required=True)
    dest.add_argument("--out", type=Path, help="weights file to write (.pt)")
    dest.add_argument("--cache", action="store_true",
                      help="write into the weights cache, where 'run' finds it "
                           "(metro_atc.core.atr.weights_store)")
    ap.add_argument("--direction", choices=DIRECTIONS,
                    help="train on this direction of the line at the peak of the service "
                         "day --day (default: the line as it is)")
    ap.add_argument("--day", type=Path,
                    help="service day period table (YAML) for --direction (default: the "
                         "shipped Taipei Blue day)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--epochs", type=int, default=DEFAULT_EPOCHS)
    ap.add_argument("--q", type=float, default=CostWeights.q, help="state weight")
    ap.add_argument("--r", type=float, default=CostWeights.r, help="control weight")
    ap.add_argument("--horizon", type=int, default=CostWeights.horizon,
                    help="number of adjustable services K")
    ap.add_argument("--quiet", action="store_true", help="no progress on stderr, no summary")
    a = ap.parse_args(argv)
    if a.epochs < 1:
        ap.error("--epochs must be >= 1")
    try:
        line = get_line(a.scenario)
        if a.direction is not None:
            line = peak_lines(load_day(a.day, line), line)[a.direction]
        elif a.day is not None:
            ap.error("--day needs --direction")
        weights = CostWeights(q=a.q, r=a.r, horizon=a.horizon)
    except ValueError as exc:  # DayError is a ValueError
        ap.error(str(exc))
    out = a.out if a.out is not None else cached_path(a.method, line)
    torch.set_num_threads(1)
    info = train_weights(a.method, line, out, epochs=a.epochs, seed=a.seed, weights=weights,
                         progress=None if a.quiet else
                         (lambda m: print(m, file=sys.stderr, flush=True)),
                         extra_info={"command": "python -m metro_atc.atr_train " + " ".join(
                             argv if argv is not None else sys.argv[1:])})
    if not a.quiet:
        print(json.dumps({"method": a.method, "scenario": line.name, "out": str(out),
                          "line_hash": line_hash(line), **info}))
    print(f"metro_atc train: weights written to {out}", file=sys.stderr)
    worse = validation_problem(out)
    if worse is not None:
        # written all the same (for study); 'run' refuses them without --accept-worse-regulator
        print(f"metro_atc train: warning: {worse}; 'run' refuses them unless "
              "--accept-worse-regulator", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
