"""LQR baseline against hand-solved Riccati cases; none regulator; regulator interface."""

import numpy as np
import pytest

from metro_atc.core.atr.blue_line import small_line, taipei_blue
from metro_atc.core.atr.cost import CostWeights, stage_cost, terminal_cost, terminal_matrix
from metro_atc.core.atr.regulators import LqrRegulator, lqr_gain, make_regulator
from metro_atc.core.atr.traffic import linear_model


def test_two_station_lqr_by_hand():
    """c = 0 (no boarding feedback): A = shift, B = I, q = r = 1.

    By hand: P = Q + A^T (P^-1 + R^-1)^-1 A gives p2 = 1, p1 = 1 + 1/(1/p2 + 1) = 1.5, and
    K = (R + P)^-1 P A = [[0, 0], [0.5, 0]]: a delay moving into station 2 is halved.
    """
    a, b = linear_model(np.zeros(2))
    np.testing.assert_array_equal(a, [[0.0, 0.0], [1.0, 0.0]])
    k = lqr_gain(a, b, 1.0, 1.0)
    np.testing.assert_allclose(k, [[0.0, 0.0], [0.5, 0.0]], atol=1e-12)
    reg = LqrRegulator(a, b, CostWeights(q=1.0, r=1.0))
    np.testing.assert_allclose(reg.decide(np.array([60.0, 10.0])), [0.0, -30.0], atol=1e-9)


def test_scalar_riccati_closed_form():
    """Scalar DARE b^2 p^2 + (r - a^2 r - q b^2) p - q r = 0 (positive root)."""
    c = 0.2
    a, b = linear_model(np.array([c]))        # a = -0.25, b = 1.25
    q, r = 1.0, 0.1
    aa, bb = a[0, 0], b[0, 0]
    coef = [bb ** 2, r - aa ** 2 * r - q * bb ** 2, -q * r]
    p = max(np.roots(coef).real)
    k_expected = bb * p * aa / (r + bb ** 2 * p)
    assert lqr_gain(a, b, q, r)[0, 0] == pytest.approx(k_expected, rel=1e-10)


def test_lqr_is_stabilising_and_scale_free_on_blue_line():
    line = taipei_blue()
    reg = make_regulator("lqr", line, CostWeights())
    a, b = linear_model(line.c())
    acl = a - b @ reg.k
    assert np.max(np.abs(np.linalg.eigvals(acl))) < 1.0
    x = np.zeros(23)
    x[0] = 180.0
    u1 = reg.decide(x)
    u2 = reg.decide(2 * x)
    np.testing.assert_allclose(u2, 2 * u1)
    assert u1[1] < 0.0               # the delayed train is told to run faster


def test_none_regulator_and_input_validation():
    line = small_line(3)
    reg = make_regulator("none", line)
    np.testing.assert_array_equal(reg.decide(np.array([1.0, 2.0, 3.0])), np.zeros(3))
    with pytest.raises(ValueError, match="NaN"):
        reg.decide(np.array([1.0, np.nan, 3.0]))
    with pytest.raises(ValueError, match="stations"):
        reg.decide(np.zeros(4))
    with pytest.raises(ValueError, match="unknown regulator"):
        make_regulator("pid", line)
    with pytest.raises(FileNotFoundError):
        make_regulator("aoc", line)          # no shipped weights for a 3-station toy line


def test_cost_terms():
    w = CostWeights(q=2.0, r=0.5, x_scale_s=10.0)
    assert stage_cost(np.array([10.0, 20.0]), np.array([10.0, 0.0]), w) == pytest.approx(
        0.5 * 2.0 * (1 + 4) + 0.5 * 0.5 * 1)
    a, _ = linear_model(np.zeros(2))
    p0 = terminal_matrix(a, 1.0)   # free run [x1, x2] -> [0, x1] -> 0: tail 2 x1^2 + x2^2
    np.testing.assert_allclose(p0, [[2.0, 0.0], [0.0, 1.0]])
    assert terminal_cost(np.array([10.0, 0.0]), p0, w) == pytest.approx(1.0)
    with pytest.raises(ValueError):
        CostWeights(q=-1.0)
    with pytest.raises(ValueError):
        CostWeights(horizon=0)
