"""The planned service day with an injected delay: KPIs and pictures, without the plant.

Builds the day of a period table (default: the shipped Taipei Blue day,
:func:`metro_atc.core.service.day.taipei_blue_day`), its circulation
(:func:`metro_atc.core.service.day.run_day`), the records of the day run with one injected
delay (:func:`metro_atc.core.service.planned.planned_records`: trips run to time, the
turnback link carries what the buffer does not absorb, followers keep the line's minimum
separation) and writes ``day_kpis.json``, ``day_kpis.txt``, ``day_train_graph.png``,
``day_circulation.png`` and ``day_kpi_table.png`` (:func:`metro_atc.core.service.dayplots.
write_day_outputs`).

Run:  python -m metro_atc.bench.service_day --out DIR [--at 07:30] [--direction up]
      [--station 0] [--delay 180] [--table FILE]
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import List, Optional

from metro_atc.core.service.day import DayError, load_day, run_day
from metro_atc.core.service.dayplots import write_day_outputs
from metro_atc.core.service.planned import Incident, planned_records, trip_direction


def _clock(text: str) -> float:
    """hh:mm -> seconds after midnight; ValueError for anything else."""
    h, _, m = text.partition(":")
    if not (h.isdigit() and m.isdigit() and int(m) < 60 and int(h) < 30):
        raise ValueError(f"expected hh:mm, got {text!r}")
    return int(h) * 3600.0 + int(m) * 60.0


def main(argv: Optional[List[str]] = None) -> int:
    """Command-line entry point; see the module docstring."""
    ap = argparse.ArgumentParser(prog="service_day", description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, required=True, help="output directory")
    ap.add_argument("--table", default=None, help="period table YAML (default: shipped)")
    ap.add_argument("--at", default="07:30", help="the first trip departing at or after "
                    "hh:mm gets the delay")
    ap.add_argument("--direction", choices=("up", "down"), default="up")
    ap.add_argument("--station", type=int, default=0, help="station index of the delay")
    ap.add_argument("--delay", type=float, default=180.0, help="injected delay [s]")
    a = ap.parse_args(argv)
    try:
        at = _clock(a.at)
    except ValueError as exc:
        ap.error(f"--at: {exc}")
    if not 0.0 <= a.delay <= 7200.0:
        ap.error("--delay must lie in [0, 7200] s")
    try:
        plan = load_day(a.table)
        circ, _ = run_day(plan)
    except DayError as exc:
        ap.exit(2, f"service_day: {exc}\n")
    cands = sorted((t for b in circ.blocks for t in b.trips
                    if trip_direction(plan, t) == a.direction and t.departure_s >= at),
                   key=lambda t: t.departure_s)
    if not cands:
        ap.exit(2, f"service_day: no {a.direction} trip departs at or after {a.at}\n")
    trip = cands[0]
    try:
        rec = planned_records(plan, circ, [Incident(trip.trip_id, a.station, a.delay)])
    except ValueError as exc:
        ap.exit(2, f"service_day: {exc}\n")
    ref = planned_records(plan, circ)
    zoom = (max(plan.periods[0].start_s, trip.departure_s - 600.0),
            trip.departure_s + 5400.0)
    paths = write_day_outputs(plan, rec.stops, rec.turnbacks, rec.depot, a.out,
                              planned=ref.stops, zooms=(zoom,))
    print(Path(paths["kpis_txt"]).read_text(encoding="utf-8"), end="")
    print(f"delay {a.delay:.0f} s on {trip.trip_id} at station {a.station}; wrote "
          + ", ".join(paths.values()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
