"""One control period of the plant's continuous part with numpy (the reference path).

:func:`advance_numpy` runs, for the whole fleet: command clean-up -> ATP supervision and
safety monitors (:mod:`.atp`) -> jerk-limited demand -> traction / blended brake / adhesion
(:mod:`.braking`) -> RK4 with energy quadrature (:mod:`.dynamics`, :mod:`.energy`) ->
arrival candidates.  :mod:`.fast` is its compiled twin (same inputs, same state updates).
"""

from __future__ import annotations

from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from metro_atc.core.line.geometry import LineGeometry
from metro_atc.core.line.vehicle import TrainParams

from .atp import AtpSupervisor
from .braking import Brakes
from .dynamics import rk4_motion
from .energy import EnergyMeter
from .fleet import Fleet
from .sensors import Sensors

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

_cnz = np.count_nonzero


class PlantParts(Protocol):
    """The components a step advances (``LineSim`` provides them)."""

    fleet: Fleet
    atp: AtpSupervisor
    brakes: Brakes
    energy: EnergyMeter
    sensors: Sensors
    geometry: LineGeometry
    p: TrainParams
    control_period_s: float
    substeps: int
    tol_stop: float
    t: float


def advance_numpy(sim: PlantParts, u: FloatArray, auto_u: FloatArray | None,
                  axles: bool = False) -> tuple[int, BoolArray | None, FloatArray]:
    """Advance the fleet one control period with the commands ``u`` [n] (validated shape).

    NaN keeps the last command, values are clipped to [-1, 1]; ``auto_u`` replaces the
    command of the trains the plant drives itself (``fleet.auto``); ``axles``: the
    instrumented-axle arrays will be read this step (a hint; here they are derived lazily
    by :meth:`.braking.AxleState.get` either way).  Updates the fleet
    (x, v, acc, a_dem, u_last), the ATP state, the brake axle state and the energy meter.
    Returns (new ATP interventions, arrival/overrun candidates (None if none), front -
    stop point [m]).
    """
    fl, atp, p = sim.fleet, sim.atp, sim.p
    dt = sim.control_period_s
    nan = np.isnan(u)
    if _cnz(nan):
        u = np.where(nan, fl.u_last, u)
    ua = np.minimum(np.maximum(u, -1.0), 1.0)
    fl.u_last = ua
    if auto_u is not None:
        ua = np.where(fl.auto, auto_u, ua)
    x, v, run = fl.x, fl.v, fl.run
    # ATP supervision (independent of the command) + safety monitors
    phi, _, cells, n_int = atp.supervise(fl)
    # demanded acceleration (jerk limited)
    mass = fl.mass
    meff = fl.meff
    f_trac_max = phi * mass * fl.trac_level
    bs = p.max_service_brake_mps2
    a_tgt = np.where(ua >= 0.0, ua * f_trac_max / meff, ua * bs)
    a_tgt = np.where(fl.hold, -bs, a_tgt)
    a_tgt, jmax, eb_mask = atp.brake_demand(a_tgt, fl.broken, fl.any_broken, bs,
                                            p.emergency_brake_actual_mps2,
                                            p.max_jerk_mps3 * dt, p.emergency_jerk_mps3 * dt)
    a_prev = fl.a_dem
    a_d = np.minimum(np.maximum(a_tgt, a_prev - jmax), a_prev + jmax)
    fl.a_dem = a_d
    # forces: traction, blended electric/friction brake, adhesion
    f_trac, f_bdem, f_e, f_brake = sim.brakes.blend(a_d, v, mass, meff, f_trac_max, eb_mask)
    # RK4 (seed 004) with energy quadrature
    mo = rk4_motion(x, v, f_trac - f_brake - p.davis_a_n, mass, meff, p, sim.geometry,
                    dt, sim.substeps, cells, (fl.inv_meff,) + fl.davis_bc)
    x1, v1 = mo.x1, mo.v1
    sim.energy.meter(mo, v, x1 - x, meff, f_trac, f_brake, f_e, f_bdem, run)
    fl.acc = (v1 - v) * (1.0 / dt)
    sim.brakes.follow(fl.acc)
    fl.x, fl.v = x1, v1
    d = x1 - fl.stop_x
    tol = sim.tol_stop
    hit = fl.cand & ((d > tol) | ((v1 <= 0.0) & (d >= -tol)))
    return n_int, (hit if _cnz(hit) else None), d
