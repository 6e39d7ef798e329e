"""The laws of :mod:`metro_atc.core.laws`: closed forms and the expressions they replaced.

Each law is checked against its closed form at known points and, on generated inputs,
against the inline expression it replaced (written out here in the old operation order):
``==`` on every float, so a re-ordered operation fails.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from metro_atc.core import laws as L
from metro_atc.core.line.vehicle import TAIPEI_MRT_6CAR, THSR_700T

RNG = np.random.default_rng(20261128)
SPEEDS = np.concatenate([RNG.uniform(0.0, 90.0, 20000), RNG.uniform(-5.0, 5.0, 500),
                         [0.0, -0.0, 1e-300, 10.0, 60.0 / 3.6]])


def _trac(p):  # type: ignore[no-untyped-def]
    return (p.a1_mps2, p.v1_mps, p.v2_mps, p.a2, p.a3, p.b2_mps, p.b3_mps)


@pytest.mark.parametrize("p", [TAIPEI_MRT_6CAR, THSR_700T])
def test_traction_law_closed_form_and_old_array_expression(p) -> None:  # type: ignore
    """eq. 3-5: a1 below v1, a2/(v+b2) to v2, a3/(v+b3)^2 above; numpy's old array form."""
    t = _trac(p)
    assert L.traction_accel(0.5 * p.v1_mps, *t) == p.a1_mps2
    assert L.traction_accel(-0.5 * p.v1_mps, *t) == p.a1_mps2
    if p.v2_mps < 1e6:
        v = 0.5 * (p.v1_mps + p.v2_mps)
        assert L.traction_accel(v, *t) == p.a2 / (v + p.b2_mps + 1e-12)
        # continuity at v1, v2 (a2, a3 from the continuity conditions)
        assert math.isclose(L.traction_accel(p.v1_mps * (1 + 1e-12), *t), p.a1_mps2,
                            rel_tol=1e-9)
        assert math.isclose(L.traction_accel(p.v2_mps * (1 + 1e-12), *t),
                            p.a2 / (p.v2_mps + p.b2_mps), rel_tol=1e-9)
    va = np.abs(SPEEDS)
    old = np.where(va <= p.v1_mps, p.a1_mps2,
                   np.where(va <= p.v2_mps, p.a2 / (va + p.b2_mps + 1e-12),
                            p.a3 / (va + p.b3_mps + 1e-12) ** 2))
    new = L.traction_accel_array(SPEEDS, *t)
    assert np.array_equal(new, old)
    assert np.array_equal(new, np.array([L.traction_accel(float(x), *t) for x in SPEEDS]))
    assert L.traction_force(33.0, p.mass_kg, *t) == p.mass_kg * L.traction_accel(33.0, *t)


def test_traction_constants_from_continuity() -> None:
    """a2 = a1 (v1 + b2); a3 = a2 / (v2 + b2) (v2 + b3)^2 (x*x, correctly rounded)."""
    a2 = L.traction_a2(1.0, 10.0, 0.5)
    assert a2 == 10.5
    a3 = L.traction_a3(1.0, 10.0, 16.0, 0.5, 0.25)
    q = 16.0 + 0.25
    assert a3 == (10.5 / 16.5) * (q * q)


def test_square_is_a_product_not_pow() -> None:
    """The laws square with ``x * x`` (correctly rounded); C ``pow(x, 2)`` is not always.

    Known answer: for this x, glibc ``pow`` (CPython's ``x ** 2``) is one ulp off the
    correctly rounded square on the reference machine; the law must give the product.
    """
    x = 6237.938163812799
    exact = x * x
    t = (1.0, 1.0, 2.0, 2.0, 1.0, 0.0, -1e-12)  # a3 / (v + b3 + 1e-12)^2 with q = v
    assert L.traction_accel(x, *t) == 1.0 / exact


def test_davis_resistance_and_odd_form() -> None:
    """A + B|v| + C v^2 (eq. 1-2, the old order), and its odd extension of the observer."""
    a, b, c = 1000.0, 50.0, 3.0
    assert L.davis_resistance(2.0, a, b, c) == 1000.0 + 100.0 + 12.0
    assert L.davis_resistance(-2.0, a, b, c) == L.davis_resistance(2.0, a, b, c)
    va = np.abs(SPEEDS)
    p = TAIPEI_MRT_6CAR
    old = p.davis_a_n + p.davis_b_n_per_mps * va + p.davis_c_n_per_mps2 * va * va
    assert np.array_equal(L.davis_resistance_array(SPEEDS, p.davis_a_n, p.davis_b_n_per_mps,
                                                   p.davis_c_n_per_mps2), old)
    for v in SPEEDS[:2000]:
        v = float(v)
        sg = 1.0 if v > 0.0 else (-1.0 if v < 0.0 else 0.0)
        assert L.davis_odd(v, 0.02, 5e-4, 4.7e-5) == (5e-4 + 4.7e-5 * abs(v)) * v + 0.02 * sg
    assert math.isnan(L.davis_odd(math.nan, 1.0, 1.0, 1.0))


def test_grade_and_curve_resistance() -> None:
    """m g sin(atan(i)); Roeckl 650/(R-55) from 300 m, 500/(R-30) below [N/kN]."""
    assert L.grade_force(0.0, 1000.0) == 0.0
    assert math.isclose(L.grade_force(0.03, 1000.0), 1000.0 * 9.80665 * 0.03 / math.sqrt(
        1.0009), rel_tol=1e-14)
    assert L.curve_resistance_per_kg(355.0) == 650.0 / 300.0 / 1000.0 * 9.80665
    assert L.curve_resistance_per_kg(130.0) == 500.0 / 100.0 / 1000.0 * 9.80665
    assert L.curve_resistance_per_kg(30.5) == 500.0 / 1.0 / 1000.0 * 9.80665
    r = RNG.uniform(20.0, 2000.0, 5000)
    old = np.where(r >= 300.0, 650.0 / np.maximum(r - 55.0, 1.0),
                   500.0 / np.maximum(r - 30.0, 1.0)) / 1000.0 * 9.80665
    assert np.array_equal(L.curve_resistance_per_kg_array(r), old)


def test_net_accel_is_newton() -> None:
    """(F - sign(v) F_r(v) - F_g) / M_eff."""
    assert L.net_accel(10.0, 5000.0, 1000.0, 100.0, 10.0, 1.0, 2000.0) == \
        (5000.0 - (100.0 + 100.0 + 100.0) - 1000.0) / 2000.0
    assert L.net_accel(0.0, 5000.0, 0.0, 100.0, 10.0, 1.0, 1000.0) == 5.0


def test_rk4_step_is_exact_for_a_constant_slope_and_fourth_order() -> None:
    """q constant (cb = cc = 0): v + q h, distance v h + q h^2 / 2 exactly; linear drag:
    the RK4 error of exp(-cb h) is O(h^5)."""
    vn, dx, k1, kv = L.davis_rk4_step(10.0, -1.0, 0.0, 0.0, 0.5)
    assert (vn, dx, k1) == (9.5, 4.875, -1.0)
    assert kv == -1.0 * (10.0 + 2.0 * (9.75 + 9.75) + 9.5)
    cb = 0.3
    errs = []
    for h in (0.2, 0.1):
        vn, dx, _, _ = L.davis_rk4_step(10.0, 0.0, cb, 0.0, h)
        errs.append(abs(vn - 10.0 * math.exp(-cb * h)))
    assert 20.0 < errs[0] / errs[1] < 40.0  # 2^5 = 32


def test_rk4_step_equals_the_old_plant_substep() -> None:
    """The plant's old inline sub-step (dynamics.rk4_motion), operation for operation."""
    for _ in range(3000):
        v, q = float(RNG.uniform(0, 30)), float(RNG.uniform(-1.5, 1.2))
        cb, cc, h = float(RNG.uniform(0, 1e-3)), float(RNG.uniform(0, 1e-4)), 0.25
        h2, h6 = 0.5 * h, h / 6.0
        k1 = q - v * (cb + cc * v)
        v2 = v + h2 * k1
        k2 = q - v2 * (cb + cc * v2)
        v3 = v + h2 * k2
        k3 = q - v3 * (cb + cc * v3)
        v4 = v + h * k3
        k4 = q - v4 * (cb + cc * v4)
        old = (v + h6 * (k1 + 2.0 * (k2 + k3) + k4), h6 * (v + 2.0 * (v2 + v3) + v4), k1,
               k1 * v + 2.0 * (k2 * v2 + k3 * v3) + k4 * v4)
        assert L.davis_rk4_step(v, q, cb, cc, h) == old
    assert L.stop_distance_in_step(2.0, -1.0, 10.0) == 2.0
    assert L.stop_distance_in_step(2.0, -1.0, 0.5) == 1.0
    assert L.stop_distance_in_step(2.0, 0.5, 1e9) == 4.0 / 2e-9


def test_brake_laws() -> None:
    """Electric brake: force limit, power limit P/v, linear fade; blend; pad torque."""
    m, b, pw, vf = 200_000.0, 1.0, 2.4e6, 5.0 / 3.6
    assert L.electric_brake_force_max(5.0, m, b, pw, vf) == 200_000.0
    assert L.electric_brake_force_max(20.0, m, b, pw, vf) == 120_000.0
    assert L.electric_brake_force_max(0.5 * vf, m, b, pw, vf) == 100_000.0
    assert L.electric_brake_force_max(0.0, m, b, pw, vf) == 0.0
    v = np.linspace(0.0, 40.0, 4001)
    vv = np.maximum(v, 1e-3)
    old = np.minimum(b * m, pw / vv) * np.minimum(v / vf, 1.0)
    assert np.array_equal(L.electric_brake_force_max_array(v, m, b, pw, vf), old)
    assert L.electric_brake_share(10.0, 4.0) == 4.0
    assert L.electric_brake_share(3.0, 4.0) == 3.0
    assert L.brake_demand_force(-0.5, 1000.0) == 500.0
    assert L.brake_demand_force(0.5, 1000.0) == 0.0
    assert L.traction_demand_force(0.5, 1000.0, 400.0, 1e9) == 400.0
    assert L.traction_demand_force(0.5, 1000.0, 600.0, 450.0) == 450.0
    assert L.pad_torque(1000.0, 0.35, 0.25) == 175.0
    assert L.clamp_force_for_torque(175.0, 0.35, 0.25) == 175.0 / (2.0 * 0.35 * 0.25)
    mu = np.array([[0.35, 0.1], [0.2, 0.38]])
    fc = np.array([[1e4, 2e3], [5.5e3, 0.0]])
    assert np.array_equal(L.pad_torque(fc, mu, 0.25), 2.0 * mu * 0.25 * fc)  # arrays too
    assert L.command_effort(2.0, 100.0, 10.0, 1.0) == 100.0
    assert L.command_effort(-0.5, 100.0, 10.0, 1.0) == -5.0


def test_adhesion_laws() -> None:
    """Burckhardt mu(0) = 0, mu(1) = c1 (1 - e^-c2) - c3; the axle load and its limit."""
    assert L.burckhardt_mu(0.0, 0.32, 150.0, 0.08) == 0.0
    assert L.burckhardt_mu(2.0, 0.32, 150.0, 0.08) == 0.32 * (1.0 - math.exp(-150.0)) - 0.08
    assert L.burckhardt_mu(-1.0, 0.32, 150.0, 0.08) == 0.0
    assert L.axle_load(24_000.0, 4.0) == 24_000.0 * (9.80665 / 4.0)
    assert L.adhesion_limit(0.3, 1000.0) == 300.0


def test_atp_curve_laws() -> None:
    """EBI speed is the inverse of the stopping distance; known coefficients."""
    b, tr, aw = 1.0, 2.0, 0.5
    c0, c1, c2 = L.ebi_coef(b, tr, aw)
    assert (c0, c1, c2) == (4.0 + 2.0, 2.0, 3.0)
    for v in (0.0, 5.0, 12.5, 22.0):
        d = L.stopping_distance(v, aw, tr, b)
        assert math.isclose(L.ebi_speed(d, 0.0, aw, tr, b), v, rel_tol=1e-12, abs_tol=1e-12)
    assert L.ebi_speed(-100.0, 0.0, aw, tr, b) == -3.0
    assert math.isnan(L.ebi_speed(math.nan, 0.0, aw, tr, b))
    assert L.ebi_speed(0.0, 4.0, aw, tr, b) == math.sqrt(6.0 + 16.0) - 3.0
    assert L.response_distance(10.0, 1.0, 2.0) == 22.0
    assert L.braking_speed(50.0, 1.0) == 10.0
    assert L.braking_speed(-5.0, 1.0) == 0.0
    assert L.guaranteed_decel_on_grade(1.2, 0.03) == 1.2 - 9.80665 * 0.03
    assert L.response_accel(1.0, 0.03) == 1.0 + 9.80665 * 0.03
    assert L.adhesion_guaranteed_decel(0.24, 100.0, 10.0) == 0.9 * 0.24 * 9.80665 * 100.0 / 110.0


def test_laws_are_compiled() -> None:
    """Each law is a numba dispatcher (so the kernels can call it) with its Python source."""
    from numba.core.registry import CPUDispatcher
    for name in ("traction_accel", "davis_resistance", "grade_force", "electric_brake_force_max",
                 "burckhardt_mu", "ebi_speed", "davis_rk4_step", "net_accel"):
        assert isinstance(getattr(L, name), CPUDispatcher), name
