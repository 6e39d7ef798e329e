"""ATO core: Li n.d. fuzzy controller, reference motion curve and THSR stopping."""

from __future__ import annotations

import numpy as np
import pytest

from metro_atc.core.ato.envelope import RunModel
from metro_atc.core.ato.fuzzy import (RULE_MATRIX, FuzzyController, d_memberships,
                                      e_memberships, flc_output)
from metro_atc.core.ato.pi import PIController
from metro_atc.core.ato.reference_curve import (REGION_ACCEL, REGION_BRAKE, REGION_CREEP,
                                                REGION_DECEL, REGION_MAX_SPEED, ReferenceCurve)
from metro_atc.core.ato.tracking import simulate_tracking
from metro_atc.core.line.vehicle import THSR_700T, Track


def test_rule_table_is_seed004_table1() -> None:
    """Rows d = P, Z, N; columns e = PB, P, Z, N, NB (Li n.d., Table 1)."""
    expected = np.array([[1, 1, 0.5, 0, -0.5], [1, 0.5, 0, -0.5, -1],
                         [0.5, 0, -0.5, -1, -1]])
    np.testing.assert_array_equal(RULE_MATRIX, expected)


def test_memberships_partition_and_symmetry() -> None:
    """Memberships sum to one; the controller output is odd and monotone in e."""
    x = np.linspace(-3.0, 3.0, 601)
    np.testing.assert_allclose(e_memberships(x).sum(axis=-1), 1.0)
    np.testing.assert_allclose(d_memberships(x).sum(axis=-1), 1.0)
    for d in (-0.7, 0.0, 0.4):
        y = flc_output(x, d)
        np.testing.assert_allclose(flc_output(-x, -d), -y, atol=1e-12)
        assert np.all(np.diff(y) >= -1e-12)
    assert float(flc_output(0.0, 0.0)) == 0.0
    assert float(flc_output(5.0, 5.0)) == 1.0


def test_reference_curve_regions_and_limits() -> None:
    """The five regions appear in order; accel/decel limits hold; r = 0 at the platform."""
    run = RunModel(THSR_700T, Track.flat(300 / 3.6), 0.0, 60_000.0)
    ref = ReferenceCurve(run)
    s = np.linspace(0.0, 60_000.0, 600_001)
    reg = ref.region(s)
    seq = [int(reg[0])] + [int(r) for a, r in zip(reg[:-1], reg[1:]) if r != a]
    assert seq == [REGION_ACCEL, REGION_MAX_SPEED, REGION_DECEL, REGION_CREEP, REGION_BRAKE]
    r = ref.speed(s)
    assert float(ref.speed(60_000.0)) == 0.0
    assert np.max(r) <= 300 / 3.6 + 1e-9
    acc = np.diff(0.5 * r ** 2) / np.diff(s)  # r dr/ds
    assert np.max(acc[s[1:] > 50.0]) <= 2.0 / 3.6 + 1e-6
    assert np.min(acc) >= -ref.p.decel_mps2 - 1e-6


def test_fuzzy_stops_at_thsr_platform() -> None:
    """Taipei -> Banqiao (7.3 km) on RK4: stop within 0.1 m, small RMSE (Li n.d., Table 5)."""
    run = RunModel(THSR_700T, Track.flat(300 / 3.6), 0.0, 7300.0)
    res = simulate_tracking([run], [ReferenceCurve(run)], FuzzyController(), dt_s=0.1)[0]
    assert res.arrived
    assert abs(res.stop_error_m) < 0.1
    assert res.speed_rmse_mps < 0.1
    assert 240.0 < res.trip_time_s < 300.0
    # traction energy exceeds the peak kinetic energy delivered
    v_peak = float(np.max(ReferenceCurve(run).speed(np.linspace(0, 7300, 7301))))
    assert res.energy_j > 0.5 * THSR_700T.mass_kg * v_peak ** 2


def test_pi_tracker_is_pluggable() -> None:
    """The PI tracker drives the same loop to a stop near the platform."""
    run = RunModel(THSR_700T, Track.flat(300 / 3.6), 0.0, 3000.0)
    res = simulate_tracking([run], [ReferenceCurve(run)], PIController(), dt_s=0.1)[0]
    assert res.arrived
    assert abs(res.stop_error_m) < 1.0


@pytest.mark.parametrize("incremental", [True, False])
def test_fuzzy_output_bounds(incremental: bool) -> None:
    """Commands stay in [-1, 1] whatever the error."""
    from metro_atc.core.ato.fuzzy import FuzzyParams
    c = FuzzyController(FuzzyParams(incremental=incremental, gain=0.5))
    rng = np.random.default_rng(0)
    for _ in range(200):
        u = c.step(rng.normal(0, 30, 3), rng.normal(0, 30, 3))
        assert np.all(np.abs(u) <= 1.0)
