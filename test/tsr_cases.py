"""Closed-loop runs of a generated incident line with its TSR moved (tests)."""

from __future__ import annotations

import copy
import dataclasses
import functools
from typing import Any

from metro_atc.core.closed_loop import run_closed_loop
from metro_atc.core.line.scenario import Scenario
from metro_atc.core.linegen import load_generated


@functools.lru_cache(maxsize=None)
def _generated(seed: int) -> Scenario:
    """Generated incident line ``seed``, parsed once per process (callers get copies)."""
    return load_generated(seed, incidents=True)


def shifted_tsr_row(seed: int, shift_m: float, limit_kmh: float) -> dict[str, Any]:
    """The closed-loop KPI row of generated incident line ``seed``, its TSR moved.

    The TSR is moved by ``shift_m`` [m] and limited to ``limit_kmh`` [km/h]; the run lasts
    until three trains have passed the zone.
    """
    base = copy.deepcopy(_generated(seed))
    z0 = next(i for i in base.incidents if i.kind == "tsr")
    z = dataclasses.replace(z0, start_m=z0.start_m + shift_m, end_m=z0.end_m + shift_m,
                            limit_kmh=limit_kmh)
    scn = dataclasses.replace(base, incidents=[z if i is z0 else i for i in base.incidents])
    headway = scn.timetable.periods[0].headway_s
    return dict(run_closed_loop(scn, duration_s=z.at_s + 2.0 * headway + 250.0).row())
