"""Property: no hunting on a TSR approach, wherever the TSR lies and whatever its limit.

``gen_0039_inc``: a 25 km/h TSR 906-1265 m on the first run (0 -> 2291 m), known at 160 s,
in force from 280 s.  The ECTP plan of that run, made without the TSR, coasts from 46 to
40 km/h and motors back (a coast-and-motor cycle); with the TSR moved +60 m and limited to
30 km/h the trains coasted to 40.3 km/h at 646 m, motored to 47 km/h and braked to the TSR
100 m later: two speed minima in one approach (hunting), out of reach of the hold rule
(:meth:`metro_atc.core.ato.onboard.OnboardAto._tsr_hold`).  The cause was the plan: a TSR
known when a run is planned is now a speed limit of the run
(:mod:`metro_atc.core.ato.tsr_plan`), so the energy-optimal profile rides into the TSR's
braking curve with no motoring cycle before it.

On gen_0039_inc and on gen_0014_inc (a 30 km/h TSR on a -40 / -21 per mille descent 1.1 km
after the first platform), with the TSR moved -150..+250 m and limited to 25 / 30 / 40 km/h,
the closed loop (plant, ATP, real ATO) up to the third train through the zone has no ATP
violation, one speed minimum per TSR approach (:mod:`metro_atc.core.tsr_hunting`, not
weakened) and every stop within 0.30 m.  Main's ATO (plans without the TSR) fails 10 of
these 30 cases (two minima per approach).
"""

from __future__ import annotations

import itertools
import multiprocessing
from concurrent.futures import ProcessPoolExecutor
from typing import Any

import pytest

from tsr_cases import shifted_tsr_row

SEEDS = (39, 14)
SHIFTS_M = (-150.0, -50.0, 50.0, 150.0, 250.0)
LIMITS_KMH = (25.0, 30.0, 40.0)
CASES = list(itertools.product(SEEDS, SHIFTS_M, LIMITS_KMH))


HOLD_CASES = [(50.0, 30.0), (150.0, 40.0), (250.0, 25.0)]
"""(shift [m], limit [km/h]) of the hold-rule cases on gen_0039_inc."""


def _row(case: tuple[int, float, float]) -> dict[str, Any]:
    return shifted_tsr_row(*case)


def _hold_row(case: tuple[float, float]) -> dict[str, Any]:
    """A hold-rule case: the run of gen_0039_inc with every plan made without the TSR (the
    worker's ``onboard.tsrs_for_run`` replaced for this run only)."""
    from metro_atc.core.ato import onboard
    keep = onboard.tsrs_for_run
    onboard.tsrs_for_run = lambda *args: ()
    try:
        return shifted_tsr_row(39, *case)
    finally:
        onboard.tsrs_for_run = keep


@pytest.fixture(scope="module")
def sweep_rows() -> dict[Any, dict[str, Any]]:
    """The 30 closed loops of the sweep and the 3 hold-rule runs, on two worker processes
    (each ~1-3 s CPU; spawned: the test process may hold DDS threads a fork would copy);
    keys: the sweep's (seed, shift, limit), ``("hold", shift, limit)``."""
    ctx = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=2, mp_context=ctx) as ex:
        hold = ex.map(_hold_row, HOLD_CASES)
        rows: dict[Any, dict[str, Any]] = dict(zip(CASES, ex.map(_row, CASES)))
        rows.update(zip((("hold", *c) for c in HOLD_CASES), hold))
        return rows


@pytest.mark.parametrize("seed", SEEDS)
@pytest.mark.parametrize("shift_m", SHIFTS_M)
@pytest.mark.parametrize("limit_kmh", LIMITS_KMH)
def test_one_speed_minimum_per_tsr_approach(
        sweep_rows: dict[Any, dict[str, Any]], seed: int, shift_m: float,
        limit_kmh: float) -> None:
    """0 violations, one speed minimum per TSR approach, the stops within 0.30 m."""
    row = sweep_rows[(seed, shift_m, limit_kmh)]
    assert row["atp_violations"] == 0
    assert row["tsr_approaches"] >= 3
    assert row["tsr_speed_minima_max"] == 1
    assert row["stop_error_max_m"] <= 0.30
    assert row["missed_stops"] == 0
    # the only intervention allowed is the one no ATO can avoid: a train inside the zone
    # or its braking distance when the TSR becomes known (counted apart by the bench)
    assert row["atp_interventions"] == row["atp_interventions_at_tsr_notice"]


@pytest.mark.parametrize("shift_m,limit_kmh", HOLD_CASES)
def test_hold_rule_alone_for_plans_made_without_the_tsr(
        sweep_rows: dict[Any, dict[str, Any]], shift_m: float, limit_kmh: float) -> None:
    """Plans made without the TSR (a TSR notified after the departure; here every plan):
    the ATO's hold rule alone keeps one speed minimum per approach on gen_0039_inc (main's
    ATO: two on these cases), by not motoring out of a speed dip before a known TSR."""
    row = sweep_rows[("hold", shift_m, limit_kmh)]
    assert row["atp_violations"] == 0
    assert row["tsr_approaches"] >= 3
    assert row["tsr_speed_minima_max"] == 1
    assert row["stop_error_max_m"] <= 0.30
