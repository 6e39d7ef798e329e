"""Command line: ``python -m metro_atc {run,bench,train} ...``.

- ``run``: bring the node graph up as separate OS processes (or one, ``--single-process``),
  run a scenario to its end, tear everything down and print KPIs.
- ``bench NAME``: the reproductions and benchmarks (``bench --list`` names them).
- ``train {aoc,dhp}``: train the ATR critic/actor networks.
- ``import ttobench``: a TTOBench track + train (+ journey) as a scenario YAML.
- ``show --scenario FILE``: the resolved rolling stock, line and timetable, with sources.
- ``day``: a two-direction service day on the plant, ROS-free
  (:mod:`metro_atc.core.service.dayplant`).
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import sys
from typing import Sequence

BENCHES = {
    "perf": "metro_atc.bench.perf",
    "hosts": "metro_atc.bench.hosts",
    "ttobench": "metro_atc.bench.ttobench",
    "regulator-synthesis": "metro_atc.bench.regulator_synthesis",
    "regulation": "metro_atc.bench.regulation",
    "closed-loop": "metro_atc.bench.closed_loop",
    "lines": "metro_atc.bench.lines",
    "line-days": "metro_atc.bench.line_days",
    "energy-regulation": "metro_atc.bench.energy_regulation",
    "mmas": "metro_atc.bench.mmas",
    "profiles": "metro_atc.bench.profiles",
    "thsr": "metro_atc.bench.thsr",
    "ukf": "metro_atc.bench.ukf",
    "service-day": "metro_atc.bench.service_day",
    "day-scale": "metro_atc.bench.day_scale",
    "turnback": "metro_atc.bench.turnback",
}


def main(argv: Sequence[str] | None = None) -> int:
    """Dispatch the sub-commands; return the process exit code."""
    args = list(sys.argv[1:] if argv is None else argv)
    if not args or args[0] in ("-h", "--help"):
        print(__doc__.strip())
        print("\nusage: python -m metro_atc {run,show,day,bench,train,import} [options]   "
              "(-h after each)")
        return 0 if args else 2
    cmd, rest = args[0], args[1:]
    if cmd == "run":
        from metro_atc.launcher import main as run_main
        return run_main(rest)
    if cmd == "bench":
        return _bench(rest)
    if cmd == "show":
        from metro_atc.show import main as show_main
        return show_main(rest)
    if cmd == "day":
        from metro_atc.core.service.dayplant import main as day_main
        return day_main(rest)
    if cmd == "import":
        if not rest or rest[0] != "ttobench":
            print("usage: python -m metro_atc import ttobench --track T.json --train R.json "
                  "[--journey J.json] --out scenario.yaml", file=sys.stderr)
            return 2
        from metro_atc.ttobench.importer import main as import_main
        return import_main(rest[1:])
    if cmd == "train":
        try:
            mod = importlib.import_module("metro_atc.atr_train")
        except ModuleNotFoundError:
            print("metro_atc train: the ATR training module is not available", file=sys.stderr)
            return 2
        return int(mod.main(rest))
    print(f"metro_atc: unknown command {cmd!r} "
          "(expected run, show, day, bench, train or import)",
          file=sys.stderr)
    return 2


def _bench(rest: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m metro_atc bench", add_help=False)
    parser.add_argument("name", nargs="?")
    parser.add_argument("--list", action="store_true")
    known, tail = parser.parse_known_args(rest)
    available = {k: v for k, v in BENCHES.items() if importlib.util.find_spec(v) is not None}
    if known.list or not known.name:
        print("benchmarks: " + ", ".join(sorted(available)))
        return 0 if known.list else 2
    if known.name not in available:
        print(f"metro_atc bench: unknown benchmark '{known.name}' "
              f"(known: {', '.join(sorted(available))})", file=sys.stderr)
        return 2
    if known.name == "lines" and "--days" in tail:  # the two-direction days: line-days
        from metro_atc.bench.line_days import main as days_main
        return int(days_main([x for x in tail if x != "--days"],
                             prog="python -m metro_atc bench lines --days"))
    mod = importlib.import_module(available[known.name])
    return int(mod.main(tail))
