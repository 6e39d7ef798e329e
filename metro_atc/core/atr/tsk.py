"""Multi-period TSK fuzzy traffic model and timetable generation (Lin 2010a, eq. 7-10).

The daily operating hours are split into L durations [z_{n-1}, z_n) with headway H_n and
passenger flow p_{j,n} (Lin 2010a, Fig. 2).  Rule n (eq. 7): IF z is F_n THEN
t(k+1) = A_n t(k) + B_n (u(k) + w(k) + D_n(k)).  The memberships (eq. 8) are crisp
(1 inside the duration, 0 outside; the last duration is closed), so the normalised
membership equals the membership and the blended model (eq. 9) selects one rule.

A_n, B_n follow :func:`metro_atc.core.atr.traffic.linear_model` with
c_{j,n} = t_b p_{j,n} (boarding time per unit time since the previous train).  The
extraction of eq. 9 reads "c_j = t_b p_{j,n} H_n" with the fraction lost; with p_{j,n}
the hourly flow this is only dimensionless as t_b p_{j,n} / 3600 s, which is what we use
(see the derivation in :mod:`metro_atc.core.atr.traffic`).  The premise variable z is the
dispatch instant of the newest train of the step (Lin 2010a uses one z for the whole step).
"""

from __future__ import annotations

from typing import List, Sequence, Tuple

import numpy as np

from metro_atc.core.atr.blue_line import LineData, Period
from metro_atc.core.atr.traffic import linear_model, scheduled_d, schedule_offsets


def membership(z_s: float, periods: Sequence[Period]) -> np.ndarray:
    """Crisp memberships mu_n(z) of Lin 2010a, eq. 8 for instant z [s]; shape (L,).

    mu_n = 1 on [z_{n-1}, z_n) for n < L and on [z_{L-1}, z_L] for n = L, else 0.
    """
    mu = np.zeros(len(periods))
    for n, p in enumerate(periods):
        last = n == len(periods) - 1
        if p.start_s <= z_s < p.end_s or (last and z_s == p.end_s):
            mu[n] = 1.0
    return mu


def normalised_membership(z_s: float, periods: Sequence[Period]) -> np.ndarray:
    """Normalised memberships mu_n / sum(mu) (Lin 2010a, eq. 9); raises outside [z_0, z_L]."""
    mu = membership(z_s, periods)
    s = mu.sum()
    if s <= 0.0:
        raise ValueError(f"instant {z_s:.1f} s lies outside the operating durations")
    return mu / s


def rule_matrices(line: LineData, periods: Sequence[Period]
                  ) -> List[Tuple[np.ndarray, np.ndarray]]:
    """(A_n, B_n) for every duration n (Lin 2010a, eq. 9) with c_{j,n} = t_b p_j * flow_n."""
    return [linear_model(line.c(p.flow_factor)) for p in periods]


def tsk_step(line: LineData, periods: Sequence[Period], t_k: np.ndarray, u: np.ndarray,
             w: np.ndarray, z_k: float) -> np.ndarray:
    """Blended TSK model step (Lin 2010a, eq. 9): sum_n mu_n(z) (A_n t + B_n (u + w + D(k)))."""
    mu = normalised_membership(z_k, periods)
    d = scheduled_d(line, z_k)
    out = np.zeros_like(np.asarray(t_k, dtype=float))
    for mu_n, (a, b) in zip(mu, rule_matrices(line, periods)):
        if mu_n > 0.0:
            out = out + mu_n * (a @ t_k + b @ (u + w + d))
    return out


def dispatch_instants(periods: Sequence[Period], z0_s: float | None = None) -> np.ndarray:
    """Dispatch instants z_k [s] over the day: z_{k+1} = z_k + H_n(z_k)."""
    z = periods[0].start_s if z0_s is None else z0_s
    end = periods[-1].end_s
    out = []
    while z < end:
        out.append(z)
        n = int(np.argmax(membership(z, periods)))
        z += periods[n].headway_s
    return np.asarray(out)


def timetable(line: LineData, periods: Sequence[Period] | None = None,
              n_trains: int | None = None, z0_s: float | None = None) -> np.ndarray:
    """Scheduled departure instants T [s], shape (n_trains, N), from Lin 2010a, eq. 10.

    T(k+1) = sum_n mu_n(z_k) {A_n T(k) + B_n D_n(k)} on the staggered state; the line is
    assumed to be in the steady state of the first duration before the first dispatch
    (virtual predecessors one headway apart).  Row m is train m, column i station i.
    """
    per = list(line.periods if periods is None else periods)
    z = dispatch_instants(per, z0_s)
    if n_trains is not None:
        z = z[:n_trains]
    n = line.n_stations
    m = z.size
    h0 = per[0].headway_s
    off0 = schedule_offsets(line, h0, per[0].flow_factor)
    # T(0): entry i is virtual train -1-i at station i
    t = z[0] + (-1 - np.arange(n)) * h0 + off0
    out = np.full((m, n), np.nan)
    zero = np.zeros(n)
    for k in range(m + n - 1):
        z_k = z[min(k, m - 1)] if k < m else z[m - 1] + (k - m + 1) * per[-1].headway_s
        # after the last dispatch entry 0 holds virtual trains that are not recorded
        t = tsk_step(line, per, t, zero, zero, float(min(z_k, per[-1].end_s)))
        for i in range(n):
            train = k - i
            if 0 <= train < m:
                out[train, i] = t[i]
    return out
