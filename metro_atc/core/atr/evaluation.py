"""Closed-loop evaluation of ATR regulators on the truth traffic model, with KPIs (Lin 2010a).

Scenario of Lin 2010a, Exp. 2: an initial departure delay at the first station (180 s), peak
headway, truth dynamics with saturation, crowding, knock-on and exponential departure
delays.  A regulator acts for the K adjustable services (stages 0..K-1), K = 40 by
default: the delayed train reaches the terminal after 22 stages and its knock-on followers
after about 30.

KPIs (our definitions; the seed's Table I/Fig. 8 define them on missing pages):
- ``cost``: sum_{k<K} U(x(k), u_applied(k)) + Phi(x(K)) (:mod:`.cost`; applied = the
  saturated adjustment), the realised finite-service cost on the truth trajectory;
- ``worst_terminal_delay_s``: largest departure deviation at the terminal station;
- ``running_time_dev_index``: RMS [s] of (run + dwell) time deviations from the timetable,
  x(k+1)_i - x(k)_{i-1}, over all trains and stations i >= 1;
- ``headway_dev_index``: RMS [s] of departure headway deviations x(k+1)_i - x(k)_i;
- ``recovery_time_s``: H times the first stage after which every |x_i| <= 30 s stays so
  (K H if that never happens within the K stages).
"""

from __future__ import annotations

from typing import Dict, Optional

import numpy as np

from metro_atc.core.atr.blue_line import LineData
from metro_atc.core.atr.cost import CostWeights, stage_cost, terminal_cost
from metro_atc.core.atr.regulators import Regulator
from metro_atc.core.atr.traffic import (split_adjustment, timetable_state,
                                        truth_arrivals_departures)

RECOVERY_TOL_S = 30.0


def simulate(line: LineData, regulator: Regulator, x0_s: np.ndarray, w_dep: np.ndarray,
             horizon: int, saturation: bool = True, knock_on: bool = True,
             crowding: bool = True) -> Dict[str, np.ndarray]:
    """Run the closed loop on the truth model; w_dep: (steps, N) departure delays [s].

    Returns x (steps+1, N), u_cmd and u_applied (steps, N) [s], and ``arr`` (steps+1, N):
    arrival deviations [s] of the trains of x (row 0 nan).  Stages >= horizon use u = 0.
    Every train is ready at its timetable (the simulation of Lin 2010a, Exp. 2);
    :func:`simulate_linked` adds the turnback link.
    """
    return simulate_linked(line, regulator, x0_s, w_dep, horizon, None, saturation,
                           knock_on, crowding)


def simulate_linked(line: LineData, regulator: Regulator, x0_s: np.ndarray,
                    w_dep: np.ndarray, horizon: int, ready_dev_s: Optional[np.ndarray],
                    saturation: bool = True, knock_on: bool = True, crowding: bool = True
                    ) -> Dict[str, np.ndarray]:
    """:func:`simulate` with the turnback link of every dispatched train.

    ``ready_dev_s`` (steps,) [s]: the train dispatched at stage k comes out of a turnback
    (:func:`metro_atc.core.service.turnback.turnback_link`, the delay it inherits from its
    previous trip): it reaches the first platform no earlier than its timetable plus
    ready_dev_s[k], and whatever the regulator commands it does not depart before that
    (a regulator may not dispatch a train before it can have turned back).  None: no link,
    exactly :func:`simulate`.
    """
    steps = w_dep.shape[0]
    n = line.n_stations
    ready = np.zeros(steps) if ready_dev_s is None else np.asarray(ready_dev_s, dtype=float)
    if ready.shape != (steps,) or not np.all(np.isfinite(ready)):
        raise ValueError(f"ready_dev_s must be {steps} finite values [s], got shape "
                         f"{ready.shape}")
    t0, t1 = timetable_state(line, 0), timetable_state(line, 1)
    arr_ref = truth_arrivals_departures(line, t0, np.zeros(n), 0.0, saturation=saturation,
                                        knock_on=knock_on, crowding=crowding)[0]
    x = np.zeros((steps + 1, n))
    x[0] = x0_s
    arr = np.full((steps + 1, n), np.nan)
    u_cmd = np.zeros((steps, n))
    u_app = np.zeros((steps, n))
    for k in range(steps):
        if k < horizon:
            u_cmd[k] = regulator.decide(x[k], k)
        if saturation:
            du_r, du_d = split_adjustment(line, u_cmd[k])
            u_app[k] = du_r + du_d
        else:
            u_app[k] = u_cmd[k]
        z = max(0.0, float(ready[k]))
        a, d = truth_arrivals_departures(line, t0 + x[k], u_cmd[k], z, w_dep=w_dep[k],
                                         saturation=saturation, knock_on=knock_on,
                                         crowding=crowding)
        x[k + 1] = d - t1
        if ready_dev_s is not None:
            x[k + 1, 0] = max(x[k + 1, 0], z)
        arr[k + 1] = a - arr_ref
    return {"x": x, "u_cmd": u_cmd, "u_applied": u_app, "arr": arr}


def kpis(traj: Dict[str, np.ndarray], line: LineData, weights: CostWeights,
         p0: np.ndarray) -> Dict[str, float]:
    """KPIs of a trajectory from :func:`simulate` (see module docstring); p0: Phi matrix."""
    x, u = traj["x"], traj["u_applied"]
    cost = float(np.sum(stage_cost(x[:-1], u, weights)) + terminal_cost(x[-1], p0, weights))
    run_dev = x[1:, 1:] - x[:-1, :-1]
    head_dev = x[1:] - x[:-1]
    ok = np.all(np.abs(x) <= RECOVERY_TOL_S, axis=1)
    bad = np.nonzero(~ok)[0]
    rec_stage = 0 if bad.size == 0 else int(bad[-1]) + 1
    return {
        "cost": cost,
        "worst_terminal_delay_s": float(np.max(x[:, -1])),
        "running_time_dev_index": float(np.sqrt(np.mean(run_dev ** 2))),
        "headway_dev_index": float(np.sqrt(np.mean(head_dev ** 2))),
        "recovery_time_s": float(rec_stage * line.headway_s),
        "max_abs_control_s": float(np.max(np.abs(u))),
    }


def incident_scenario(line: LineData, delay_s: float, seed: int, steps: int,
                      station: int = 0, disturbances: bool = True,
                      rng: Optional[np.random.Generator] = None
                      ) -> Dict[str, np.ndarray]:
    """Initial deviation (delay_s at ``station``) and seeded exponential departure delays."""
    g = rng if rng is not None else np.random.default_rng(seed)
    x0 = np.zeros(line.n_stations)
    x0[station] = delay_s
    mean = line.disturbance_mean_s if disturbances else 0.0
    w = g.exponential(mean, size=(steps, line.n_stations)) if mean > 0 else np.zeros(
        (steps, line.n_stations))
    return {"x0": x0, "w": w}
