"""Seed 004 reference motion curve (speed vs distance), 5 regions, and planned-profile curves.

Seed 004 Sec. 3, Fig. 6: region 1 accelerate from standstill to the maximum speed
(S_acc), region 2 hold the maximum speed (S_max-speed), region 3 decelerate (S_dec), region 4
creep slowly (S_creep), region 5 brake to the stop at the platform point (S_brake).  The
curve is a function of the travelled distance ``s`` [m] (the RK4 displacement is mapped onto
the curve to get the desired speed r_k).  The paper gives no numbers for the regions except
the legal maximum acceleration 2 km/h/s (Table 4), used here for acceleration and
deceleration; the acceleration region additionally follows the train's traction capability
with a margin (:attr:`ReferenceCurveParams.traction_margin`) so that the curve is trackable
by the power-limited train (10 260 kW, Li n.d., Table 4).  Creep speed / length and the final
braking rate are our choices (documented defaults).

:class:`ProfileReference` turns a planned speed profile (MMAS, coasting control, DP) into a
reference of the same interface, with the Li n.d. creep/brake tail for platform stopping.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np
from numpy.typing import ArrayLike, NDArray

from metro_atc.core.ato.envelope import RunModel
from metro_atc.core.line.vehicle import max_traction_force, resistance_force

FloatArray = NDArray[np.float64]

REGION_ACCEL = 0
"""Region 1: accelerate."""
REGION_MAX_SPEED = 1
"""Region 2: maximum speed."""
REGION_DECEL = 2
"""Region 3: decelerate."""
REGION_CREEP = 3
"""Region 4: creep."""
REGION_BRAKE = 4
"""Region 5: brake to the platform point."""
REGION_NAMES = ("accelerate", "max speed", "decelerate", "creep", "brake")
"""Names of the five regions."""


@dataclass(frozen=True)
class ReferenceCurveParams:
    """Parameters of the 5-region curve (SI).

    v_max_mps: maximum speed (None: the run's speed limit); accel_mps2 / decel_mps2:
    acceleration and deceleration of regions 1 and 3 (Li n.d.: 2 km/h/s; deceleration with
    a 10 % braking margin); traction_margin: fraction of the net traction capability the
    acceleration region may use; creep_speed_mps, creep_length_m: region 4;
    brake_decel_mps2: region 5; step_m: tabulation step of region 1;
    departure_speed_mps: floor of the desired speed in the first half of the run (a
    distance-indexed curve is 0 at s = 0, which would never start the train).
    """

    v_max_mps: Optional[float] = None
    accel_mps2: float = 2.0 / 3.6
    decel_mps2: float = 0.9 * 2.0 / 3.6
    traction_margin: float = 0.9
    creep_speed_mps: float = 1.5
    creep_length_m: float = 10.0
    brake_decel_mps2: float = 0.3
    step_m: float = 2.0
    departure_speed_mps: float = 0.5


def stop_tail(s: ArrayLike, length_m: float, decel: float, creep_v: float, creep_len: float,
              brake_decel: float) -> FloatArray:
    """Decelerate / creep / brake envelope [m/s] ending at standstill at s = length_m.

    Regions 3-5 of Li n.d., Fig. 6: ``sqrt(v_c^2 + 2 a_d (s_c - s))`` before the creep start
    ``s_c``, ``v_c`` during creep, ``sqrt(2 a_b (L - s))`` in the final braking region.
    """
    sa = np.asarray(s, dtype=float)
    d_brake = creep_v * creep_v / (2.0 * brake_decel)
    s_b = length_m - d_brake
    s_c = s_b - creep_len
    dec = np.sqrt(creep_v * creep_v + 2.0 * decel * np.maximum(s_c - sa, 0.0))
    brk = np.sqrt(2.0 * brake_decel * np.maximum(length_m - sa, 0.0))
    return np.where(sa < s_c, dec, np.where(sa < s_b, creep_v, brk))


class ReferenceCurve:
    """Seed 004 5-region reference speed r(s) [m/s] for one run (s in [0, L] [m])."""

    def __init__(self, run: RunModel, params: Optional[ReferenceCurveParams] = None) -> None:
        """Tabulate region 1 on the run (grades and traction capability included)."""
        self.run = run
        self.p = params if params is not None else ReferenceCurveParams()
        p = self.p
        lim = float(np.min(run.static_limit(run.s_env)))
        self.v_max = float(min(p.v_max_mps if p.v_max_mps is not None else lim, lim))
        n = max(2, int(np.ceil(run.length_m / p.step_m)))
        self.s_tab = np.linspace(0.0, run.length_m, n + 1)
        h = run.length_m / n
        fg = run.mean_grade_force(self.s_tab[:-1], self.s_tab[1:])
        train = run.train
        e = np.zeros(n + 1)
        e_max = 0.5 * self.v_max ** 2
        for k in range(n):  # midpoint RK2 in distance on e = v^2/2
            ek = e[k]
            if ek >= e_max:
                e[k + 1:] = e_max
                break
            a1 = self._accel(train, np.sqrt(2.0 * ek), fg[k])
            e_mid = ek + 0.5 * h * a1
            a2 = self._accel(train, np.sqrt(2.0 * max(e_mid, 0.0)), fg[k])
            e[k + 1] = min(max(ek + h * a2, 0.0), e_max)
        self.v_acc = np.sqrt(2.0 * e)

    def _accel(self, train: object, v: float, fg: float) -> float:
        from metro_atc.core.line.vehicle import TrainParams
        assert isinstance(train, TrainParams)
        net = (float(max_traction_force(train, v)) - float(resistance_force(train, v)) - fg) \
            / train.effective_mass_kg
        return max(min(self.p.accel_mps2, self.p.traction_margin * net), 0.0)

    def speed(self, s: ArrayLike) -> FloatArray:
        """Desired speed r(s) [m/s] (Li n.d., Fig. 6); zero beyond the platform point."""
        sa = np.asarray(s, dtype=float)
        p = self.p
        acc = np.interp(sa, self.s_tab, self.v_acc)
        acc = np.where(sa < 0.5 * self.run.length_m,
                       np.maximum(acc, p.departure_speed_mps), acc)
        tail = stop_tail(sa, self.run.length_m, p.decel_mps2, p.creep_speed_mps,
                         p.creep_length_m, p.brake_decel_mps2)
        out = np.minimum(np.minimum(acc, self.v_max), tail)
        return np.where(sa >= self.run.length_m, 0.0, np.maximum(out, 0.0))

    def region(self, s: ArrayLike) -> NDArray[np.int64]:
        """Region index 0..4 (REGION_*) at s [m]."""
        sa = np.asarray(s, dtype=float)
        p = self.p
        acc = np.interp(sa, self.s_tab, self.v_acc)
        tail = stop_tail(sa, self.run.length_m, p.decel_mps2, p.creep_speed_mps,
                         p.creep_length_m, p.brake_decel_mps2)
        d_brake = p.creep_speed_mps ** 2 / (2.0 * p.brake_decel_mps2)
        s_b = self.run.length_m - d_brake
        s_c = s_b - p.creep_length_m
        limited = tail < np.minimum(acc, self.v_max) - 1e-9
        out = np.where(acc < self.v_max - 1e-6, REGION_ACCEL, REGION_MAX_SPEED)
        out = np.where(limited & (sa < s_c), REGION_DECEL, out)
        out = np.where(limited & (sa >= s_c) & (sa < s_b), REGION_CREEP, out)
        out = np.where(limited & (sa >= s_b), REGION_BRAKE, out)
        return out.astype(np.int64)


class ProfileReference:
    """Reference r(s) [m/s] from a planned profile (s_grid [m], v [m/s]) with a stop tail.

    The tail (Li n.d. regions 3-5, default without creep) caps the profile near the
    platform point so the tracker lands on it; ``tail_*`` are the tail's decelerations [m/s^2],
    creep speed [m/s] and length [m].
    """

    def __init__(self, s_grid: ArrayLike, v: ArrayLike, length_m: float,
                 tail_decel: float = 0.7, creep_speed: float = 0.6, creep_len: float = 0.0,
                 tail_brake: float = 0.35, departure_speed: float = 0.5) -> None:
        """Store the planned profile and the stop-tail parameters."""
        self.s_grid = np.asarray(s_grid, dtype=float)
        self.v = np.asarray(v, dtype=float)
        self.length_m = float(length_m)
        self.tail = (tail_decel, creep_speed, creep_len, tail_brake)
        self.departure_speed = float(departure_speed)
        self._s_list: list[float] = self.s_grid.tolist()
        self._e_list: list[float] = (self.v * self.v).tolist()
        self._n = len(self._s_list)
        # the stop tail's region bounds for the compiled step (kernel_tables)
        d, cv, _, bb = self.tail
        s_b = self.length_m - cv * cv / (2.0 * bb)
        self._tail_at = (s_b - creep_len, s_b, cv * cv, 2.0 * d, 2.0 * bb)

    def kernel_tables(self) -> tuple[list[float], list[float], list[float]]:
        """What the compiled ATO step's ``speed_at`` reads (:meth:`speed` at one point).

        ([length [m], departure speed [m/s], creep start [m], brake start [m], cv^2,
        2 decel, 2 brake, creep speed [m/s]], the s grid [m], v^2 [m^2/s^2]).
        """
        return ([self.length_m, self.departure_speed, *self._tail_at, self.tail[1]],
                self._s_list, self._e_list)

    def speed(self, s: ArrayLike) -> FloatArray:
        """Desired speed [m/s] at s [m]."""
        sa = np.asarray(s, dtype=float)
        # interpolate kinetic energy v^2/2 (exact for constant-acceleration pieces; linear
        # interpolation of v would make the final approach exponential, never arriving)
        plan = np.sqrt(np.interp(sa, self.s_grid, self.v * self.v))
        plan = np.where(sa < 0.5 * self.length_m, np.maximum(plan, self.departure_speed), plan)
        d, cv, cl, b = self.tail
        tail = stop_tail(sa, self.length_m, d, cv, cl, b)
        return np.where(sa >= self.length_m, 0.0, np.minimum(plan, tail))
