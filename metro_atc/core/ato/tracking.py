"""Closed-loop run simulation: a speed tracker on RK4 train dynamics (Li n.d., Sec. 3, Fig. 5).

Loop per control step: displacement s_k -> reference curve -> desired speed r_k; the tracker
(fuzzy / PI) turns e_k = r_k - v_k (and d_k) into a normalised effort u_k; Newton's law is
integrated by RK4 (:func:`metro_atc.core.line.vehicle.rk4_step`) over the step with the
effort and the local grade held constant.  Vectorised over several runs at once (e.g. the
seven THSR runs of Li n.d., Table 5).

Reported per run: trip time [s] (until the final standstill), stop error [m] (position of
the standstill minus the platform point), speed RMSE against the reference [m/s] over the
trip, traction energy ``sum max(F, 0) ds`` [J] (mechanical, at the wheel), and optionally the
trajectories.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Optional, Protocol, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from metro_atc.core.ato.envelope import RunModel
from metro_atc.core.line.vehicle import effort_force, rk4_step

FloatArray = NDArray[np.float64]


class SpeedReference(Protocol):
    """Anything with ``speed(s) -> r`` [m/s] for run coordinate s [m]."""

    def speed(self, s: ArrayLike) -> FloatArray:
        """Desired speed [m/s]."""
        ...


class Tracker(Protocol):
    """Tracker interface shared by the fuzzy and the PI controllers."""

    def reset(self, u0: ArrayLike = 0.0) -> None:
        """Reset internal state."""
        ...

    def step(self, r_mps: ArrayLike, v_mps: ArrayLike, dt_s: float = 0.1,
             u_ff: ArrayLike = 0.0) -> FloatArray:
        """Normalised effort in [-1, 1]."""
        ...

    def set_output(self, u: ArrayLike, u_ff: ArrayLike = 0.0) -> None:
        """Align the internal state with the applied effort (u_ff: its feedforward part)."""
        ...


@dataclass
class TrackResult:
    """Figures of one closed-loop run (SI); ``t``, ``s``, ``v``, ``r``, ``u`` if recorded."""

    trip_time_s: float
    stop_error_m: float
    speed_rmse_mps: float
    energy_j: float
    arrived: bool
    t: FloatArray = field(default_factory=lambda: np.zeros(0))
    s: FloatArray = field(default_factory=lambda: np.zeros(0))
    v: FloatArray = field(default_factory=lambda: np.zeros(0))
    r: FloatArray = field(default_factory=lambda: np.zeros(0))
    u: FloatArray = field(default_factory=lambda: np.zeros(0))


def simulate_tracking(runs: Sequence[RunModel], refs: Sequence[SpeedReference],
                      tracker: Tracker, dt_s: float = 0.1, max_time_s: float = 1e5,
                      standstill_s: float = 2.0, record: bool = False,
                      record_every: int = 10,
                      on_time: Optional[Callable[[float, int], None]] = None
                      ) -> list[TrackResult]:
    """Run every (run, reference) pair with one vectorised tracker until all have stopped.

    A run is finished when the train has been at standstill for ``standstill_s`` after
    passing half the run; the trip time is the instant the final standstill began.
    All runs must use the same train (``runs[0].train``).  ``on_time(t_s, n_running)``, if
    given, is called after every step with the simulated time [s] and the runs not yet
    finished (progress reporting; it must not change anything).
    """
    n = len(runs)
    train = runs[0].train
    lengths = np.array([r.length_m for r in runs])
    s = np.zeros(n)
    v = np.zeros(n)
    energy = np.zeros(n)
    sq_err = np.zeros(n)
    n_err = np.zeros(n)
    still = np.zeros(n)
    done = np.zeros(n, dtype=bool)
    trip = np.full(n, np.nan)
    tracker.reset(np.zeros(n))
    traces: list[list[FloatArray]] = [[] for _ in range(5)]
    t = 0.0
    k = 0
    while not np.all(done) and t < max_time_s:
        r = np.array([ref.speed(si) for ref, si in zip(refs, s)], dtype=float)
        u = tracker.step(r, v, dt_s)
        u = np.where(done, -1.0, u)
        grade = np.array([run.grade(si) for run, si in zip(runs, s)], dtype=float)
        f = effort_force(train, v, u)
        s1, v1 = rk4_step(train, s, v, f, grade, dt_s)
        s1 = np.where(done, s, s1)
        v1 = np.where(done, 0.0, v1)
        energy += np.where(done, 0.0, np.maximum(f, 0.0) * (s1 - s))
        active = ~done
        sq_err += np.where(active, (r - v) ** 2, 0.0)
        n_err += active
        if record and k % record_every == 0:
            for lst, val in zip(traces, (np.full(n, t), s, v, r, u)):
                lst.append(np.array(val, dtype=float))
        t += dt_s
        k += 1
        stopped = (v1 <= 1e-9) & (s1 > 0.5 * lengths) & active
        first = np.where(stopped & (still == 0.0), t, np.where(stopped, trip, np.nan))
        trip = np.where(done, trip, first)
        still = np.where(stopped, still + dt_s, 0.0)
        done |= still >= standstill_s - 1e-9
        s, v = s1, v1
        if on_time is not None:
            on_time(t, int(n - np.count_nonzero(done)))
    out = []
    for i in range(n):
        tr = [np.array([a[i] for a in lst]) for lst in traces] if record else \
            [np.zeros(0)] * 5
        out.append(TrackResult(trip_time_s=float(trip[i]), stop_error_m=float(s[i] - lengths[i]),
                               speed_rmse_mps=float(np.sqrt(sq_err[i] / max(n_err[i], 1.0))),
                               energy_j=float(energy[i]), arrived=bool(done[i]),
                               t=tr[0], s=tr[1], v=tr[2], r=tr[3], u=tr[4]))
    return out
