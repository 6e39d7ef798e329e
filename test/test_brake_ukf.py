"""Tests of the generic scaled UKF (Lin 2010b, eq. 7-8)."""
from __future__ import annotations

import numpy as np
import pytest

from metro_atc.core.brake import checks
from metro_atc.core.brake import metro_car as mc
from metro_atc.core.brake.ukf import (UKF, BatchUKF, robust_cholesky, sigma_points,
                                      unscented_transform, ut_weights)


def test_paper_weights() -> None:
    """alpha 0.5, beta 2, kappa 3 - L: lambda = 0.25 * 3 - L, weights sum to one."""
    w = ut_weights(26)
    assert w.lam == pytest.approx(0.75 - 26.0)
    assert w.gamma == pytest.approx(np.sqrt(0.75))
    assert w.wm.sum() == pytest.approx(1.0)
    assert w.wc[0] == pytest.approx(w.wm[0] + 1.0 - 0.25 + 2.0)
    assert np.allclose(w.wm[1:], 0.5 / 0.75)


def test_sigma_points_reproduce_mean_and_covariance() -> None:
    """The weighted sigma points have exactly the prior mean and covariance."""
    rng = np.random.default_rng(1)
    a = rng.standard_normal((6, 6))
    p = a @ a.T + np.eye(6)
    x = rng.standard_normal(6)
    w = ut_weights(6)
    xs = sigma_points(x, robust_cholesky(p), w.gamma)
    m = w.wm @ xs
    d = xs - m
    assert np.allclose(m, x, atol=1e-12)
    assert np.allclose(d.T @ (w.wc[:, None] * d), p, atol=1e-10)


@pytest.mark.parametrize("seed,n", [(0, 5), (1, 8), (2, 3)])
def test_equals_linear_kalman_filter(seed: int, n: int) -> None:
    """On an affine model the UKF is the Kalman filter, to round-off."""
    dx, dp = checks.linear_equivalence(seed, n_steps=150, n=n)
    assert dx < 1e-10
    assert dp < 1e-10


def test_partial_update_equals_reduced_kf() -> None:
    """Updating with a subset of rows equals a KF with the reduced C and R."""
    rng = np.random.default_rng(3)
    s = checks.random_linear_system(rng, n=4, m=3)
    c, r = s["c"], s["r"]
    x0, p0 = rng.standard_normal(4), np.eye(4)

    def fx(xs: np.ndarray, u: np.ndarray, dt: float) -> np.ndarray:
        return xs

    def hx(xs: np.ndarray, u: np.ndarray) -> np.ndarray:
        return xs @ c.T

    ukf = UKF(fx, hx, x0, p0, np.zeros((4, 4)), r)
    rows = np.array([0, 2])
    z = rng.standard_normal(2)
    ukf.update(z, np.zeros(0), rows)
    cr, rr = c[rows], r[np.ix_(rows, rows)]
    k = p0 @ cr.T @ np.linalg.inv(cr @ p0 @ cr.T + rr)
    assert np.allclose(ukf.x, x0 + k @ (z - cr @ x0), atol=1e-12)
    assert np.allclose(ukf.p, p0 - k @ cr @ p0, atol=1e-12)


def test_polar_conversion_beats_linearisation() -> None:
    """Julier-Uhlmann polar example: UT moments are much closer to the closed form."""
    m = checks.polar_moments()
    err_ut = np.abs(m["ut_mean"] - m["exact_mean"]).max()
    err_lin = np.abs(m["lin_mean"] - m["exact_mean"]).max()
    assert err_ut < 1e-3
    assert err_ut < err_lin / 20.0
    cov_ut = np.linalg.norm(m["ut_cov"] - m["exact_cov"])
    cov_lin = np.linalg.norm(m["lin_cov"] - m["exact_cov"])
    assert cov_ut < cov_lin


def test_falling_body_ukf_beats_ekf() -> None:
    """Athans falling body: UKF altitude and speed errors are far below the EKF's."""
    r = checks.falling_body(n_runs=2, n_steps=30, seed=4)
    ukf, ekf = r["ukf"][10:].mean(axis=0), r["ekf"][10:].mean(axis=0)
    assert ukf[0] < 0.2 * ekf[0]
    assert ukf[1] < 0.2 * ekf[1]
    assert ukf[0] < 500.0          # ft, measurement std is 100 ft


def test_unscented_transform_of_quadratic() -> None:
    """y = x^2, x ~ N(m, s^2): exact mean m^2 + s^2; variance closer than linearised."""
    m, s2 = 1.5, 0.3
    mean, cov = unscented_transform(np.array([m]), np.array([[s2]]), lambda xs: xs ** 2)
    assert mean[0] == pytest.approx(m ** 2 + s2, rel=1e-12)
    exact = 4 * m ** 2 * s2 + 2 * s2 ** 2          # Var(x^2) for a Gaussian
    linearised = 4 * m ** 2 * s2
    assert abs(cov[0, 0] - exact) < 0.3 * abs(linearised - exact)


def test_robust_cholesky_fallbacks() -> None:
    """PD -> exact factor; semidefinite/indefinite -> a usable square root."""
    rng = np.random.default_rng(5)
    a = rng.standard_normal((5, 5))
    p = a @ a.T + np.eye(5)
    s = robust_cholesky(p)
    assert np.allclose(s, np.linalg.cholesky(p))
    v = rng.standard_normal((5, 1))
    semi = v @ v.T                               # rank 1
    s2 = robust_cholesky(semi)
    assert np.allclose(s2 @ s2.T, semi, atol=1e-6)
    indef = np.diag([1.0, 2.0, -1e-3, 3.0, 4.0])
    s3 = robust_cholesky(indef)
    assert np.isfinite(s3).all()
    assert np.allclose(s3 @ s3.T, np.diag([1.0, 2.0, 0.0, 3.0, 4.0]), atol=1e-6)


def test_batch_equals_single() -> None:
    """BatchUKF runs the same filter for each member (nonlinear model)."""
    rng = np.random.default_rng(6)

    def fx(xs: np.ndarray, u: np.ndarray, dt: float) -> np.ndarray:
        out = xs.copy()
        out[..., 0] = xs[..., 0] + dt * xs[..., 1]
        out[..., 1] = xs[..., 1] - dt * np.sin(xs[..., 0]) + dt * u[..., 0:1]
        return out

    def hx(xs: np.ndarray, u: np.ndarray) -> np.ndarray:
        return np.stack((np.sin(xs[..., 0]), xs[..., 1] ** 2), axis=-1)

    q, r = np.diag([1e-4, 1e-3]), np.diag([0.01, 0.02])
    x0 = rng.standard_normal((3, 2))
    p0 = np.stack([np.eye(2) * (k + 1) * 0.1 for k in range(3)])
    singles = [UKF(fx, hx, x0[k], p0[k], q, r) for k in range(3)]
    batch = BatchUKF(fx, hx, x0, p0, q, r)
    for _ in range(40):
        u = rng.standard_normal((3, 1))
        z = rng.standard_normal((3, 2))
        batch.predict(u, 0.05)
        batch.update(z, u)
        for k, f in enumerate(singles):
            f.predict(u[k], 0.05)
            f.update(z[k], u[k])
    for k, f in enumerate(singles):
        assert np.allclose(batch.x[k], f.x, atol=1e-10)
        assert np.allclose(batch.p[k], f.p, atol=1e-10)


def test_covariance_positive_definite_long_run() -> None:
    """Metro observer, 3000 steps incl. predict-only stretches: P stays symmetric PD."""
    p = mc.MetroCarParams()
    ukf = mc.make_metro_ukf(p, 0.02, 20.0)
    rng = np.random.default_rng(7)
    v = 20.0
    caps = mc.metro_variance_caps()
    min_eig = np.inf
    for k in range(3000):
        fc = 15000.0 if (k // 500) % 2 else 0.0
        u = np.r_[np.full(4, fc), np.zeros(4), p.mass]
        a = -2 * 0.35 * p.r_b * fc * 4 / (p.mass * p.r_w)
        v = max(v + 0.02 * a, 5.0) if v > 5.0 else 20.0
        z = np.r_[np.full(4, v / p.r_w) + 0.05 * rng.standard_normal(4),
                  a + 0.03 * rng.standard_normal(), v + 0.05 * rng.standard_normal()]
        ukf.predict(u, 0.02)
        if not (1000 <= k < 1400):              # 8 s without measurements
            ukf.update(z, u)
        assert np.array_equal(ukf.p, ukf.p.T)
        if k % 50 == 0:
            # scale-free check: eigenvalues of the correlation matrix (P spans 1e-6..1e12)
            d = 1.0 / np.sqrt(np.diag(ukf.p))
            e = np.linalg.eigvalsh(ukf.p * d[:, None] * d[None, :])
            min_eig = min(min_eig, float(e.min()))
            assert e.min() > 1e-9
            np.linalg.cholesky(ukf.p)
            assert (np.diag(ukf.p) <= caps * (1 + 1e-9)).all()
    assert np.isfinite(ukf.x).all()
    assert min_eig > 0.0
