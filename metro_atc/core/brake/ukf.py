"""Generic scaled unscented Kalman filter (Lin 2010b, eq. 7-8).

The diagnostic observer of the brake-by-wire paper is "essentially a UKF" with a
prediction procedure for the nonlinear stochastic state equation
``x_k = f(x_{k-1}, u_{k-1}) + eta_k`` (Lin 2010b, eq. 7) and a measurement procedure
for ``y_k = h(x_k) + n_k`` (Lin 2010b, eq. 8); both noises are additive.  The scaled
unscented transform uses the paper's parameters ``alpha = 0.5``, ``beta = 2``,
``kappa = 3 - L`` (L = state dimension).

Implementation notes
--------------------
* Sigma points are propagated in one vectorised call: ``f`` and ``h`` receive an
  array of shape ``(2L+1, L)`` and return ``(2L+1, L)`` / ``(2L+1, m)``.
* After the prediction the sigma points are redrawn from ``(x^-, P^-)`` (the
  additive-noise form); with this choice the filter equals the linear Kalman
  filter exactly when ``f`` and ``h`` are affine (tested to round-off).
* With ``kappa = 3 - L`` and large L the centre weight is strongly negative, so a
  covariance computed from strongly nonlinear propagations may lose definiteness.
  Every covariance is symmetrised, and the square root uses a Cholesky
  factorisation with a jitter fallback (growing diagonal loading) and, as a last
  resort, an eigenvalue-clipped square root.  The filter never returns NaN: an
  update that produces non-finite numbers is rejected (state and covariance are
  kept from before the update).
* LAPACK ``dpotrf``/``dpotrs`` are called directly to keep the per-step Python
  overhead low (the metro observer must reach >= 10 000 steps/s on one core).

All quantities are in the caller's SI units.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Optional

import numpy as np
from scipy.linalg import lapack

FloatArray = np.ndarray
TransitionFn = Callable[[FloatArray, FloatArray, float], FloatArray]
MeasurementFn = Callable[[FloatArray, FloatArray], FloatArray]


@dataclass(frozen=True)
class UTWeights:
    """Weights of the scaled unscented transform.

    Attributes:
        wm: mean weights, shape (2L+1,).
        wc: covariance weights, shape (2L+1,).
        gamma: sigma-point spread sqrt(L + lambda) (dimensionless).
        lam: scaling parameter lambda = alpha^2 (L + kappa) - L.
    """

    wm: FloatArray
    wc: FloatArray
    gamma: float
    lam: float


def ut_weights(n: int, alpha: float = 0.5, beta: float = 2.0,
               kappa: Optional[float] = None) -> UTWeights:
    """Return the scaled-UT weights (Lin 2010b: alpha 0.5, beta 2, kappa 3-L).

    Args:
        n: state dimension L.
        alpha: spread parameter (dimensionless).
        beta: prior-knowledge parameter (2 is optimal for Gaussians).
        kappa: secondary scaling; ``None`` means the paper's ``3 - L``.

    Returns:
        The weights; ``sum(wm) == 1``.
    """
    if n < 1:
        raise ValueError("state dimension must be >= 1")
    k = 3.0 - n if kappa is None else float(kappa)
    lam = alpha * alpha * (n + k) - n
    if n + lam <= 0.0:
        raise ValueError("alpha/kappa give a non-positive L + lambda")
    wm = np.full(2 * n + 1, 0.5 / (n + lam))
    wc = wm.copy()
    wm[0] = lam / (n + lam)
    wc[0] = wm[0] + (1.0 - alpha * alpha + beta)
    return UTWeights(wm=wm, wc=wc, gamma=float(np.sqrt(n + lam)), lam=float(lam))


def symmetrize(p: FloatArray) -> FloatArray:
    """Return ``(P + P^T) / 2``."""
    return 0.5 * (p + p.T)


def robust_cholesky(p: FloatArray, max_tries: int = 4) -> FloatArray:
    """Lower Cholesky factor of a (nearly) positive-definite matrix.

    Tries plain Cholesky, then adds a growing diagonal jitter
    ``eps * max(mean(diag), 1e-12)`` with ``eps = 1e-12, 1e-10, ...`` (``max_tries``
    steps, i.e. at most 1e-6 relative); if that fails (a clearly indefinite matrix),
    returns the square root of the eigenvalue-clipped matrix (not triangular, but
    ``S S^T`` equals the clipped matrix, which is all the sigma points need).

    Args:
        p: symmetric matrix (n, n).
        max_tries: number of jitter escalations.

    Returns:
        S with ``S @ S.T`` approximately ``p`` (exactly ``p`` when it is PD).
    """
    c, info = lapack.dpotrf(p, lower=1, clean=1)
    if info == 0:
        return np.asarray(c)
    scale = max(float(np.mean(np.abs(np.diag(p)))), 1e-12)
    eye = np.eye(p.shape[0])
    jitter = 1e-12 * scale
    for _ in range(max_tries):
        c, info = lapack.dpotrf(p + jitter * eye, lower=1, clean=1)
        if info == 0:
            return np.asarray(c)
        jitter *= 100.0
    w, v = np.linalg.eigh(symmetrize(p))
    w = np.clip(w, 1e-12 * scale, None)
    return np.asarray(v * np.sqrt(w))


def sigma_points(x: FloatArray, sqrt_p: FloatArray, gamma: float) -> FloatArray:
    """Sigma points ``[x, x + gamma S_i, x - gamma S_i]`` as rows, shape (2L+1, L)."""
    d = gamma * sqrt_p.T
    return np.concatenate((x[None, :], x + d, x - d), axis=0)


def unscented_transform(x: FloatArray, p: FloatArray, fn: Callable[[FloatArray], FloatArray],
                        weights: Optional[UTWeights] = None) -> tuple[FloatArray, FloatArray]:
    """Propagate a Gaussian ``N(x, P)`` through ``fn`` with the scaled UT.

    Args:
        x: mean (L,).
        p: covariance (L, L).
        fn: vectorised map, rows in -> rows out.
        weights: UT weights; defaults to the paper's parameters.

    Returns:
        (mean, covariance) of the transformed variable.
    """
    w = weights if weights is not None else ut_weights(x.size)
    xs = sigma_points(x, robust_cholesky(p), w.gamma)
    ys = fn(xs)
    mean = w.wm @ ys
    dev = ys - mean
    return mean, symmetrize(dev.T @ (w.wc[:, None] * dev))


class UKF:
    """Scaled unscented Kalman filter with additive noises (Lin 2010b, eq. 7-8).

    Args:
        fx: transition ``f(X, u, dt) -> X'`` vectorised over sigma-point rows.
        hx: measurement ``h(X, u) -> Y`` vectorised over rows (m outputs).
        x0: initial mean (L,).
        p0: initial covariance (L, L).
        q: process-noise covariance per step (L, L) or a callable ``q(dt)``.
        r: measurement-noise covariance (m, m).
        alpha, beta, kappa: UT parameters (paper: 0.5, 2, 3 - L).
        p_max_diag: optional cap on the variances (L,); a variance above its cap is
            scaled down together with its correlations (``P <- D P D``), which keeps P
            positive definite and bounds it during long predict-only stretches.
    """

    def __init__(self, fx: TransitionFn, hx: MeasurementFn, x0: FloatArray, p0: FloatArray,
                 q: FloatArray | Callable[[float], FloatArray], r: FloatArray,
                 alpha: float = 0.5, beta: float = 2.0, kappa: Optional[float] = None,
                 p_max_diag: Optional[FloatArray] = None) -> None:
        """Create the filter (see class docstring)."""
        self.fx = fx
        self.hx = hx
        self.x = np.array(x0, dtype=float)
        self.p = symmetrize(np.array(p0, dtype=float))
        self.q = q
        self.r = np.array(r, dtype=float)
        n = self.x.size
        self.weights = ut_weights(n, alpha, beta, kappa)
        self._wm = self.weights.wm
        self._wc_col = self.weights.wc[:, None]
        # sigma-point selector: rows [0; gamma I; -gamma I]; deviations D = E @ S^T
        self._e = np.concatenate((np.zeros((1, n)), np.eye(n), -np.eye(n))) * self.weights.gamma
        self.p_max_diag = None if p_max_diag is None else np.asarray(p_max_diag, dtype=float)
        self.n_rejected = 0

    def restarted(self, x0: FloatArray, p0: FloatArray, symmetric: bool = False) -> "UKF":
        """A new filter at ``(x0, P0)`` with this one's models, noises, weights and caps.

        Equal to constructing a :class:`UKF` with the same arguments (the weights and the
        sigma-point selector depend on L and the UT parameters only), without recomputing
        them; this filter is not changed.  ``symmetric``: ``p0`` is already its own
        :func:`symmetrize` (copied as it is; a restart per 1 Hz heartbeat sample).
        """
        new = object.__new__(type(self))  # copy.copy's shallow copy, without its protocol
        new.__dict__.update(self.__dict__)
        new.x = np.array(x0, dtype=float)
        new.p = np.array(p0, dtype=float) if symmetric else symmetrize(np.array(p0, dtype=float))
        new.n_rejected = 0
        return new

    def _q(self, dt: float) -> FloatArray:
        q = self.q
        return q(dt) if callable(q) else q

    def _deviations(self) -> FloatArray:
        """Sigma-point deviations ``gamma * (0, +S_i, -S_i)`` as rows (2L+1, L)."""
        c, info = lapack.dpotrf(self.p, lower=1, clean=1)
        if info != 0:
            c = robust_cholesky(0.5 * (self.p + self.p.T))
        return self._e @ c.T

    def _limit(self, p: FloatArray) -> FloatArray:
        cap = self.p_max_diag
        if cap is None:
            return p
        d = np.diagonal(p)
        if (d <= cap).all():
            return p
        sc = np.sqrt(np.minimum(1.0, cap / np.maximum(d, 1e-300)))
        return p * (sc[:, None] * sc[None, :])

    def predict(self, u: FloatArray, dt: float) -> None:
        """Prediction procedure (Lin 2010b, eq. 7): x^- = E[f(x, u)], P^- = Cov + Q."""
        ys = self.fx(self._deviations() + self.x, u, dt)
        x = self._wm @ ys
        dev = ys - x
        p = dev.T @ (self._wc_col * dev)
        p += self._q(dt)
        p += p.T
        p *= 0.5
        if np.isfinite(x.sum() + p.sum()):
            self.x = x
            self.p = self._limit(p)
        else:  # keep the previous estimate, inflate its uncertainty
            self.n_rejected += 1
            self.p = self._limit(self.p + self._q(dt))

    def innovation(self, u: FloatArray, rows: Optional[FloatArray] = None
                   ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Predicted measurement, its covariance S and the cross covariance P_xy.

        Args:
            u: input vector passed to ``h``.
            rows: optional integer index of the measurement rows to use.

        Returns:
            (y_hat (m,), S (m, m), P_xy (L, m)).
        """
        d = self._deviations()
        ys = self.hx(d + self.x, u)
        r = self.r
        if rows is not None:
            ys = ys[:, rows]
            r = r[np.ix_(rows, rows)]
        y = self._wm @ ys
        dy = ys - y
        wdy = self._wc_col * dy
        s = dy.T @ wdy
        s += r
        pxy = d.T @ wdy
        return y, s, pxy

    def update(self, z: FloatArray, u: FloatArray, rows: Optional[FloatArray] = None) -> bool:
        """Measurement procedure (Lin 2010b, eq. 8) with measurement ``z``.

        Args:
            z: measurement vector (all m rows, or only ``rows`` if given).
            u: input vector passed to ``h``.
            rows: optional index of the measurement rows present in ``z``.

        Returns:
            True if the update was applied, False if it was rejected (non-finite).
        """
        y, s, pxy = self.innovation(u, rows)
        cs, info = lapack.dpotrf(s, lower=1, clean=1)
        if info != 0:
            cs = robust_cholesky(0.5 * (s + s.T))
            k = np.linalg.solve(cs @ cs.T, pxy.T).T
        else:
            kt, _ = lapack.dpotrs(cs, pxy.T, lower=1)
            k = kt.T
        x = self.x + k @ (np.asarray(z, dtype=float) - y)
        p = self.p - k @ pxy.T
        p += p.T
        p *= 0.5
        if not np.isfinite(x.sum() + p.sum()):
            self.n_rejected += 1
            return False
        self.x = x
        self.p = p
        return True


class LinearKF:
    """Reference linear Kalman filter ``x' = A x + B u + w``, ``y = C x + D u + v``.

    Used to check the UKF on linear systems (they must agree to round-off).
    """

    def __init__(self, a: FloatArray, b: FloatArray, c: FloatArray, d: FloatArray,
                 x0: FloatArray, p0: FloatArray, q: FloatArray, r: FloatArray) -> None:
        """Store the model matrices and the initial Gaussian."""
        self.a, self.b, self.c, self.d = a, b, c, d
        self.x = np.array(x0, dtype=float)
        self.p = np.array(p0, dtype=float)
        self.q, self.r = q, r

    def predict(self, u: FloatArray) -> None:
        """Time update."""
        self.x = self.a @ self.x + self.b @ u
        self.p = self.a @ self.p @ self.a.T + self.q

    def update(self, z: FloatArray, u: FloatArray) -> None:
        """Apply the measurement step in its textbook form (not Joseph)."""
        s = self.c @ self.p @ self.c.T + self.r
        k = np.linalg.solve(s, self.c @ self.p).T
        self.x = self.x + k @ (z - self.c @ self.x - self.d @ u)
        self.p = self.p - k @ s @ k.T
        self.p = 0.5 * (self.p + self.p.T)


def batch_cholesky(p: FloatArray) -> FloatArray:
    """Lower Cholesky factors of a stack of matrices (B, n, n), robust per matrix."""
    try:
        return np.asarray(np.linalg.cholesky(p))
    except np.linalg.LinAlgError:
        return np.stack([robust_cholesky(0.5 * (pi + pi.T)) for pi in p])


class BatchUKF:
    """``B`` independent scaled UKFs stepped in lockstep (same f, h, Q, R).

    Numerically the same filter as :class:`UKF` (Lin 2010b, eq. 7-8) applied to each
    batch member; used by the Monte-Carlo benchmark.  ``f(X, U, dt)`` receives sigma
    points (B, 2L+1, L) and inputs (B, n_u); ``h(X, U)`` likewise.

    Args:
        fx, hx: vectorised models (see :class:`UKF`).
        x0: initial means (B, L); p0: initial covariances (B, L, L).
        q: process noise (L, L); r: measurement noise (m, m).
        alpha, beta, kappa: UT parameters (paper: 0.5, 2, 3 - L).
    """

    def __init__(self, fx: TransitionFn, hx: MeasurementFn, x0: FloatArray, p0: FloatArray,
                 q: FloatArray, r: FloatArray, alpha: float = 0.5, beta: float = 2.0,
                 kappa: Optional[float] = None) -> None:
        """Create the batch (see class docstring)."""
        self.fx = fx
        self.hx = hx
        self.x = np.array(x0, dtype=float)
        self.p = np.array(p0, dtype=float)
        self.q = np.asarray(q, dtype=float)
        self.r = np.asarray(r, dtype=float)
        self.weights = ut_weights(self.x.shape[1], alpha, beta, kappa)
        self._wc = self.weights.wc[None, :, None]

    def _sigma(self) -> FloatArray:
        s = batch_cholesky(self.p)
        d = self.weights.gamma * np.swapaxes(s, 1, 2)
        xb = self.x[:, None, :]
        return np.concatenate((xb, xb + d, xb - d), axis=1)

    def predict(self, u: FloatArray, dt: float) -> None:
        """Prediction procedure (Lin 2010b, eq. 7) for every member."""
        ys = self.fx(self._sigma(), u, dt)
        x = np.einsum("n,bnl->bl", self.weights.wm, ys)
        dev = ys - x[:, None, :]
        p = np.swapaxes(dev, 1, 2) @ (self._wc * dev) + self.q
        self.x = x
        self.p = 0.5 * (p + np.swapaxes(p, 1, 2))

    def update(self, z: FloatArray, u: FloatArray) -> None:
        """Measurement procedure (Lin 2010b, eq. 8) with measurements ``z`` (B, m)."""
        xs = self._sigma()
        ys = self.hx(xs, u)
        y = np.einsum("n,bnm->bm", self.weights.wm, ys)
        dy = ys - y[:, None, :]
        wdy = self._wc * dy
        s = np.swapaxes(dy, 1, 2) @ wdy + self.r
        pxy = np.swapaxes(xs - self.x[:, None, :], 1, 2) @ wdy
        kt = np.linalg.solve(s, np.swapaxes(pxy, 1, 2))
        innov = (z - y)[:, :, None]
        x = self.x + (np.swapaxes(kt, 1, 2) @ innov)[:, :, 0]
        p = self.p - pxy @ kt
        ok = np.isfinite(x).all(axis=1) & np.isfinite(p).all(axis=(1, 2))
        self.x = np.where(ok[:, None], x, self.x)
        p = np.where(ok[:, None, None], p, self.p)
        self.p = 0.5 * (p + np.swapaxes(p, 1, 2))
