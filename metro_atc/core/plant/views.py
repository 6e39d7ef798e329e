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

FLEET_KEYS = ("x_m", "v_mps", "a_mps2", "current_station", "next_station", "mode",
              "departure_time_s", "target_running_time_s", "atp_limit_mps",
              "movement_authority_m")
"""The keys of :func:`plant_states` that :func:`fleet_state_rows` gives."""


def target_departure(sim: Any, rows: Any = None) -> NDArray[np.float64]:
    """Commanded (else scheduled) departure time from each train's current station [s].

    ``rows``: those trains only (indices), in that order; None: every train.
    """
    cur = sim.fleet.cur_station if rows is None else sim.fleet.cur_station[rows]
    j = np.minimum(np.maximum(cur, 0), sim.n_st - 1)
    r = np.arange(sim.n) if rows is None else rows
    dep = sim.stations.cmd_dep[r, j]
    return np.where(np.isfinite(dep), dep, sim.service.sched_dep[r, j])


def target_running_time(sim: Any, rows: Any = None) -> NDArray[np.float64]:
    """Commanded (else scheduled) running time to each train's next station [s]."""
    cur = sim.fleet.cur_station if rows is None else sim.fleet.cur_station[rows]
    j = np.minimum(np.maximum(cur, 0), sim.n_st - 2)
    r = np.arange(sim.n) if rows is None else rows
    rt = sim.stations.cmd_rt[r, j]
    return np.where(np.isfinite(rt), rt, sim.service.sched_running_s[j])


def plant_states(sim: Any) -> dict[str, Any]:
    """Per-train state arrays (copies); ``mode`` uses the TrainState.MODE_* values."""
    fl, atp = sim.fleet, sim.atp
    run = fl.run
    return {
        "x_m": np.where(fl.status == DONE, fl.x_done, fl.x),
        "v_mps": fl.v.copy(), "a_mps2": fl.acc.copy(),
        "mode": fl.modes(atp.eb, atp.sb), "current_station": fl.cur_station.copy(),
        "next_station": np.where(run | (fl.status == WAIT),
                                 np.where(fl.next_stop < sim.n_st, fl.next_stop, -1),
                                 -1),
        "traction_energy_j": sim.energy.e_trac.copy(),
        "regen_energy_j": sim.energy.e_regen.copy(),
        "atp_limit_mps": np.maximum(atp.atp_limit, 0.0),
        "movement_authority_m": atp.eoa.copy(),
        "speed_code_mps": atp.speed_code.copy(),
        "atp_interventions": atp.interventions.copy(), "load_pax": fl.load.copy(),
        "in_service": run.copy(),
        "target_running_time_s": target_running_time(sim),
        "departure_time_s": target_departure(sim),
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
    }


def dwelling_in_service(sim: Any) -> list[tuple[int, int]]:
    """(train, current station) of the trains dwelling in service, by train index.

    The trains whose :func:`plant_states` ``mode`` is MODE_DWELL and ``in_service`` true.
    """
    fl = sim.fleet
    at = np.flatnonzero(fl.run & fl.dwelling).tolist()
    cur = fl.cur_station
    return [(i, int(cur[i])) for i in at]
