"""Several plant steps per compiled call: the reference driver's run (:mod:`.kernel_run`).

:meth:`.line.LineSim.run_driven` runs :func:`.driver.simple_driver` + :meth:`LineSim.step`
until a time; with the compiled kernel, :func:`run_compiled` does the steps between two
points that need Python in one call of :func:`.kernel_run.run_rows` and leaves the plant
exactly as the per-step loop would (fleet, ATP, brakes' axle states, sensors' clock and
normals position, trace rows, the stepper's cached blocks and driver command), with the
samples of all those steps as one :class:`.sensors.SensorBlock` (same values, in order; the
sensor faults applied as the per-step blocks apply them).  The station logic of a step that
ends at an arrival or overrun candidate is left to the caller (``hit``, ``d``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .braking import AxleState
from .sensors import SensorBlock, StepResult
from .stations import TrainEvent

FloatArray = NDArray[np.float64]

MAX_STEPS = 256
"""Steps per compiled call at most (output blocks allocated per call)."""


@dataclass
class DrivenRun:
    """What :meth:`.line.LineSim.run_driven` did: steps, events, samples, interventions."""

    steps: int = 0
    kernel_steps: int = 0
    """Of ``steps``, those done inside compiled multi-step calls."""
    calls: int = 0
    """Compiled multi-step calls that did at least one step."""
    atp_interventions: int = 0
    stops: list[int] = field(default_factory=lambda: [0] * 6)
    """Compiled calls per reason they stopped (``kernel_run.STOP_*`` index)."""
    events: list[TrainEvent] = field(default_factory=list)
    blocks: list[SensorBlock] = field(default_factory=list)
    """Sensor samples in time order (one block per step or per compiled call)."""

    def add(self, res: StepResult, samples: bool) -> None:
        """Count one :meth:`.line.LineSim.step` result (its samples read if ``samples``)."""
        self.steps += 1
        self.events.extend(res.events)
        self.atp_interventions += res.atp_interventions
        if samples:
            blk = res.sensor_arrays
            if blk is not None:
                self.blocks.append(blk)

    @property
    def n_samples(self) -> int:
        """Train samples in :attr:`blocks` (sample instants x instrumented trains)."""
        return sum(b.t.size * b.trains.size for b in self.blocks)


def run_compiled(sim: Any, u0: FloatArray, t_next: float, until_s: float, samples: bool,
                 out: DrivenRun) -> tuple[int, Any, Any]:
    """Reference-driver steps in one compiled call; returns (steps, hit, d).

    ``u0``: the reference driver's command for the first step, whose discrete events (if
    due) the caller has done; ``t_next``: the plant's next discrete time [s] (the call
    stops before a later step starting at or after it); ``until_s``: no step starts at or
    after it.  ``hit`` (arrival / overrun candidates) and ``d`` (distance past the stop
    point [m]) of the last step when it needs the station logic, else None.
    """
    kr = _kernel_run()
    stp, fl, atp, br, sen = sim.stepper, sim.fleet, sim.atp, sim.brakes, sim.sensors
    kn = stp.kn
    if br.any_slide or br.any_wsp:
        return 0, None, None
    u0 = np.ascontiguousarray(u0, dtype=float)
    fs, ints, bools, grids, axc, blk0 = stp.packed(sim)
    n, na = fl.n, axc.shape[2]
    sensed = bool(sen.any_sensed)
    if sensed:
        sen.clock_ready()
    cpos0 = sen.cpos
    idx = sen.idx
    m = idx.size
    samples = samples and sensed
    dt = sim.control_period_s
    t0 = sim.t
    # steps this call can make at most (output buffers; a hit may end it sooner)
    t_end = min(t_next, until_s, sim.duration_s)
    kmax = max(1, min(MAX_STEPS, int((t_end - t0) / dt) + 2))
    if samples:
        cap = kmax * (int(dt / sen.sensor_dt) + 2)
        sen.reserve((2 * na + 2) * cap * m)
        ax0 = br.ax
        slip0 = np.ascontiguousarray(ax0.arrays[2] if ax0.arrays is not None
                                     else ax0.get()[2])
        axs = np.empty((2, 3, n, na))
    else:
        cap = 0
        slip0 = np.zeros((n, na))
        axs = np.empty((2, 3, 0, na))
    o4, o2 = np.empty((2, cap, m, na)), np.empty((2, cap, m))
    blks = np.empty((kmax, kn.N_OUT, n))
    tk = np.empty(kmax)
    rf = np.empty(kr.RESULT_F.itemsize // 8)
    ri = np.zeros(kr.RESULT_I.itemsize // 8, dtype=np.int64)
    kr.run_rows(stp.c, stp.tabs, stp.geo, stp.stab, stp.dcs, fs, ints, bools, grids, axc,
                blk0, blks, u0, axs, br.r_w, idx, slip0, sen.clock, sen.zbuf, o4, o2, False,
                False, fl.any_auto, sensed, samples, t0, t_next, sim.duration_s, until_s,
                cpos0, sen.zpos, tk, rf, ri)
    res = dict(zip(kr.RESULT_INTS, ri.tolist()))  # by name: plain ints, not record fields
    t_last, gmin = (dict(zip(kr.RESULT_FLOATS, rf.tolist()))[f] for f in ("t", "gmin"))
    k = res["steps"]
    out.stops[res["why"]] += 1
    if k == 0:
        return 0, None, None
    # the plant state of the last step (what NumbaStepper.advance binds)
    blk = blks[k - 1]
    x1, v1, acc, lim, eoa, a_d, _, _, u_clean = blk[:kn.OUT.drv]
    atp.atp_limit, atp.eoa = lim, eoa
    fl.u_last, fl.a_dem = u_clean, a_d
    atp.any_atp, atp.any_violation = bool(res["any_atp"]), bool(res["any_viol"])
    if gmin < atp.min_sep:
        atp.min_sep = gmin
    atp.steps_above_civil += res["n_civil"]
    coef = br.ax_coef

    def axle(j: int) -> AxleState:
        b = blks[j]
        arr = (axs[j % 2, 0], axs[j % 2, 1], axs[j % 2, 2]) if samples else None
        return AxleState(b[kn.OUT.ffa], b[kn.OUT.acc], b[kn.OUT.wax], coef, arr)

    br.ax_prev, br.ax = (axle(k - 2) if k > 1 else br.ax), axle(k - 1)
    fl.acc, fl.x, fl.v = acc, x1, v1
    stp.blk0, stp.blk0_rows = blk, (x1, v1, u_clean, a_d, eoa)
    stp.drv_blk = blk
    hit_step = res["why"] == kr.STOP_HIT
    stp.drv_state = () if hit_step else (x1, v1, eoa, fl.stop_x)
    # sensors: clock and normals advanced as the per-step path does
    cpos = res["cpos"]
    sen.pre = None
    if sensed:
        sen.cpos, sen.next_sample_t = cpos, sen.clock_l[cpos]
    n_s = res["samples"]
    if samples:
        sen.zpos, sen.want = res["zpos"], True
        if n_s:
            ts = sen.clock[cpos0:cpos]
            omega, clamp, accel, vref = o4[0, :n_s], o4[1, :n_s], o2[0, :n_s], o2[1, :n_s]
            if sen.faults:
                sen.apply_faults(ts, idx, omega, clamp, accel, vref)
            car_mass = fl.mass / sim.p.cars
            out.blocks.append(SensorBlock(ts, idx, omega, clamp, accel, vref, car_mass[idx]))
    # time, step count, trace rows
    every, tr, sc = sim.trace_every, sim.trace, sim.step_count
    if every:  # steps j with (sc + j + 1) % every == 0
        for j in range(every - 1 - sc % every, k, every):
            bj = blks[j]
            tr["t"].append(float(tk[j]))
            tr["x"].append(bj[kn.OUT.x1].copy())
            tr["v"].append(bj[kn.OUT.v1].copy())
            tr["run"].append(fl.run)
            tr["atp"].append(bj[kn.OUT.lim].copy())
    sim.t, sim.step_count = t_last, sc + k
    out.steps += k
    out.kernel_steps += k
    out.calls += 1
    out.atp_interventions += res["n_int"]
    if not hit_step:
        return k, None, None
    d = blk[kn.OUT.d]
    tol = sim.tol_stop
    return k, fl.cand & ((d > tol) | ((v1 <= 0.0) & (d >= -tol))), d


def _kernel_run() -> Any:
    """:mod:`.kernel_run` (imported on first use: numba stays optional)."""
    global _KR
    if _KR is None:
        from . import kernel_run
        _KR = kernel_run
    return _KR


_KR: Any = None

__all__ = ["MAX_STEPS", "DrivenRun", "run_compiled"]
