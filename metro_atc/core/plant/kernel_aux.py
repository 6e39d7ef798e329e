"""Compiled (numba) sensor samples of the instrumented cars (:class:`.fast.FastSensors`).

The normal draws are made by the caller with the sensors' own generator (one stream).
"""

from __future__ import annotations

from numba import njit

from .kernel import _mx


@njit(cache=True)
def sensor_block(idx, rw, slip0, slip1, clamp1, v0, v1, acc, ts, t0: float, t1: float, z,
                 noise, o4, o2):  # type: ignore[no-untyped-def]
    """Noisy samples into o4 = (omega, clamp) [2, s, train, 4], o2 = (accel, vref) [2, s, train].

    ``z`` is the step's standard-normal draw (omega, clamp, accel, vref blocks in that
    order); ``noise`` = (omega, clamp, accel, ref speed) standard deviations.
    """
    omega, clamp, accel, vref = o4[0], o4[1], o2[0], o2[1]
    ns, m = ts.shape[0], idx.shape[0]
    na = rw.shape[1]
    k = ns * m * na
    for c in range(m):
        i = idx[c]
        for a in range(na):  # truth of the axle at both ends of the step, then the samples
            om0 = (v0[i] * (1.0 - slip0[i, a])) / rw[i, a]
            dom = (v1[i] * (1.0 - slip1[i, a])) / rw[i, a] - om0
            cl = clamp1[i, a]
            for s in range(ns):
                frac = (ts[s] - t0) / (t1 - t0)
                j = (s * m + c) * na + a
                omega[s, c, a] = (om0 + frac * dom) + noise[0] * z[j]
                clamp[s, c, a] = _mx(cl + noise[1] * z[k + j], 0.0)
        dv = v1[i] - v0[i]
        for s in range(ns):
            frac = (ts[s] - t0) / (t1 - t0)
            accel[s, c] = acc[i] + noise[2] * z[2 * k + s * m + c]
            zv = z[2 * k + ns * m + s * m + c]
            vref[s, c] = (v0[i] + frac * dv) + noise[3] * zv
