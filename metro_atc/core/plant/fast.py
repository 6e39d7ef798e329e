"""The compiled plant step: the wrappers around :mod:`.kernel` / :mod:`.kernel_step`.

One step of the fleet's continuous part (ATP supervision and monitors, jerk-limited
demand, traction / blended brake / adhesion, RK4 with the energy quadrature, arrival
candidates) is one call of the fused per-train loops, whose physics is
:mod:`metro_atc.core.laws`; a step where an axle may slide hands the rail force to the
adhesion / wheel-slide model of :mod:`.braking`.  The kernels read and write the
components' own arrays, so the state stays in the components (checkpoints, plots and
nodes see them).  ``NUMBA_DISABLE_JIT=1`` runs the same source uncompiled (debugging).
"""

from __future__ import annotations

import copy
import time
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from metro_atc.core.line.geometry import LineGeometry
from metro_atc.core.line.rolling_stock import KMH
from metro_atc.core.line.vehicle import TrainParams

from .atp import CIVIL_TOL_MPS, AtpSupervisor
from .braking import AxleState, Brakes
from .energy import EnergyMeter
from .fast_state import Blocks, same
from .fleet import Fleet
from .sensors import SensorBlock, Sensors, SensorSnap

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

AUTO_GAIN, AUTO_LOOKAHEAD_S = 1.5, 0.7
""":func:`.driver.driver_command` defaults: the plant's own driver of turning-back trains."""


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


class FastSensors(Sensors):
    """:class:`Sensors` whose samples are assembled by the compiled kernel."""

    def __init__(self, scn: Any, seed: int, faults: list[dict[str, Any]]) -> None:
        """As :class:`Sensors` (the compiled assembly is loaded here)."""
        super().__init__(scn, seed, faults)
        from .kernel_aux import sensor_block
        self.kernel = sensor_block
        sen = self.spec
        self.noise = np.array([sen.wheel_omega_noise_radps, sen.clamp_force_noise_n,
                               sen.accel_noise_mps2, sen.ref_speed_noise_mps], dtype=float)
        i1, f1, f2 = np.zeros(1, dtype=np.int64), np.ones(1), np.ones((1, 4))
        sensor_block(i1, f2, f2, f2, f2, f1, f1, f1, f1, 0.0, 1.0, np.zeros(10), self.noise,
                     np.zeros((2, 1, 1, 4)), np.zeros((2, 1, 1)))  # compile / load now

    def block(self, sn: SensorSnap) -> SensorBlock:
        """Samples with noise and injected sensor faults.

        The compiled step computes them with the step (``sn.pre``, see
        :meth:`NumbaStepper.advance`) once samples have been read (``want``); they are
        used when the normals they took are still the next ones of the stream (samples
        read in step order), else they are computed here.
        """
        self.want = True
        idx, ts = sn.idx, sn.ts
        pre = sn.pre
        if pre is not None and pre[2] is self.zbuf and pre[3] == self.zpos:
            self.zpos += pre[4]
            o4, o2 = pre[0], pre[1]
        else:
            ax1 = sn.ax1
            clamp1, slip1 = ax1.arrays[1:] if ax1.arrays is not None else ax1.get()[1:]
            ax0 = sn.ax0
            slip0 = ax0.arrays[2] if ax0.arrays is not None else ax0.get()[2]
            if clamp1.shape != slip1.shape:  # [n, 1] clamp of the rolling model
                clamp1 = np.ascontiguousarray(np.broadcast_to(clamp1, slip1.shape))
            ns, m, na = ts.size, idx.size, slip1.shape[1]
            z = self.normals((2 * na + 2) * ns * m)
            o4, o2 = np.empty((2, ns, m, na)), np.empty((2, ns, m))
            self.kernel(idx, sn.r_w, slip0, slip1, clamp1, sn.v0, sn.v1, sn.acc, ts, sn.t0,
                        sn.t1, z, self.noise, o4, o2)
        omega, clamp, accel, vref = o4[0], o4[1], o2[0], o2[1]
        if self.faults:
            self.apply_faults(ts, idx, omega, clamp, accel, vref)
        return SensorBlock(ts, idx, omega, clamp, accel, vref, sn.car_mass[idx])


class NumbaStepper:
    """The plant's step of the continuous part with the compiled kernel.

    The kernel (:func:`.kernel_step.step_rows`) takes a few packed arrays: constants of
    the run (with the sensor noise), static tables, the persistent blocks of
    :mod:`.fast_state` (float / integer / boolean per-train state the kernel updates in
    place, whose rows the components' attributes are; copies of the arrays that only change
    at discrete events: fleet masks, mass constants, brake ratios, supervision grids) and
    the previous step's output block, whose rows are the fleet's x, v, efforts and the
    movement authority (a fresh block per step: arrays a caller kept are never overwritten).

    Reference driver: with ``want_drv`` (set by the first :meth:`driver` call of the
    reference driver) the kernel also computes the driver's command for the next step from
    the end-of-step state; :meth:`driver` serves it while that state is unchanged (same step
    count and the same position/speed/authority arrays; after arrivals or overruns the
    command is recomputed).
    """

    checkpoint_transient = ("warm_s", "state", "blk0", "blk0_rows", "ax_key", "axc")
    """Not plant state: the compile / cache-load time of this process [s] and the packed
    views of the components' arrays (re-packed from the restored components)."""

    def __init__(self, sim: PlantParts) -> None:
        """Pack the run's constants and static tables (compiles / loads the kernel)."""
        from . import kernel as kn
        from . import kernel_step as ks
        self.kn, self.ks = kn, ks
        atp, g, p, br, fl = sim.atp, sim.geometry, sim.p, sim.brakes, sim.fleet
        dt = sim.control_period_s
        cu = atp.curve
        vals = (("x0", g.x0), ("inv_dx", g.inv_dx), ("train_length", g.length_m),
                ("x_switch", g.x_switch), ("block", atp.block_len), ("margin", atp.margin),
                ("eoa_end", g.eoa_end), ("g_down", atp.g_down), ("b_g", cu.b_g),
                ("t_r", cu.t_r), ("t_sbi", atp.t_sbi), ("sbi_offset", _sbi_offset()),
                ("ceiling_tol", g.ceiling_tol), ("bs", p.max_service_brake_mps2),
                ("eb_decel", p.emergency_brake_actual_mps2),
                ("jerk", p.max_jerk_mps3 * dt), ("jerk_eb", p.emergency_jerk_mps3 * dt),
                ("civil_tol", CIVIL_TOL_MPS), ("n_ax", br.n_ax), ("trac_adh", br.trac_adh),
                ("mu_pk", br.mu_pk), ("inv_nax", 1.0 / br.n_ax),
                ("inv_nmot", 1.0 / max(br.n_mot, 1)), ("davis_a", p.davis_a_n),
                ("davis_b", p.davis_b_n_per_mps), ("davis_c", p.davis_c_n_per_mps2),
                ("dt", dt), ("tol", sim.tol_stop), ("code_step", 5.0 * KMH),
                ("fixed", bool(atp.fixed_block)), ("n_sid", g.n_sid),
                ("substeps", sim.substeps), ("fc_per_n", br.fc_per_n), ("jw", br.jw),
                ("m_trac", p.mass_kg), ("meff_sb", p.service_brake_meff_limit_kg),
                ("meff_eb", p.emergency_brake_meff_limit_kg), ("lead_ext", atp.lead_ext))
        self.noise = getattr(sim.sensors, "noise", np.zeros(4))
        self.c = _record_vector(kn.CONSTANTS, vals + (("noise", self.noise),))
        """The run constants: a float vector the kernels read as ``kernel.CONSTANTS``."""
        tb = atp.tables
        self.tabs = np.ascontiguousarray(np.stack([tb.v, tb.phi, tb.ebrake]))
        self.stab = np.ascontiguousarray(np.stack([tb.mu, tb.slip]))
        self.geo = np.ascontiguousarray(np.stack([g.gsin_avg, g.curve_avg]))
        self.no_axles = np.zeros((3, 0, 4))
        self.no_ts = np.zeros(0)
        self.no_sens = (np.zeros(0), np.zeros(0, dtype=np.int64), np.zeros((fl.n, 4)),
                        np.zeros(0), 0)
        self.dc_auto = _driver_consts(sim, AUTO_GAIN, AUTO_LOOKAHEAD_S)
        self.dcs = np.stack((np.zeros(ks.DRIVER.itemsize // 8), self.dc_auto))
        self.state = _blocks(fl.n, g.n_cells)
        self.blk0 = np.zeros((kn.N_OUT, fl.n))
        self.blk0_rows: tuple[Any, ...] = ()
        self.ax_key: Any = None
        self.axc = np.zeros((3, fl.n, 0))
        self.dc_key: tuple[float, float] | None = None
        self.dc = np.zeros(ks.DRIVER.itemsize // 8)
        self.want_drv = False
        self.drv_state: tuple[Any, ...] = ()
        self.drv_blk = np.zeros((kn.N_OUT, fl.n))
        self.step_rows = ks.step_rows
        self.warm_s = self._warm(sim)

    def _warm(self, sim: PlantParts) -> float:
        """Compile (or load from the cache) every kernel now, on a copy of the plant.

        Keeps the JIT / cache-load time out of the first step (benchmarks, lockstep
        timeouts); returns the time it took [s].
        """
        t0 = time.perf_counter()
        tmp = copy.deepcopy(sim)
        n = tmp.fleet.n
        self.advance(tmp, np.zeros(n), None, True)
        self.driver(tmp, 1.5, 0.7, False)
        self._motion(tmp, np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n),
                     np.empty((self.kn.N_OUT, n)))
        self.state.reset()
        self.ax_key, self.blk0_rows = None, ()
        self.drv_state, self.dc_key, self.want_drv = (), None, False
        return time.perf_counter() - t0

    def _sync(self, fl: Any, atp: Any, br: Any, en: Any) -> tuple[Any, ...]:
        """The persistent blocks (float, int, bool state; grids; axle coefficients)."""
        parts = (fl, atp, en, br)
        coef = br.ax_coef
        if coef is not self.ax_key:
            self.axc = np.ascontiguousarray(np.stack(coef[1:4]))
            self.ax_key = coef
        return self.state.sync(parts) + (self.axc,)

    def _motion(self, sim: PlantParts, f_trac: FloatArray, f_brake: FloatArray,
                f_e: FloatArray, f_bdem: FloatArray, blk: FloatArray) -> int:
        """:func:`.kernel_step.motion` of the fleet (after the numpy rail force)."""
        fl, en = sim.fleet, sim.energy
        fs, _, bs = self._sync(fl, sim.atp, sim.brakes, en)[:3]
        ks = self.ks
        return int(ks.motion(self.c, fl.x, fl.v, f_trac, f_brake, f_e, f_bdem,
                             fs[ks.FS.mass:ks.FS.mass + len(ks.MASS)], self.geo,
                             bs[ks.BOOLS.run:], fl.stop_x,
                             en.e_trac, en.e_elec, en.e_fric, en.e_res, en.e_curve,
                             en.e_grade, en.e_stop_corr, en.n_in_service, blk))

    def _blk0(self, fl: Any, atp: Any) -> FloatArray:
        """The previous output block, holding the current x, v, u_last, a_dem and eoa."""
        kn = self.kn
        cur = (fl.x, fl.v, fl.u_last, fl.a_dem, atp.eoa)
        if same(cur, self.blk0_rows):
            return self.blk0
        blk0 = np.zeros((kn.N_OUT, fl.n))  # rebound elsewhere (set_xv, restore, copy)
        for row, arr in zip((kn.OUT.x1, kn.OUT.v1, kn.OUT.u, kn.OUT.ad, kn.OUT.eoa), cur):
            blk0[row] = arr
        return blk0

    def set_constant(self, name: str, value: float) -> None:
        """Set one scalar of the run constants (``kernel.CONSTANT_FIELDS``) from now on."""
        self.c[self.kn.CONSTANT_FIELDS.index(name)] = float(value)

    def packed(self, sim: PlantParts) -> tuple[Any, ...]:
        """The kernel's packed state: (float, int, bool blocks, grids, axle coefs, blk0)."""
        fl, atp, br, en = sim.fleet, sim.atp, sim.brakes, sim.energy
        if br.ax_coef is not self.ax_key:
            self._sync(fl, atp, br, en)
        fs, ints, bools, grids = self.state.sync((fl, atp, en, br))
        r0 = self.blk0_rows  # the previous output block while its rows are still bound
        blk0 = (self.blk0 if r0 and r0[0] is fl.x and r0[1] is fl.v and r0[2] is fl.u_last
                and r0[3] is fl.a_dem and r0[4] is atp.eoa else self._blk0(fl, atp))
        return fs, ints, bools, grids, self.axc, blk0

    def advance(self, sim: PlantParts, u: FloatArray, auto_u: FloatArray | None,
                axles: bool = False, ts: FloatArray | None = None
                ) -> tuple[int, BoolArray | None, FloatArray]:
        """Advance the fleet one control period with the commands ``u`` [n] (valid shape).

        NaN keeps the last command, values are clipped to [-1, 1]; ``auto_u`` replaces the
        command of the trains the plant drives itself (``fleet.auto``).  Updates the fleet
        (x, v, acc, a_dem, u_last), the ATP state, the brake axle state and the energy
        meter.  Returns (new ATP interventions, arrival/overrun candidates (None if none),
        front - stop point [m]).  ``axles``: fill the axle arrays now.

        ``auto_u`` None: the kernel computes the turning-back trains' commands itself
        (:func:`.driver.driver_command` with its default gains, at the start of the step).

        ``ts``: the step's sensor sample instants; once samples have been read
        (``sensors.want``) the kernel computes them with the step, from the next normals
        of the sensor stream without consuming them (``sensors.pre``; taken by
        :meth:`FastSensors.block` when they are read in order).
        """
        kn = self.kn
        fl, atp, br = sim.fleet, sim.atp, sim.brakes
        n = fl.n
        coef = br.ax_coef
        fs, ints, bools, grids, axc, blk0 = self.packed(sim)
        blk = np.empty((kn.N_OUT, n))
        ax_out = np.empty((3, n, axc.shape[2])) if axles else self.no_axles
        sen = sim.sensors
        so, sidx, slip0, zbuf, zpos = self.no_sens
        k = 0
        if axles and ts is not None and sen.want and isinstance(sen, FastSensors):
            sidx = sen.idx
            ns, m, na = ts.size, sidx.size, axc.shape[2]
            k = (2 * na + 2) * ns * m
            sen.reserve(k)
            zbuf, zpos = sen.zbuf, sen.zpos
            ax0 = br.ax
            slip0 = ax0.arrays[2] if ax0.arrays is not None else ax0.get()[2]
            so = np.empty(k)
        t0 = sim.t
        auto = auto_u is None and fl.any_auto  # the kernel drives the turning-back trains
        if auto_u is not None:
            fs[self.ks.FS.auto] = auto_u
        r = self.step_rows(
            self.c, self.tabs, self.geo, self.stab, self.dcs, fs, ints, bools, grids, axc,
            blk0, blk, u, ax_out, br.r_w, sidx, slip0, self.no_ts if ts is None else ts,
            zbuf, zpos, so, br.any_slide, br.any_wsp, self.want_drv, auto, t0,
            t0 + sim.control_period_s)
        n_int, atp.any_atp, atp.any_violation, gmin, n_civil, n_hit = r
        if gmin < atp.min_sep:
            atp.min_sep = gmin
        atp.steps_above_civil += n_civil
        x1, v1, acc, lim, eoa, a_d, f_fa, w_ax, u_clean = blk[:kn.OUT.drv]
        atp.atp_limit, atp.eoa = lim, eoa
        fl.u_last, fl.a_dem = u_clean, a_d
        if n_hit < 0:  # an axle may slide: the numpy adhesion / WSP model, then the motion
            f_brake = br.rail_force(blk[kn.OUT.fe], blk[kn.OUT.ff], w_ax, a_d, fl.v)
            n_hit = self._motion(sim, blk[kn.OUT.ftrac], f_brake, blk[kn.OUT.fe],
                                 blk[kn.OUT.fbdem], blk)
            br.follow(acc)
            self.drv_state = ()
        else:
            arrays = (ax_out[0], ax_out[1], ax_out[2]) if axles else None
            br.ax_prev, br.ax = br.ax, AxleState(f_fa, acc, w_ax, coef, arrays)
            self.drv_state = (x1, v1, eoa, fl.stop_x) if self.want_drv and not n_hit else ()
            self.drv_blk = blk
            if k:
                m4 = 2 * ns * m * na
                sen.pre = (so[:m4].reshape(2, ns, m, na), so[m4:].reshape(2, ns, m), zbuf,
                           zpos, k)
        fl.acc, fl.x, fl.v = acc, x1, v1
        self.blk0, self.blk0_rows = blk, (x1, v1, u_clean, a_d, eoa)
        d = blk[kn.OUT.d]
        hit = None
        if n_hit > 0:
            tol = sim.tol_stop
            hit = fl.cand & ((d > tol) | ((v1 <= 0.0) & (d >= -tol)))
        return n_int, hit, d

    def driver(self, sim: PlantParts, gain: float, lookahead_s: float,
               active_only: bool) -> FloatArray:
        """:func:`.driver.driver_command` (``active_only``: :func:`.driver.simple_driver`)."""
        ks = self.ks
        atp, fl = sim.atp, sim.fleet
        if self.dc_key != (gain, lookahead_s):
            self.dc, self.dc_key = _driver_consts(sim, gain, lookahead_s), (gain, lookahead_s)
            self.dcs[0] = self.dc
            self.drv_state = ()
        if active_only:
            self.want_drv = True
            st = self.drv_state
            if (st and st[0] is fl.x and st[1] is fl.v and st[2] is atp.eoa
                    and st[3] is fl.stop_x):
                return self.drv_blk[self.kn.OUT.drv].copy()
        out = np.empty(fl.n)
        ks.driver(self.dc, fl.x, fl.v, fl.stop_x, atp.eoa, atp.speed_code, atp.drive_env,
                  atp.sbi_static, fl.status, atp.fixed_block, active_only, out)
        return out


def _blocks(n: int, n_cells: int) -> Blocks:
    """The persistent blocks of :func:`.kernel_step.step_rows`.

    The rows of ``kernel_step.FS``, ``INTS``, ``BOOLS`` and the supervision grids
    ``kernel.GRIDS``, of the components
    (fleet, atp, energy, brakes).
    """
    from . import kernel as kn
    from . import kernel_step as ks
    own_f = ((0, "trac_level"), (0, "stop_x"), (1, "speed_code"), (1, "eoa_ext"),
             (2, "e_trac"), (2, "e_elec"), (2, "e_fric"), (2, "e_res"), (2, "e_curve"),
             (2, "e_grade"), (2, "e_stop_corr"))
    copy_f = ((0, "mass", False), (0, "meff", False), (0, "inv_meff", False),
              (0, "davis_b", None), (0, "davis_c", None),  # rebound with meff
              (3, "slide_ratio", False), (3, "fric_mult", False))
    f = tuple((p, a, True) for p, a in own_f) + copy_f
    i = ((0, "status", True), (1, "interventions", True), (1, "violations", True),
         (2, "n_in_service", True))
    b = ((1, "eb", True), (1, "sb", True), (1, "in_violation", True), (0, "run", False),
         (0, "hold", False), (0, "broken", False), (0, "auto", False), (0, "cand", False))
    g = tuple((1, a, False) for a in kn.GRIDS._fields)
    # the kernels read these rows by the names of kernel_step.FS / INTS / BOOLS (the
    # float block's last row, ``auto``, is scratch)
    for rows, names in ((f, ks.FS._fields[:-1]), (i, ks.INTS._fields), (b, ks.BOOLS._fields)):
        if tuple(a for _, a, _ in rows) != names:
            raise AssertionError(f"block rows {[a for _, a, _ in rows]} are not {names}")
    return Blocks((((n,), float, 1, f), ((n,), np.int64, 0, i), ((n,), bool, 0, b),
                   ((n_cells,), float, 0, g)), 4)


def _driver_consts(sim: PlantParts, gain: float, lookahead_s: float) -> FloatArray:
    """Constants of the compiled reference driver: a float vector of ``kernel_step.DRIVER``."""
    from . import kernel_step as ks
    atp, g = sim.atp, sim.geometry
    c0, c2 = atp.curve.coef(atp.a_w)
    return _record_vector(ks.DRIVER, (
        ("x0", g.x0), ("inv_dx", g.inv_dx), ("b_drive", atp.b_drive), ("t_sbi", atp.t_sbi),
        ("c0", c0), ("c2", c2), ("c1", atp.curve.c1), ("bs", sim.p.max_service_brake_mps2),
        ("tol", g.tol_stop), ("gain", gain), ("lookahead", lookahead_s)))


def _record_vector(dtype: np.dtype[Any], vals: tuple[tuple[str, Any], ...]) -> FloatArray:
    """The float vector a kernel views as the record ``dtype``, every field given once."""
    names = [name for name, _ in vals]
    if sorted(names) != sorted(dtype.names or ()):
        raise ValueError(f"record fields {sorted(names)} != {sorted(dtype.names or ())}")
    rec = np.zeros(1, dtype=dtype)
    for name, val in vals:
        rec[name] = val
    return rec.view(np.float64).copy()


def _sbi_offset() -> float:
    """The ATP's SBI offset below the EBI-derived speed [m/s]."""
    from metro_atc.core.line.atp_constants import SBI_OFFSET_MPS
    return float(SBI_OFFSET_MPS)


__all__ = ["FastSensors", "NumbaStepper", "PlantParts"]
