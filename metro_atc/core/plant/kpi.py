"""Key performance indicators of a line simulation (JSON-serialisable dict).

Punctuality: share of departures no more than ``PUNCTUAL_S`` late against the timetable.
Recovery: ``recovery_time_s`` runs from the first departure more than ``RECOVERY_TOL_S``
late to the last one (the Lin 2010a, Exp. 2 "the delay subsides"), ``late_departures`` counts
them.  The tolerance is the punctuality threshold: with the routine exponential departure
delays of the scenarios a few departures end 30-50 s late anywhere in a run, which would
make a tighter tolerance measure noise instead of the recovery from an incident.
Schedule deviation: departure minus timetable (Lin 2010a cost). Headway deviation: actual
minus scheduled headway between consecutive trains at each station.  Running-time
deviation: actual minus target (ATS command if any, else timetable) running time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

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


@dataclass(frozen=True)
class RunLog:
    """What the KPIs need from a run (times [s], energy [J]); built by ``LineSim.run_log``.

    Rows are trains, columns stations; NaN where a train did not (yet) arrive/depart.
    """

    scenario: str
    seed: int
    train_ids: list[str]
    n_st: int
    t: float
    step_count: int
    completed: NDArray[np.bool_]
    act_arr: FloatArray
    act_dep: FloatArray
    sched_arr: FloatArray
    sched_dep: FloatArray
    cmd_rt: FloatArray
    sched_running_s: FloatArray
    energy: dict[str, FloatArray]
    interventions: NDArray[np.int64]
    violations: NDArray[np.int64]
    min_sep: float
    margin: float
    boarded: FloatArray
    left_behind: FloatArray
    skipped_stops: int
    stop_errors_m: FloatArray = field(default_factory=lambda: np.zeros(0))
    """Berthing error of every arrival at a platform (front minus stop point) [m]."""
    steps_above_civil: int = 0
    """Train-steps run above the civil speed limit."""
    control_period_s: float = 0.0
    """Length of one step [s]."""
    withdrawn: NDArray[np.bool_] = field(default_factory=lambda: np.zeros(0, dtype=bool))
    """Trains the dispatcher withdrew from service before the terminus (per train)."""


def compute_kpis(log: RunLog) -> dict[str, Any]:
    """KPIs of a run log (line level and per train)."""
    dep_dev = log.act_dep - log.sched_dep
    arr_dev = log.act_arr - log.sched_arr
    h_act = log.act_dep[1:] - log.act_dep[:-1]
    h_sch = log.sched_dep[1:] - log.sched_dep[:-1]
    tgt_rt = np.where(np.isfinite(log.cmd_rt[:, :-1]), log.cmd_rt[:, :-1],
                      log.sched_running_s[None, :])
    rt_act = log.act_arr[:, 1:] - log.act_dep[:, :-1]
    rt_dev = rt_act - tgt_rt
    e = log.energy
    valid = np.isfinite(dep_dev)
    punct = float(np.mean(dep_dev[valid] <= PUNCTUAL_S)) if valid.any() else None
    late = dep_dev > RECOVERY_TOL_S  # NaN (no departure) compares False
    t_late = log.act_dep[late]
    recovery = float(t_late.max() - t_late.min()) if t_late.size else 0.0
    per_train = []
    for i, tid in enumerate(log.train_ids):
        v = np.isfinite(dep_dev[i])
        per_train.append({
            "train_id": tid,
            "completed": bool(log.completed[i]),
            "departures": int(v.sum()),
            "punctuality": float(np.mean(dep_dev[i][v] <= PUNCTUAL_S)) if v.any() else None,
            "max_delay_s": float(dep_dev[i][v].max()) if v.any() else None,
            "terminal_delay_s": _f(float(arr_dev[i, -1])),
            "schedule_deviation_s": _stats(dep_dev[i]),
            "running_time_deviation_s": _stats(rt_dev[i]),
            "energy_kwh": float(e["substation"][i] / J_PER_KWH),
            "traction_wheel_kwh": float(e["traction_wheel"][i] / J_PER_KWH),
            "regen_kwh": float(e["regen_to_line"][i] / J_PER_KWH),
            "atp_interventions": int(log.interventions[i]),
            "atp_violations": int(log.violations[i]),
        })
    tot = {k: float(np.sum(val) / J_PER_KWH) for k, val in e.items()}
    return {
        "scenario": log.scenario,
        "seed": log.seed,
        "trains": len(log.train_ids),
        "completed_trains": int(np.sum(log.completed)),
        "withdrawn_trains": int(np.sum(log.withdrawn)),
        "stations": int(log.n_st),
        "sim_time_s": float(log.t),
        "steps": int(log.step_count),
        "atp_violations": int(log.violations.sum()),
        "atp_interventions": int(log.interventions.sum()),
        "min_separation_m": _f(log.min_sep),
        "safety_margin_m": float(log.margin),
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
        "passengers_boarded": int(round(float(log.boarded.sum()))),
        "passengers_left_behind": int(round(float(log.left_behind.sum()))),
        "skipped_stops": int(log.skipped_stops),
        **berthing_kpis(log),
        "per_train": per_train,
    }


BERTH_TOL_M = 0.30
"""Berthing tolerance [m] (platform screen doors, e.g. Taipei Metro +-30 cm)."""


def berthing_kpis(log: RunLog) -> dict[str, Any]:
    """Stopping accuracy and ATP-envelope figures of a run.

    ``stop_error_m`` p50/p95/max of |front - stop point| over the arrivals [m];
    ``stops_outside_0p30_m``; ``missed_stops`` (ran past the platform);
    ``atp_interventions_per_100_stops`` (ATP brake interventions: the ATO should never need
    them); ``time_above_civil_limit_s`` (train-seconds above the civil limit).
    """
    err = np.abs(np.asarray(log.stop_errors_m, dtype=float))
    err = err[np.isfinite(err)]
    stops = int(err.size) + int(log.skipped_stops)
    q = (lambda p: float(np.percentile(err, p))) if err.size else (lambda p: None)
    return {
        "stops": stops,
        "stop_error_m": {"p50": q(50), "p95": q(95),
                         "max": float(err.max()) if err.size else None},
        "stops_outside_0p30_m": int(np.count_nonzero(err > BERTH_TOL_M)),
        "missed_stops": int(log.skipped_stops),
        "atp_interventions_per_100_stops":
            100.0 * float(log.interventions.sum()) / stops if stops else 0.0,
        "time_above_civil_limit_s": float(log.steps_above_civil * log.control_period_s),
    }


def service_end(trains: int, completed_trains: int, sim_time_s: float, reached_end: bool,
                cut_at_s: float | None, duration_s: float,
                withdrawn_trains: int = 0) -> dict[str, Any]:
    """The ``finished`` / ``cut_at_s`` fields of a run's KPIs: did the whole service run.

    ``reached_end``: the run stepped to its end (the scenario's ``duration_s`` [s], every
    train out of service, or the cut); False when it was stopped before (a signal).
    ``cut_at_s``: the user's cut (``--duration`` / ``max_sim_time_s`` [s]) when it ended the
    run, else None.  ``withdrawn_trains``: trains the dispatcher withdrew from service
    (neither completed nor missing).  ``finished`` is True only when every train completed
    its trips or was withdrawn;
    ``cut_at_s`` is kept only for a run the cut left unfinished; ``end`` says in one line
    why the run ended.
    """
    wd = int(withdrawn_trains)
    missing = int(trains) - int(completed_trains) - wd
    finished = bool(reached_end) and missing == 0
    if finished:
        end = f"service completed: {trains} of {trains} trains" if wd == 0 else \
            f"service completed: {trains - wd} of {trains} trains, {wd} withdrawn by the " \
            "dispatcher"
    elif not reached_end:
        end = f"stopped at t={sim_time_s:.1f} s before the end: {missing} of {trains} " \
            "trains did not complete"
    elif cut_at_s is not None:
        end = f"cut at t={cut_at_s:.1f} s (--duration / max_sim_time_s): {missing} of " \
            f"{trains} trains did not complete"
    else:
        end = f"scenario duration {duration_s:.1f} s reached: {missing} of {trains} " \
            "trains did not complete their trips"
    return {"finished": finished, "incomplete_trains": missing,
            "cut_at_s": None if finished or cut_at_s is None else float(cut_at_s),
            "end": end}
