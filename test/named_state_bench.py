"""Micro-bench: a kernel's run constants as numbered slots or as named state.

The plant kernels used to read their run constants from a float vector by index (``C_* =
range(N)``).  This compares, for the same per-train loop (12 constants, n trains), the CPU
time per call from Python of: the float vector with index constants, a ``namedtuple`` of
floats, a one-record numpy structured array (``c[0].name``), a numba ``jitclass`` instance
and the float vector viewed as the record inside the kernel (``c.view(REC)[0]``: what the
plant and ATO kernels do now); the compiled loop is the same for all five, the difference is
the argument's unboxing at each call (the plant calls its step kernel once per step)::

    python test/named_state_bench.py
"""

from __future__ import annotations

import time
from collections import namedtuple
from typing import Any

import numpy as np
from numba import float64, njit
from numba.experimental import jitclass

NAMES = ["x0", "inv_dx", "b_g", "t_r", "tsbi", "bs", "jerk", "davis_a", "davis_b", "davis_c",
         "dt", "tol"]
(C_X0, C_INV_DX, C_B_G, C_TR, C_TSBI, C_BS, C_JERK, C_DA, C_DB, C_DC, C_DT, C_TOL,
 N_CONST) = range(13)
VALS = np.array([0.0, 0.5, 1.0, 1.5, 2.0, 1.0, 0.25, 4000.0, 100.0, 10.0, 0.25, 0.3])


@njit
def k_slots(c, x, v, out):  # type: ignore[no-untyped-def]
    """The loop on a float vector read by index constants."""
    s = 0.0
    for i in range(x.shape[0]):
        a = c[C_B_G] * c[C_TR] + c[C_TR] * v[i]
        r = c[C_DA] + c[C_DB] * v[i] + c[C_DC] * v[i] * v[i]
        k = int((x[i] - c[C_X0]) * c[C_INV_DX])
        out[i] = a - r * c[C_DT] / c[C_BS] + k * c[C_TOL] + c[C_JERK] * c[C_TSBI]
        s += out[i]
    return s


@njit
def k_named(c, x, v, out):  # type: ignore[no-untyped-def]
    """The loop on anything with the named attributes (namedtuple, jitclass)."""
    s = 0.0
    for i in range(x.shape[0]):
        a = c.b_g * c.t_r + c.t_r * v[i]
        r = c.davis_a + c.davis_b * v[i] + c.davis_c * v[i] * v[i]
        k = int((x[i] - c.x0) * c.inv_dx)
        out[i] = a - r * c.dt / c.bs + k * c.tol + c.jerk * c.tsbi
        s += out[i]
    return s


@njit
def k_record(cr, x, v, out):  # type: ignore[no-untyped-def]
    """The loop on the first record of a structured array."""
    return k_named(cr[0], x, v, out)


Consts = namedtuple("Consts", NAMES)  # type: ignore[misc]
REC = np.dtype([(n, np.float64) for n in NAMES], align=True)


@njit
def k_view(c, x, v, out):  # type: ignore[no-untyped-def]
    """The loop on a float vector viewed as the record inside the kernel."""
    return k_named(c.view(REC)[0], x, v, out)


@jitclass([(n, float64) for n in NAMES])
class JitConsts:
    """The constants as a jitclass."""

    def __init__(self, vals):  # type: ignore[no-untyped-def]
        """Fill from a float vector in :data:`NAMES` order."""
        self.x0, self.inv_dx, self.b_g, self.t_r = vals[0], vals[1], vals[2], vals[3]
        self.tsbi, self.bs, self.jerk, self.davis_a = vals[4], vals[5], vals[6], vals[7]
        self.davis_b, self.davis_c, self.dt, self.tol = vals[8], vals[9], vals[10], vals[11]


def main() -> None:
    """Alternate the five forms 5 times; print min and median CPU time per call."""
    rng = np.random.default_rng(0)
    for n in (30, 3000):
        x, v, out = rng.uniform(0.0, 2e4, n), rng.uniform(0.0, 22.0, n), np.empty(n)
        forms: dict[str, tuple[Any, Any]] = {
            "slots": (k_slots, VALS.copy()),
            "namedtuple": (k_named, Consts(*VALS.tolist())),
            "record": (k_record, np.array([tuple(VALS)], dtype=REC)),
            "jitclass": (k_named, JitConsts(VALS)),
            "vector view": (k_view, VALS.copy()),
        }
        res = {name: k(c, x, v, out) for name, (k, c) in forms.items()}
        assert len(set(res.values())) == 1, res  # the same floats
        reps = 20000 if n == 30 else 2000
        times: dict[str, list[float]] = {name: [] for name in forms}
        for _ in range(5):
            for name, (k, c) in forms.items():
                t = time.process_time()
                for _ in range(reps):
                    k(c, x, v, out)
                times[name].append((time.process_time() - t) / reps * 1e6)
        for name, ts in times.items():
            ts.sort()
            print(f"n = {n:5d}  {name:11s} min {ts[0]:.2f} us, median {ts[2]:.2f} us per call")


if __name__ == "__main__":
    main()
