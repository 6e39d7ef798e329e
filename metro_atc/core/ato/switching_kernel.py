"""Compiled (numba) simulation of traction-then-coast strategies (ECTP, ACTP).

:func:`simulate_kernel` runs :func:`metro_atc.core.ato.coasting.simulate_switching`: per
strategy and distance step, :func:`metro_atc.core.ato.step_kernel.strategy_step_one` in
accelerate / coast mode with no speed code (closed-form coasting, ACTP n.d.,
eq. 7-8), a coasting point inside a step splitting it.  ``test/test_ato_switching_kernel.py``
holds it to the numbers of the former numpy reference (frozen in ``test/data``) on generated
lines.

The step itself is :func:`metro_atc.core.ato.step_kernel.strategy_step_one` (shared with
the DP's kernel); the train's constants come packed by
:func:`metro_atc.core.ato.step_kernel.pack_train`.  Compiled on first use and cached on disk
(``cache=True``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import NDArray

from metro_atc.core.ato.envelope import MODE_ACCEL, MODE_COAST
from metro_atc.core.ato.step_kernel import strategy_step_one

FloatArray = NDArray[np.float64]


@njit(cache=True, error_model="numpy")
def simulate_kernel(c: NDArray[np.void], s: FloatArray, h: float, fg: FloatArray,
                    cap: FloatArray, yc: FloatArray, delta: FloatArray, record: bool
                    ) -> tuple[FloatArray, FloatArray, NDArray[np.bool_], FloatArray]:
    """Time [s], energy [J], stalled flag and (if ``record``) e = v^2/2 history per strategy.

    c: :func:`metro_atc.core.ato.step_kernel.pack_train` (one record); s: (n+1,) uniform grid
    [m] of step h [m]; fg: (n,) mean grade force of each step [N]; cap: (n,) envelope e at each
    step's end; yc, delta: (K,) coasting points [m] and traction levels.  The history has
    shape (K, n+1) (or (0, 0) without ``record``).
    """
    tr = c[0]
    n = s.shape[0] - 1
    k_n = yc.shape[0]
    t_out = np.zeros(k_n)
    en_out = np.zeros(k_n)
    st_out = np.zeros(k_n, dtype=np.bool_)
    hist = np.zeros((k_n, n + 1)) if record else np.zeros((0, 0))
    for j in range(k_n):
        y = yc[j]
        dl = delta[j]
        e = 0.0
        t = 0.0
        en = 0.0
        st = False
        for k in range(n):
            sk = s[k]
            sw = (y > sk + 1e-9) and (y < s[k + 1] - 1e-9)
            accel = sk + 1e-9 < y
            h1 = y - sk if sw else h
            e1, dt, de, st1 = strategy_step_one(tr, e, h1, fg[k], cap[k],
                                                MODE_ACCEL if accel else MODE_COAST,
                                                np.inf, dl)
            if sw:
                e2, dt2, de2, st2 = strategy_step_one(tr, e1, h - h1, fg[k], cap[k],
                                                      MODE_COAST, np.inf, dl)
                e1 = e2
                dt += dt2
                de += de2
                st1 = st1 or st2
            e = e1
            if math.isfinite(dt):
                t += dt
            en += de
            st = st or st1
            if record:
                hist[j, k + 1] = e
        t_out[j] = np.inf if st else t
        en_out[j] = en
        st_out[j] = st
    return t_out, en_out, st_out, hist
