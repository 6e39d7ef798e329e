"""Compiled (numba) twin of the metro observer's UKF step (Lin 2010b, eq. 7-8, eq. 4, 9, 10).

:class:`MetroUKF` is the :class:`~metro_atc.core.brake.ukf.UKF` that
:func:`metro_atc.core.brake.metro_car.make_metro_ukf` builds, with :meth:`UKF.predict` and
:meth:`UKF.update` done by the loops below instead of ~25 numpy calls each (19 states,
39 sigma points: numpy's per-call overhead is most of the numpy path's time).  The
arithmetic is the numpy path's, element by element: the same sigma points
``x +- gamma S_i`` from the lower Cholesky factor ``S`` of ``P`` (Lin 2010b, eq. 7), the same
Euler transition of :func:`~metro_atc.core.brake.metro_car.make_metro_fx` (a linear map plus
the pad torque ``2 mu_b R_b F_c tanh(w / w_eps)`` of eq. 4 and the running resistance), the
same measurement :func:`~metro_atc.core.brake.metro_car.make_metro_hx` (eq. 8), weighted
means and covariances, the symmetrised covariance, the variance caps, and the Kalman gain
from the Cholesky factor of the innovation covariance.  Sums run in another order than
BLAS's, so the two paths agree to round-off, not bit for bit
(``test/test_brake_kernel.py``: every estimate within 1e-9 relative on recorded and generated
sample streams, every level the same).

Anything unusual goes back to the numpy path for that step: a covariance whose plain
Cholesky factorisation fails (the numpy path's jitter / eigenvalue fallbacks), or a result
that is not finite (its rejection rules).  Compiled on first use and cached on disk
(``cache=True``): ``scripts/install.sh`` compiles them after each build
(:func:`metro_atc.core.brake.metro_car.precompile_metro_kernels`), so a node only loads
them (~0.3 s of CPU, against ~6 s to compile).  The running resistance is
:func:`metro_atc.core.laws.davis_odd`; ``NUMBA_DISABLE_JIT=1`` runs the same source
uncompiled (debugging).
"""

from __future__ import annotations

import math
from typing import Callable, Optional

import numpy as np
from numba import njit
from numpy.typing import NDArray

from metro_atc.core import laws
from metro_atc.core.brake.ukf import UKF

FloatArray = NDArray[np.float64]


@njit(cache=True, error_model="numpy")
def _cholesky(p: FloatArray, c: FloatArray) -> bool:
    """Lower Cholesky factor of ``p`` into ``c``; False if ``p`` is not positive definite."""
    n = p.shape[0]
    for j in range(n):
        s = p[j, j]
        for k in range(j):
            s -= c[j, k] * c[j, k]
        if not s > 0.0:
            return False
        d = math.sqrt(s)
        c[j, j] = d
        for i in range(j + 1, n):
            t = p[i, j]
            for k in range(j):
                t -= c[i, k] * c[j, k]
            c[i, j] = t / d
        for i in range(j):
            c[i, j] = 0.0
    return True


@njit(cache=True, error_model="numpy")
def _sigma(x: FloatArray, c: FloatArray, gamma: float, xs: FloatArray) -> None:
    """Sigma points ``[x, x + gamma S_i, x - gamma S_i]`` (rows) of the factor ``c``."""
    n = x.shape[0]
    for k in range(n):
        xs[0, k] = x[k]
    for i in range(n):
        for k in range(n):
            d = gamma * c[k, i]
            xs[1 + i, k] = d + x[k]
            xs[1 + n + i, k] = -d + x[k]


@njit(cache=True, error_model="numpy")
def predict_kernel(x: FloatArray, p: FloatArray, u: FloatArray, dt: float, a: FloatArray,
                   q: FloatArray, cap: FloatArray, wm: FloatArray, wc: FloatArray,
                   gamma: float, k: FloatArray) -> tuple[FloatArray, FloatArray, int]:
    """One prediction (Lin 2010b, eq. 7) of the metro observer.

    ``a``: the linear part's transpose (:func:`metro_linear_part` at ``dt``, transposed);
    ``k`` = (k_w = 2 R_b / J, 1 / w_eps, J, Davis a, b, c).  Returns (x^-, P^-, code):
    code 0 done, 1 P not positive definite, 2 non-finite result (caller: numpy path).
    """
    n = x.shape[0]
    ns = 2 * n + 1
    c = np.zeros((n, n))
    if not _cholesky(p, c):
        return x, p, 1
    xs = np.empty((ns, n))
    _sigma(x, c, gamma, xs)
    k_w, inv_eps, j_w, da, db, dc = k[0], k[1], k[2], k[3], k[4], k[5]
    ys = np.empty((ns, n))
    for s in range(ns):
        for j in range(n):
            acc = 0.0
            for i in range(n):
                acc += xs[s, i] * a[i, j]
            ys[s, j] = acc
        v = xs[s, 0]
        f = xs[s, 7] + xs[s, 10] + xs[s, 13] + xs[s, 16]
        ac = f / u[8]
        ac -= laws.davis_odd(v, da, db, dc)
        ys[s, 0] += dt * ac
        for j in range(4):
            br = math.tanh(xs[s, 1 + j] * inv_eps)
            br *= xs[s, 5]
            br *= u[j]
            br *= -dt * k_w
            br += (dt / j_w) * u[4 + j]
            ys[s, 1 + j] += br
    xm = np.zeros(n)
    for s in range(ns):
        for j in range(n):
            xm[j] += wm[s] * ys[s, j]
    pn = np.zeros((n, n))
    for s in range(ns):
        for i in range(n):
            di = ys[s, i] - xm[i]
            w = wc[s] * di
            for j in range(n):
                pn[i, j] += w * (ys[s, j] - xm[j])
    ok = True
    for i in range(n):
        if not math.isfinite(xm[i]):
            ok = False
        for j in range(n):
            pn[i, j] += q[i, j]
    for i in range(n):
        for j in range(i, n):
            m = 0.5 * (pn[i, j] + pn[j, i])
            pn[i, j] = m
            pn[j, i] = m
            if not math.isfinite(m):
                ok = False
    if not ok:
        return x, p, 2
    capped = False
    for i in range(n):
        if not pn[i, i] <= cap[i]:
            capped = True
    if capped:
        sc = np.empty(n)
        for i in range(n):
            sc[i] = math.sqrt(min(1.0, cap[i] / max(pn[i, i], 1e-300)))
        for i in range(n):
            for j in range(n):
                pn[i, j] = pn[i, j] * (sc[i] * sc[j])
    return xm, pn, 0


@njit(cache=True, error_model="numpy")
def update_kernel(x: FloatArray, p: FloatArray, z: FloatArray, rows: NDArray[np.int64],
                  u: FloatArray, r: FloatArray, wm: FloatArray, wc: FloatArray, gamma: float,
                  k: FloatArray) -> tuple[FloatArray, FloatArray, int]:
    """One measurement update (Lin 2010b, eq. 8) with the measured rows ``rows`` of ``z``.

    ``k`` as in :func:`predict_kernel`.  Returns (x, P, code): code 0 applied, 1 P or S not
    positive definite, 2 non-finite result (caller: numpy path).
    """
    n = x.shape[0]
    ns = 2 * n + 1
    m = rows.shape[0]
    c = np.zeros((n, n))
    if not _cholesky(p, c):
        return x, p, 1
    xs = np.empty((ns, n))
    _sigma(x, c, gamma, xs)
    da, db, dc = k[3], k[4], k[5]
    yfull = np.empty(6)
    ys = np.empty((ns, m))
    for s in range(ns):
        v = xs[s, 0]
        yfull[0] = xs[s, 1]
        yfull[1] = xs[s, 2]
        yfull[2] = xs[s, 3]
        yfull[3] = xs[s, 4]
        yfull[4] = (xs[s, 7] + xs[s, 10] + xs[s, 13] + xs[s, 16]) / u[8]
        yfull[4] -= laws.davis_odd(v, da, db, dc)
        yfull[5] = v
        for j in range(m):
            ys[s, j] = yfull[rows[j]]
    ym = np.zeros(m)
    for s in range(ns):
        for j in range(m):
            ym[j] += wm[s] * ys[s, j]
    sm = np.zeros((m, m))
    pxy = np.zeros((n, m))
    for s in range(ns):
        for j in range(m):
            wdy = wc[s] * (ys[s, j] - ym[j])
            for i in range(m):
                sm[i, j] += (ys[s, i] - ym[i]) * wdy
            for i in range(n):  # the deviation gamma S_i itself (not (x + d) - x)
                if s == 0:
                    d = 0.0
                elif s <= n:
                    d = gamma * c[i, s - 1]
                else:
                    d = -(gamma * c[i, s - 1 - n])
                pxy[i, j] += d * wdy
    for i in range(m):
        for j in range(m):
            sm[i, j] += r[rows[i], rows[j]]
    cs = np.zeros((m, m))
    if not _cholesky(sm, cs):
        return x, p, 1
    # K^T = S^-1 Pxy^T by forward and back substitution with the factor of S
    kt = np.empty((m, n))
    for col in range(n):
        for i in range(m):
            t = pxy[col, i]
            for j in range(i):
                t -= cs[i, j] * kt[j, col]
            kt[i, col] = t / cs[i, i]
        for i in range(m - 1, -1, -1):
            t = kt[i, col]
            for j in range(i + 1, m):
                t -= cs[j, i] * kt[j, col]
            kt[i, col] = t / cs[i, i]
    xn = x.copy()
    for i in range(n):
        acc = 0.0
        for j in range(m):
            acc += kt[j, i] * (z[j] - ym[j])
        xn[i] += acc
    pn = np.empty((n, n))
    for i in range(n):
        for j in range(n):
            acc = 0.0
            for h in range(m):
                acc += kt[h, i] * pxy[j, h]
            pn[i, j] = p[i, j] - acc
    for i in range(n):
        if not math.isfinite(xn[i]):
            return x, p, 2
        for j in range(i, n):
            mm = 0.5 * (pn[i, j] + pn[j, i])
            if not math.isfinite(mm):
                return x, p, 2
            pn[i, j] = mm
            pn[j, i] = mm
    return xn, pn, 0


class MetroUKF(UKF):
    """The metro observer's UKF with the compiled step (see module docstring).

    Args:
        base: the numpy-path filter (:func:`make_metro_ukf`'s arguments, weights, caps).
        linear_part: ``dt -> A`` (:func:`metro_linear_part` of the car).
        dt_nominal: the sensor period [s] (the transition's first cached step).
        consts: (k_w = 2 R_b / J, 1 / w_eps, J, Davis a, b, c).
    """

    def __init__(self, base: UKF, linear_part: Callable[[float], FloatArray],
                 dt_nominal: float, consts: FloatArray) -> None:
        """Take over ``base``'s state, models and weights."""
        self.__dict__.update(base.__dict__)
        self._linear_part = linear_part
        self._a_t: dict[float, FloatArray] = {
            dt_nominal: np.ascontiguousarray(linear_part(dt_nominal).T)}
        self._k = np.asarray(consts, dtype=float)
        self._all_rows = np.arange(self.r.shape[0], dtype=np.int64)
        self._cap: FloatArray = (np.full(self.x.size, np.inf) if self.p_max_diag is None
                                 else self.p_max_diag)
        self.kernel_steps = 0
        """Steps done by the kernels (the others went through the numpy path)."""

    def _a(self, dt: float) -> FloatArray:
        a = self._a_t.get(dt)
        if a is None:  # the numpy path's key: time stamps jitter by round-off
            key = round(dt * 1e6) * 1e-6
            a = self._a_t.get(key)
            if a is None:
                a = np.ascontiguousarray(self._linear_part(key).T)
                if len(self._a_t) < 256:
                    self._a_t[key] = a
        return a

    def predict(self, u: FloatArray, dt: float) -> None:
        """Prediction (Lin 2010b, eq. 7) by :func:`predict_kernel` (numpy path if it declines)."""
        q = self._q(dt)
        x, p, code = predict_kernel(self.x, self.p, np.asarray(u, dtype=float), float(dt),
                                    self._a(dt), q, self._cap, self._wm, self.weights.wc,
                                    self.weights.gamma, self._k)
        if code:
            super().predict(u, dt)
            return
        self.kernel_steps += 1
        self.x = x
        self.p = p

    def update(self, z: FloatArray, u: FloatArray, rows: Optional[FloatArray] = None) -> bool:
        """Seed 000 eq. 8 (measurement) by :func:`update_kernel`, else the numpy path."""
        idx = self._all_rows if rows is None else np.asarray(rows, dtype=np.int64)
        x, p, code = update_kernel(self.x, self.p, np.asarray(z, dtype=float), idx,
                                   np.asarray(u, dtype=float), self.r, self._wm,
                                   self.weights.wc, self.weights.gamma, self._k)
        if code:
            return super().update(z, u, rows)
        self.kernel_steps += 1
        self.x = x
        self.p = p
        return True
