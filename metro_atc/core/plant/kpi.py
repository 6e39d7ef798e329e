"""Key performance indicators of a line simulation (JSON-serialisable dict).

Punctuality: share of departures no more than ``PUNCTUAL_S`` late against the timetable.
Recovery: ``recovery_time_s`` runs from the first departure more than ``RECOVERY_TOL_S``
late to the last one (the seed 000 Exp. 2 "the delay subsides"), ``late_departures`` counts
them.  The tolerance is the punctuality threshold: with the routine exponential departure
delays of the scenarios a few departures end 30-50 s late anywhere in a run, which would
make a tighter tolerance measure noise instead of the recovery from an incident.
Schedule deviation: departure minus timetable (seed 000 cost). Headway deviation: actual
minus scheduled headway between consecutive trains at each station.  Running-time
deviation: actual minus target (ATS command if any, else timetable) running time.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:  # pragma: no cover
    from .line import LineSim

PUNCTUAL_S = 60.0
"""A departure at most this late counts as punctual [s]."""

RECOVERY_TOL_S = PUNCTUAL_S
"""A departure more than this late counts as not recovered [s]."""

J_PER_KWH = 3.6e6
"""Joules per kWh."""


def _stats(a: NDArray[np.float64]) -> dict[str, float | None]:
    a = a[np.isfinite(a)]
    if a.size == 0:
        return {"mean": None, "mean_abs": None, "rms": None, "max": None}
    return {"mean": float(a.mean()), "mean_abs": float(np.abs(a).mean()),
            "rms": float(np.sqrt(np.mean(a * a))), "max": float(a.max())}


def _f(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def compute_kpis(sim: "LineSim") -> dict[str, Any]:
    """KPIs of ``sim`` so far (line level and per train)."""
    from .line import _ST_DONE
    dep_dev = sim.act_dep - sim.sched_dep
    arr_dev = sim.act_arr - sim.sched_arr
    h_act = sim.act_dep[1:] - sim.act_dep[:-1]
    h_sch = sim.sched_dep[1:] - sim.sched_dep[:-1]
    tgt_rt = np.where(np.isfinite(sim.cmd_rt[:, :-1]), sim.cmd_rt[:, :-1],
                      sim.sched_running_s[None, :])
    rt_act = sim.act_arr[:, 1:] - sim.act_dep[:, :-1]
    rt_dev = rt_act - tgt_rt
    e = sim.energy_breakdown()
    valid = np.isfinite(dep_dev)
    punct = float(np.mean(dep_dev[valid] <= PUNCTUAL_S)) if valid.any() else None
    late = dep_dev > RECOVERY_TOL_S  # NaN (no departure) compares False
    t_late = sim.act_dep[late]
    recovery = float(t_late.max() - t_late.min()) if t_late.size else 0.0
    per_train = []
    for i, tid in enumerate(sim.train_ids):
        v = np.isfinite(dep_dev[i])
        per_train.append({
            "train_id": tid,
            "completed": bool(sim.status[i] == _ST_DONE),
            "departures": int(v.sum()),
            "punctuality": float(np.mean(dep_dev[i][v] <= PUNCTUAL_S)) if v.any() else None,
            "max_delay_s": float(dep_dev[i][v].max()) if v.any() else None,
            "terminal_delay_s": _f(float(arr_dev[i, -1])),
            "schedule_deviation_s": _stats(dep_dev[i]),
            "running_time_deviation_s": _stats(rt_dev[i]),
            "energy_kwh": float(e["substation"][i] / J_PER_KWH),
            "traction_wheel_kwh": float(e["traction_wheel"][i] / J_PER_KWH),
            "regen_kwh": float(e["regen_to_line"][i] / J_PER_KWH),
            "atp_interventions": int(sim.interventions[i]),
            "atp_violations": int(sim.violations[i]),
        })
    tot = {k: float(np.sum(val) / J_PER_KWH) for k, val in e.items()}
    return {
        "scenario": sim.scn.name,
        "seed": sim.seed,
        "trains": int(sim.n),
        "completed_trains": int(np.sum(sim.status == _ST_DONE)),
        "stations": int(sim.n_st),
        "sim_time_s": float(sim.t),
        "steps": int(sim.step_count),
        "atp_violations": int(sim.violations.sum()),
        "atp_interventions": int(sim.interventions.sum()),
        "min_separation_m": _f(sim.min_sep),
        "safety_margin_m": float(sim.margin),
        "energy_kwh": tot["substation"],
        "energy": {
            "traction_wheel_kwh": tot["traction_wheel"],
            "regen_to_line_kwh": tot["regen_to_line"],
            "electric_brake_kwh": tot["electric_brake"],
            "friction_brake_kwh": tot["friction_brake"],
            "resistance_kwh": tot["resistance"], "curve_kwh": tot["curve"],
            "aux_kwh": tot["aux"], "substation_net_kwh": tot["substation"],
        },
        "max_delay_s": _f(float(np.nanmax(dep_dev))) if valid.any() else None,
        "max_terminal_delay_s": _f(float(np.nanmax(arr_dev[:, -1])))
        if np.isfinite(arr_dev[:, -1]).any() else None,
        "punctuality": punct,
        "punctual_threshold_s": PUNCTUAL_S,
        "recovery_time_s": recovery,
        "late_departures": int(late.sum()),
        "recovery_tolerance_s": RECOVERY_TOL_S,
        "schedule_deviation_s": _stats(dep_dev),
        "headway_deviation_s": _stats(h_act - h_sch),
        "running_time_deviation_s": _stats(rt_dev),
        "passengers_boarded": int(round(float(sim.boarded.sum()))),
        "passengers_left_behind": int(round(float(sim.left_behind.sum()))),
        "skipped_stops": int(sim.skipped_stops),
        "per_train": per_train,
    }
