"""Compiled inner loops of the MAX-MIN ant system on the pre-work tables (Ke 2010, Sec. 4.2).

:func:`construct_ants` is one iteration's tour construction of :func:`mmas.solve_mmas`
(Ke 2010, Sec. 4.2 items 4-5: an ant picks section by section a mode by roulette wheel on
``tau[m, mode_{m-1}, mode] * eta[m, mode]^lambda`` and then a speed code on
``tau_v[m, mode, code]`` over the allowed codes) together with the table evaluation of the
tour as it is built (Ke 2010, eq. 6-7, :meth:`sections.SectionTables.lookup` arithmetic);
It is the colony's only construction path (``NUMBA_DISABLE_JIT=1`` runs it as Python); its
tests compare it with the recorded output of the former numpy construction
(``test/data/mmas_numpy_ref.npz``: identical tours and figures for the same uniforms).
:func:`table_prefix` is the state of one tour at every section start (the common prefixes of
the local search's single-section moves).

Compiled with numba when installed (:func:`metro_atc.core.ato.step_kernel.jit`, on-disk
cache), plain Python otherwise.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from metro_atc.core.ato.step_kernel import jit

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


@jit
def construct_ants(cum_m: FloatArray, cum_c: FloatArray, u: FloatArray, packed: FloatArray,
                   inv_he: float, n_e: int, modes: IntArray, codes: IntArray, t: FloatArray,
                   en: FloatArray) -> None:  # pragma: no cover - compiled
    """Build and evaluate the ants' tours of one iteration (in place).

    cum_m (N_s, 3, 3): cumulative mode weights per section and previous mode; cum_c
    (N_s, 3, n_codes): cumulative code weights per section and mode; u (N_s, 2, K):
    uniforms in [0, 1) (mode, code) per section and ant; packed: the tables' (rows, 3)
    look-up array; inv_he: 1 / entry-energy step [s^2/m^2]; n_e: entry grid size.
    Out: modes, codes (K, N_s); t [s], en [J] (K,).  An ant starts in accelerate mode 0's
    row (previous mode 0) at standstill.
    """
    n_s = cum_m.shape[0]
    n_c = cum_c.shape[2]
    n_k = u.shape[2]
    hi = n_e - 1.000001
    for k in range(n_k):
        prev = 0
        e = 0.0
        tk = 0.0
        ek = 0.0
        for i in range(n_s):
            r = u[i, 0, k] * cum_m[i, prev, 2]
            m = 0
            for j in range(3):
                if cum_m[i, prev, j] < r:
                    m += 1
            if m > 2:
                m = 2
            r = u[i, 1, k] * cum_c[i, m, n_c - 1]
            c = 0
            for j in range(n_c):
                if cum_c[i, m, j] < r:
                    c += 1
            if c > n_c - 1:
                c = n_c - 1
            modes[k, i] = m
            codes[k, i] = c
            f = e * inv_he
            if f > hi:
                f = hi
            j0 = int(f)
            w = f - j0
            b = ((i * 3 + m) * n_c + c) * n_e + j0
            e = packed[b, 0] * (1.0 - w) + packed[b + 1, 0] * w
            tk += packed[b, 1] * (1.0 - w) + packed[b + 1, 1] * w
            ek += packed[b, 2] * (1.0 - w) + packed[b + 1, 2] * w
            prev = m
        t[k] = tk
        en[k] = ek


@jit
def table_prefix(packed: FloatArray, h_e: float, n_e: int, n_c: int, modes: IntArray,
                 codes: IntArray, e_p: FloatArray, t_p: FloatArray, en_p: FloatArray
                 ) -> None:  # pragma: no cover - compiled
    """State (entry e, time [s], energy [J]) of one tour (N_s,) at each section start (N_s,).

    The arithmetic of :func:`metro_atc.core.ato.tour_kernel.table_kernel` section by
    section; e_p, t_p, en_p are filled from section 0 (standstill) on.
    """
    n_s = modes.shape[0]
    hi = n_e - 1.000001
    e = 0.0
    t = 0.0
    en = 0.0
    for i in range(n_s):
        e_p[i] = e
        t_p[i] = t
        en_p[i] = en
        f = e / h_e
        f = min(max(f, 0.0), hi)
        j0 = int(f)
        w = f - j0
        b = ((i * 3 + modes[i]) * n_c + codes[i]) * n_e + j0
        e = packed[b, 0] * (1.0 - w) + packed[b + 1, 0] * w
        t += packed[b, 1] * (1.0 - w) + packed[b + 1, 1] * w
        en += packed[b, 2] * (1.0 - w) + packed[b + 1, 2] * w
