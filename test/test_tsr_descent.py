"""Property: a TSR on a steep descent soon after a platform, followed smoothly.

``gen_0014_inc``: a 30 km/h TSR 1.1 km after the first platform; the trains leave it down a
-40 then -21 per mille descent and are at ~40 km/h, still accelerating, when the TSR's
braking curve falls on them.  On that line and on copies of it with the TSR moved and its
limit changed, the closed loop (plant, ATP, real ATO) up to the third train through the
zone has no ATP intervention and one speed minimum per TSR approach (no hunting,
:mod:`metro_atc.core.tsr_hunting`).  Before the ATO read the TSR's SBI curve
``CAP_LOOKAHEAD_S`` ahead (as it reads the static one), shifts 0 and +40 m had 3 SBI
onsets each (every train whose run was planned with the TSR in force, 119 m before it at
40.2 km/h) and +100 m two speed minima in one approach.
"""

from __future__ import annotations

import pytest

from tsr_cases import shifted_tsr_row
from metro_atc.core.closed_loop import run_closed_loop
from metro_atc.core.linegen import load_generated


@pytest.mark.parametrize("shift_m,limit_kmh", [(0.0, 30.0), (40.0, 25.0), (100.0, 30.0),
                                               (-100.0, 30.0)])
def test_tsr_after_departure_on_a_descent_no_intervention_no_hunting(
        shift_m: float, limit_kmh: float) -> None:
    """0 ATP interventions and violations, one speed minimum per TSR approach."""
    row = shifted_tsr_row(14, shift_m, limit_kmh)
    assert row["atp_violations"] == 0
    assert row["tsr_approaches"] >= 3
    assert row["atp_interventions"] == 0
    assert row["tsr_speed_minima_raw_max"] == 1
    assert row["tsr_speed_minima_max"] == 1


@pytest.mark.parametrize("seed", [39, 40])
def test_intervention_at_a_tsr_notice_is_counted_apart(seed: int) -> None:
    """gen_0039/0040_inc: the TSR becomes known (to the ATP and the ATO at once) with the
    first train inside the zone (0040: its rear) at 63-66 km/h: an SBI in the same step,
    which no ATO can avoid; the bench counts it in ``atp_interventions_at_tsr_notice``."""
    row = run_closed_loop(load_generated(seed, incidents=True), duration_s=260.0).row()
    assert row["atp_interventions"] == 1
    assert row["atp_interventions_at_tsr_notice"] == 1
