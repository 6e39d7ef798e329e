"""Golden ECTP plans: record once from a reference planner, compare the planner under test.

A *case* is one interstation of a scenario (the Blue line or a generated line, with the
planning limits, train and track the closed loop gives the ATO,
:func:`metro_atc.core.ato.onboard.envelope_limits`) planned by ECTP
(:func:`metro_atc.core.ato.planner.plan_profile`, integration step ``max(2, L/700)`` as
:class:`metro_atc.core.ato.controller.AtoCore` uses) for several running-time targets: just
above the flat-out time, two slacker ones and one below the minimum (the flat-out fallback).
Stored per plan: coasting point, running time, energy, feasibility, the sections derived
from the speed profile (bounds, modes, codes), the profile's length and sum and 33 samples.

Recorded from the numpy planner before the compiled kernel (``git log test/data``).
Re-record (only when the plans are meant to change, and say so in the commit):
``python test/ato_golden.py``.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from metro_atc.core.ato import coasting
from metro_atc.core.ato.envelope import RunModel
from metro_atc.core.ato.onboard import envelope_limits
from metro_atc.core.ato.planner import Profile, plan_profile
from metro_atc.core.bridge import timetable_for, track_for, train_for
from metro_atc.core.line.scenario import Scenario, load_scenario
from metro_atc.core.linegen import load_generated

PATH = Path(__file__).parent / "data" / "ato_ectp_golden.json"
TARGET_FACTORS = (0.97, 1.02, 1.12, 1.30)
"""Targets as multiples of the flat-out running time (0.97: below the minimum)."""
SCENARIOS: tuple[tuple[str, tuple[tuple[int, int], ...]], ...] = (
    ("taipei_blue", ((0, 1), (5, 6), (10, 11), (21, 22), (12, 11))),
    ("gen:0", ((0, 1), (3, 4), (6, 7))),
    ("gen:1", ((2, 3), (8, 9), (11, 12))),
    ("gen:2", ((0, 1), (5, 6), (10, 11))),
    ("gen:12", ((0, 1), (4, 5), (7, 8))),
    ("gen:46", ((1, 2), (3, 4), (5, 6))),
)
"""Scenarios and their interstations (station index pairs; (12, 11) runs backwards).
gen:12 uses the high-speed stock, gen:46 is the steep line that broke the bracket search."""
N_SAMPLES = 33


def scenario(name: str) -> Scenario:
    """The scenario of a case name (``taipei_blue`` or ``gen:<seed>``)."""
    if name.startswith("gen:"):
        return load_generated(int(name[4:]))
    pkg = Path(__file__).resolve().parents[1] / "metro_atc" / "scenarios" / f"{name}.yaml"
    return load_scenario(str(pkg))


def cases() -> Iterator[tuple[str, int, int, RunModel, float]]:
    """(scenario, from, to, run model, integration step [m]) of every golden interstation."""
    for name, pairs in SCENARIOS:
        scn = scenario(name)
        train, track = train_for(scn), track_for(scn)
        limits = envelope_limits(scn, train)
        pos = np.asarray(timetable_for(scn).station_positions_m, dtype=float)
        for a, b in pairs:
            run = RunModel(train, track, float(pos[a]), float(pos[b]), limits)
            yield name, a, b, run, max(2.0, run.length_m / 700.0)


def summary(prof: Profile) -> dict[str, Any]:
    """The stored fingerprint of a plan."""
    v = np.asarray(prof.v_profile, dtype=float)
    idx = np.linspace(0, v.size - 1, N_SAMPLES).round().astype(int)
    return {"coast_point_m": prof.coast_point_m, "running_time_s": prof.running_time_s,
            "energy_j": prof.energy_j, "feasible": prof.feasible,
            "section_bounds_m": prof.section_bounds_m.tolist(), "modes": prof.modes.tolist(),
            "codes_mps": prof.codes_mps.tolist(), "n": int(v.size), "v_sum": float(v.sum()),
            "v_samples": v[idx].tolist()}


def record() -> list[dict[str, Any]]:
    """Plan every case and target with the planner of this checkout."""
    out = []
    for name, a, b, run, h in cases():
        t_min = coasting.fotp(run, math.inf, h).time_s
        cache: dict[Any, Any] = {}
        for f in TARGET_FACTORS:
            target = round(f * t_min, 2)
            prof = plan_profile(run, target, "ectp", cache, h_m=h)
            out.append({"scenario": name, "from": a, "to": b, "h_m": h, "target_s": target,
                        **summary(prof)})
            print(f"{name} {a}->{b} target {target:.2f} s: coast {prof.coast_point_m:.3f} m, "
                  f"{prof.running_time_s:.3f} s, {prof.energy_j / 3.6e6:.4f} kWh, "
                  f"{prof.compute_s:.3f} s", file=sys.stderr)
    return out


def main() -> None:
    """Record the golden plans into :data:`PATH`."""
    rows = record()
    PATH.parent.mkdir(parents=True, exist_ok=True)
    PATH.write_text(json.dumps(rows, indent=None, separators=(",", ":")) + "\n")
    print(f"{len(rows)} plans -> {PATH}", file=sys.stderr)


if __name__ == "__main__":
    main()
