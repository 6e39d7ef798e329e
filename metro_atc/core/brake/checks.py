"""Verification problems for the UKF with known answers.

* :func:`linear_equivalence` runs the UKF (Lin 2010b, eq. 7-8, alpha 0.5, beta 2,
  kappa 3 - L) and a textbook Kalman filter on a random stable linear system; for
  affine models the unscented transform is exact, so both must agree to round-off.
* :func:`polar_moments` is the classic polar-to-Cartesian conversion (Julier &
  Uhlmann): the true mean and covariance of ``(r cos t, r sin t)`` for independent
  Gaussian ``r, t`` are known in closed form; the UT must beat linearisation.
* :func:`falling_body` is the vertically falling body with unknown ballistic
  coefficient tracked by range measurements (Athans, Wishner & Bertolini 1968, used
  by Julier & Uhlmann 2004); UKF and EKF (central-difference Jacobians) are compared
  by Monte-Carlo error.  Units of that problem are feet and seconds, as published.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from metro_atc.core.brake.ukf import UKF, LinearKF, unscented_transform, ut_weights

FloatArray = np.ndarray


def random_linear_system(rng: np.random.Generator, n: int = 5, m: int = 3, nu: int = 2
                         ) -> dict[str, FloatArray]:
    """A random stable discrete linear system ``(A, B, C, D, Q, R)``."""
    a = rng.standard_normal((n, n))
    a *= 0.95 / max(abs(np.linalg.eigvals(a)))
    b = rng.standard_normal((n, nu))
    c = rng.standard_normal((m, n))
    d = rng.standard_normal((m, nu))
    lq = rng.standard_normal((n, n)) * 0.1
    lr = rng.standard_normal((m, m)) * 0.2
    return {"a": a, "b": b, "c": c, "d": d, "q": lq @ lq.T + 1e-3 * np.eye(n),
            "r": lr @ lr.T + 1e-2 * np.eye(m)}


def linear_equivalence(seed: int = 0, n_steps: int = 200, n: int = 5
                       ) -> tuple[float, float]:
    """Max |x_ukf - x_kf| and max |P_ukf - P_kf| over a run on a random linear system.

    Returns:
        (max state difference, max covariance difference), both relative to the
        magnitude of the KF quantities (dimensionless).
    """
    rng = np.random.default_rng(seed)
    s = random_linear_system(rng, n=n)
    a, b, c, d = s["a"], s["b"], s["c"], s["d"]
    nu = b.shape[1]
    x0 = rng.standard_normal(n)
    p0 = np.eye(n) * 2.0

    def fx(xs: FloatArray, u: FloatArray, dt: float) -> FloatArray:
        return np.asarray(xs @ a.T + b @ u)

    def hx(xs: FloatArray, u: FloatArray) -> FloatArray:
        return np.asarray(xs @ c.T + d @ u)

    ukf = UKF(fx, hx, x0, p0, s["q"], s["r"])
    kf = LinearKF(a, b, c, d, x0, p0, s["q"], s["r"])
    x_true = x0 + rng.standard_normal(n)
    dx = dp = 0.0
    lq = np.linalg.cholesky(s["q"])
    lr = np.linalg.cholesky(s["r"])
    for _ in range(n_steps):
        u = np.asarray(rng.standard_normal(nu))
        x_true = a @ x_true + b @ u + lq @ rng.standard_normal(n)
        z = c @ x_true + d @ u + lr @ rng.standard_normal(c.shape[0])
        ukf.predict(u, 1.0)
        kf.predict(u)
        ukf.update(z, u)
        kf.update(z, u)
        dx = max(dx, float(np.max(np.abs(ukf.x - kf.x)) / (1.0 + np.max(np.abs(kf.x)))))
        dp = max(dp, float(np.max(np.abs(ukf.p - kf.p)) / (1.0 + np.max(np.abs(kf.p)))))
    return dx, dp


def polar_moments(r_mean: float = 1.0, r_std: float = 0.02, t_mean: float = np.pi / 2,
                  t_std: float = np.radians(15.0)) -> dict[str, FloatArray]:
    """Exact, UT and linearised moments of ``y = (r cos t, r sin t)``.

    Exact: ``E[cos t] = cos(mu) e^{-s^2/2}``, ``E[cos^2 t] = (1 + cos(2 mu) e^{-2 s^2})/2``
    etc.; r and t independent.

    Returns:
        dict with ``exact_mean``, ``exact_cov``, ``ut_mean``, ``ut_cov``, ``lin_mean``,
        ``lin_cov``.
    """
    m, s2 = t_mean, t_std ** 2
    er, er2 = r_mean, r_mean ** 2 + r_std ** 2
    ec, es = np.cos(m) * np.exp(-s2 / 2), np.sin(m) * np.exp(-s2 / 2)
    ec2 = 0.5 * (1 + np.cos(2 * m) * np.exp(-2 * s2))
    es2 = 0.5 * (1 - np.cos(2 * m) * np.exp(-2 * s2))
    ecs = 0.5 * np.sin(2 * m) * np.exp(-2 * s2)
    mean = np.array([er * ec, er * es])
    cov = np.array([[er2 * ec2 - mean[0] ** 2, er2 * ecs - mean[0] * mean[1]],
                    [er2 * ecs - mean[0] * mean[1], er2 * es2 - mean[1] ** 2]])
    x = np.array([r_mean, t_mean])
    p = np.diag([r_std ** 2, t_std ** 2])

    def fn(xs: FloatArray) -> FloatArray:
        return np.stack((xs[:, 0] * np.cos(xs[:, 1]), xs[:, 0] * np.sin(xs[:, 1])), axis=1)

    ut_mean, ut_cov = unscented_transform(x, p, fn, ut_weights(2))
    jac = np.array([[np.cos(m), -r_mean * np.sin(m)], [np.sin(m), r_mean * np.cos(m)]])
    lin_mean = fn(x[None, :])[0]
    return {"exact_mean": mean, "exact_cov": cov, "ut_mean": ut_mean, "ut_cov": ut_cov,
            "lin_mean": lin_mean, "lin_cov": jac @ p @ jac.T}


@dataclass(frozen=True)
class FallingBody:
    """Athans-Wishner-Bertolini falling body (feet, seconds)."""

    gamma: float = 5e-5
    """Air-density decay constant [1/ft]."""
    m_dist: float = 1e5
    """Horizontal distance of the radar [ft]."""
    h_alt: float = 1e5
    """Altitude of the radar [ft]."""
    r_var: float = 1e4
    """Range measurement variance [ft^2]."""
    dt: float = 1.0
    """Measurement period [s]."""
    n_sub: int = 16
    """RK4 substeps per period."""

    def deriv(self, x: FloatArray) -> FloatArray:
        """Continuous dynamics for rows ``[altitude, speed (down), ballistic coef]``."""
        d = np.empty_like(x)
        d[..., 0] = -x[..., 1]
        d[..., 1] = -np.exp(-self.gamma * x[..., 0]) * x[..., 1] ** 2 * x[..., 2]
        d[..., 2] = 0.0
        return d

    def step(self, x: FloatArray) -> FloatArray:
        """Propagate one measurement period with RK4."""
        h = self.dt / self.n_sub
        for _ in range(self.n_sub):
            k1 = self.deriv(x)
            k2 = self.deriv(x + 0.5 * h * k1)
            k3 = self.deriv(x + 0.5 * h * k2)
            k4 = self.deriv(x + h * k3)
            x = x + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
        return x

    def range_(self, x: FloatArray) -> FloatArray:
        """Radar range [ft]."""
        return np.sqrt(self.m_dist ** 2 + (x[..., 0] - self.h_alt) ** 2)


def falling_body(n_runs: int = 20, n_steps: int = 60, seed: int = 0) -> dict[str, FloatArray]:
    """Monte-Carlo mean absolute errors of UKF and EKF on the falling-body problem.

    Returns:
        dict with ``ukf`` and ``ekf`` arrays (n_steps, 3) of mean absolute errors of
        altitude [ft], speed [ft/s] and ballistic coefficient [1/ft].
    """
    fb = FallingBody()
    rng = np.random.default_rng(seed)
    x_true0 = np.array([3e5, 2e4, 1e-3])
    x_hat0 = np.array([3e5, 2e4, 3e-5])
    p0 = np.diag([1e6, 4e6, 1e-4])
    q = np.diag([1e-8, 1e-8, 1e-14])
    r = np.array([[fb.r_var]])
    err_u = np.zeros((n_steps, 3))
    err_e = np.zeros((n_steps, 3))

    def fx(xs: FloatArray, u: FloatArray, dt: float) -> FloatArray:
        return fb.step(xs)

    def hx(xs: FloatArray, u: FloatArray) -> FloatArray:
        return np.asarray(fb.range_(xs))[..., None]

    u0 = np.zeros(0)
    for _ in range(n_runs):
        ukf = UKF(fx, hx, x_hat0, p0, q, r)
        xe, pe = x_hat0.copy(), p0.copy()
        xt = x_true0.copy()
        for k in range(n_steps):
            xt = fb.step(xt)
            z = fb.range_(xt) + np.sqrt(fb.r_var) * rng.standard_normal()
            ukf.predict(u0, fb.dt)
            ukf.update(np.array([z]), u0)
            # EKF with central-difference Jacobians
            hstep = np.maximum(np.abs(xe) * 1e-6, 1e-12)
            pts = np.concatenate((xe + np.diag(hstep), xe - np.diag(hstep)))
            fp = fb.step(pts)
            jf = ((fp[:3] - fp[3:]) / (2 * hstep)).T
            xe = fb.step(xe[None, :])[0]
            pe = jf @ pe @ jf.T + q
            hp = fb.range_(xe + np.diag(np.maximum(np.abs(xe) * 1e-6, 1e-12)))
            hm = fb.range_(xe - np.diag(np.maximum(np.abs(xe) * 1e-6, 1e-12)))
            jh = ((hp - hm) / (2 * np.maximum(np.abs(xe) * 1e-6, 1e-12)))[None, :]
            s = jh @ pe @ jh.T + r
            kg = pe @ jh.T / s
            xe = xe + (kg * (z - fb.range_(xe))).ravel()
            pe = (np.eye(3) - kg @ jh) @ pe
            pe = 0.5 * (pe + pe.T)
            err_u[k] += np.abs(ukf.x - xt) / n_runs
            err_e[k] += np.abs(xe - xt) / n_runs
    return {"ukf": err_u, "ekf": err_e}
