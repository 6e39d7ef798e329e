"""What the line simulator publishes of the plant, read from a :class:`~.line.LineSim`.

:func:`plant_states` is :meth:`LineSim.states` (every per-train array, copies);
:func:`fleet_state_rows` gives the arrays of the fleet state for some trains only, the same
values as :func:`plant_states`' entries of those trains, without copying the others (issue
13: the line simulator publishes the fleet state of the trains in service every step, on
the lockstep's critical path); :func:`dwelling_in_service` the trains dwelling in service.
ROS-free; SI units.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from .fleet import DONE, WAIT
from .kpi import RunLog
from .stations import HELD_S

FLEET_KEYS = ("x_m", "v_mps", "a_mps2", "current_station", "next_station", "mode",
              "departure_time_s", "target_running_time_s", "atp_limit_mps",
              "movement_authority_m", "mass_kg")
"""The keys of :func:`plant_states` that :func:`fleet_state_rows` gives."""


def target_departure(sim: Any, rows: NDArray[np.intp]) -> NDArray[np.float64]:
    """Commanded (else scheduled) departure time from the current station [s].

    ``rows``: the trains (indices), in that order.  NaN for a train held until a later
    command (:data:`.stations.HELD_S`: no departure decided yet).
    """
    j = np.minimum(np.maximum(sim.fleet.cur_station[rows], 0), sim.n_st - 1)
    dep = sim.stations.cmd_dep[rows, j]
    out = np.where(np.isfinite(dep), dep, sim.service.sched_dep[rows, j])
    return np.where(out >= HELD_S, np.nan, out)


def target_running_time(sim: Any, rows: NDArray[np.intp]) -> NDArray[np.float64]:
    """Commanded (else scheduled) running time to the next station of trains ``rows`` [s].

    A run past stops a dispatcher has the train skip: plus the scheduled running times of
    the runs after the skipped stops (their dwell is not added).
    """
    j = np.minimum(np.maximum(sim.fleet.cur_station[rows], 0), sim.n_st - 2)
    rt = sim.stations.cmd_rt[rows, j]
    out = np.where(np.isfinite(rt), rt, sim.service.sched_running_s[j])
    nxt = sim.fleet.next_stop[rows]
    far = (nxt > j + 1) & (nxt < sim.n_st)
    if far.any():
        cs = np.concatenate(([0.0], np.cumsum(sim.service.sched_running_s)))
        out = np.where(far, out + cs[np.minimum(nxt, sim.n_st - 1)] - cs[j + 1], out)
    return out


def plant_states(sim: Any) -> dict[str, Any]:
    """Per-train state arrays (copies); ``mode`` uses the TrainState.MODE_* values.

    ``mass_kg`` is the load-weigh mass of each train [kg] (the on-board ATO's).

    The :data:`FLEET_KEYS` arrays are :func:`fleet_state_rows` of every train (one formula
    for both); the others are copies of the components' arrays.
    """
    fl, atp = sim.fleet, sim.atp
    f = fleet_state_rows(sim, np.arange(sim.n))
    return {
        "x_m": f["x_m"], "v_mps": f["v_mps"], "a_mps2": f["a_mps2"], "mode": f["mode"],
        "current_station": f["current_station"], "next_station": f["next_station"],
        "traction_energy_j": sim.energy.e_trac.copy(),
        "regen_energy_j": sim.energy.e_regen.copy(),
        "atp_limit_mps": f["atp_limit_mps"], "movement_authority_m": f["movement_authority_m"],
        "speed_code_mps": atp.speed_code.copy(),
        "atp_interventions": atp.interventions.copy(), "load_pax": fl.load.copy(),
        "mass_kg": f["mass_kg"],
        "in_service": fl.run.copy(),
        "target_running_time_s": f["target_running_time_s"],
        "departure_time_s": f["departure_time_s"],
    }


def fleet_state_rows(sim: Any, rows: NDArray[np.intp]) -> dict[str, Any]:
    """The :data:`FLEET_KEYS` arrays of :func:`plant_states` at the trains ``rows`` only.

    ``rows``: train indices (int array); each array's entries are those of the full array
    at ``rows``, in that order (new arrays).
    """
    fl, atp = sim.fleet, sim.atp
    status = fl.status[rows]
    nxt = fl.next_stop[rows]
    return {
        "x_m": np.where(status == DONE, fl.x_done[rows], fl.x[rows]),
        "v_mps": fl.v[rows], "a_mps2": fl.acc[rows],
        "current_station": fl.cur_station[rows],
        "next_station": np.where(fl.run[rows] | (status == WAIT),
                                 np.where(nxt < sim.n_st, nxt, -1), -1),
        "mode": fl.modes(atp.eb, atp.sb, rows),
        "departure_time_s": target_departure(sim, rows),
        "target_running_time_s": target_running_time(sim, rows),
        "atp_limit_mps": np.maximum(atp.atp_limit[rows], 0.0),
        "movement_authority_m": atp.eoa[rows],
        "mass_kg": fl.mass[rows],
    }


def dwelling_in_service(sim: Any) -> list[tuple[int, int]]:
    """(train, current station) of the trains dwelling in service, by train index.

    The trains whose :func:`plant_states` ``mode`` is MODE_DWELL and ``in_service`` true.
    """
    fl = sim.fleet
    at = np.flatnonzero(fl.run & fl.dwelling).tolist()
    cur = fl.cur_station
    return [(i, int(cur[i])) for i in at]


def plant_run_log(sim: Any) -> RunLog:
    """What the KPIs need from the run of plant ``sim`` (copies)."""
    st, atp, sv = sim.stations, sim.atp, sim.service
    return RunLog(
        scenario=sim.scn.name, seed=sim.seed, train_ids=list(sim.train_ids),
        n_st=sim.n_st, t=sim.t, step_count=sim.step_count,
        completed=np.asarray((sim.fleet.status == DONE) & ~st.withdrawn),
        withdrawn=st.withdrawn.copy(),
        act_arr=st.act_arr.copy(), act_dep=st.act_dep.copy(), sched_arr=sv.sched_arr,
        sched_dep=sv.sched_dep, cmd_rt=st.cmd_rt.copy(),
        sched_running_s=sv.sched_running_s, energy=sim.energy_breakdown(),
        interventions=atp.interventions.copy(), violations=atp.violations.copy(),
        min_sep=atp.min_sep, margin=atp.margin, boarded=st.boarded.copy(),
        left_behind=st.left_behind.copy(), skipped_stops=st.skipped_stops,
        stop_errors_m=np.array([e.stop_error_m for e in st.events
                                if e.kind == "arrival"], dtype=float),
        steps_above_civil=int(atp.steps_above_civil),
        control_period_s=float(sim.control_period_s))
