"""The compiled plant step: kernel selection and the wrappers around :mod:`.kernel`.

``plant_kernel`` (``LineSim(kernel=...)`` or the ``METRO_ATC_PLANT_KERNEL`` environment
variable): ``numpy`` -- the reference path (:mod:`.physics`); ``numba`` -- the fused
per-train loops of :mod:`.kernel` / :mod:`.kernel_aux`; ``auto`` (default) -- numba when it
is installed, else numpy.  Both read and write the same component arrays, so the state stays
in the components (checkpoints, plots and nodes see no difference); the numpy path is the
reference the compiled one is tested against (golden traces, generated lines).
"""

from __future__ import annotations

import copy
import importlib.util
import operator
import os
import time
from typing import Any

import numpy as np
from numpy.typing import NDArray

from metro_atc.core.line.rolling_stock import KMH

from .atp import CIVIL_TOL_MPS
from .braking import AxleState
from .physics import PlantParts
from .sensors import SensorBlock, Sensors, SensorSnap

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

KERNELS = ("auto", "numba", "numpy")
"""Accepted values of ``plant_kernel``."""
AUTO_GAIN, AUTO_LOOKAHEAD_S = 1.5, 0.7
""":func:`.driver.driver_command` defaults: the plant's own driver of turning-back trains."""
KERNEL_ENV = "METRO_ATC_PLANT_KERNEL"
"""Environment variable selecting the kernel when ``LineSim`` is not told."""


def numba_available() -> bool:
    """True when numba can be imported."""
    return importlib.util.find_spec("numba") is not None


def resolve_kernel(name: str | None = None) -> str:
    """``numba`` or ``numpy`` for the requested kernel (argument, else env, else auto)."""
    req = (name or os.environ.get(KERNEL_ENV, "") or "auto").strip().lower()
    if req not in KERNELS:
        raise ValueError(f"plant kernel must be one of {KERNELS}, got {req!r}")
    if req == "numpy":
        return "numpy"
    if not numba_available():
        if req == "numba":
            raise RuntimeError("plant kernel 'numba' requested but numba is not installed")
        return "numpy"
    return "numba"


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
        """Samples with noise and injected sensor faults (same draws as the numpy path).

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
    """:func:`.physics.advance_numpy` with the compiled kernel (same signature, same updates).

    The kernel takes a few packed arrays: constants of the run, static tables, and stacked
    copies of arrays that only change at discrete events (fleet masks, mass constants,
    supervision grids, brake coefficients), re-stacked whenever a component rebinds one of
    them (they are compared by identity every step).  The dynamic state is passed as the
    components' own arrays and updated in place or rebound exactly as the numpy path does.

    Reference driver: with ``want_drv`` (set by the first :meth:`driver` call of the
    reference driver) the kernel also computes the driver's command for the next step from
    the end-of-step state; :meth:`driver` serves it while that state is unchanged (same step
    count and the same position/speed/authority arrays; after arrivals or overruns the
    command is recomputed).
    """

    checkpoint_transient = ("warm_s",)
    """Not plant state: the compile / cache-load time of this process [s] (checkpoints)."""

    def __init__(self, sim: PlantParts) -> None:
        """Pack the run's constants and static tables (compiles / loads the kernel)."""
        from . import kernel as kn
        from . import kernel_step as ks
        self.kn, self.ks = kn, ks
        atp, g, p, br, fl = sim.atp, sim.geometry, sim.p, sim.brakes, sim.fleet
        dt = sim.control_period_s
        cu = atp.curve
        c = np.zeros(kn.N_CONST)
        vals = {
            kn.C_X0: g.x0, kn.C_INV_DX: g.inv_dx, kn.C_LEN: g.length_m,
            kn.C_X_SWITCH: g.x_switch, kn.C_BLOCK: atp.block_len, kn.C_MARGIN: atp.margin,
            kn.C_EOA_END: g.eoa_end, kn.C_G_DOWN: atp.g_down, kn.C_C0A: cu.c0a,
            kn.C_C0B: cu.c0b, kn.C_C1: cu.c1, kn.C_C2A: cu.c2a, kn.C_TR: cu.t_r,
            kn.C_TSBI: atp.t_sbi, kn.C_SBI_OFF: _sbi_offset(), kn.C_CEIL_TOL: g.ceiling_tol,
            kn.C_BS: p.max_service_brake_mps2, kn.C_EB_DECEL: p.emergency_brake_actual_mps2,
            kn.C_JERK: p.max_jerk_mps3 * dt, kn.C_JERK_EB: p.emergency_jerk_mps3 * dt,
            kn.C_CIVIL_TOL: CIVIL_TOL_MPS, kn.C_G_AXLE: br.g_per_axle,
            kn.C_TRAC_ADH: br.trac_adh, kn.C_MU_PK: br.mu_pk, kn.C_INV_NAX: 1.0 / br.n_ax,
            kn.C_INV_NMOT: 1.0 / max(br.n_mot, 1), kn.C_DAVIS_A: p.davis_a_n,
            kn.C_DAVIS_B: p.davis_b_n_per_mps, kn.C_DAVIS_C: p.davis_c_n_per_mps2,
            kn.C_DT: dt, kn.C_TOL: sim.tol_stop, kn.C_CODE_STEP: 5.0 * KMH,
            kn.C_FIXED: float(bool(atp.fixed_block)), kn.C_N_SID: g.n_sid,
            kn.C_SUBSTEPS: sim.substeps, kn.C_FC_PER_N: br.fc_per_n, kn.C_JW: br.jw}
        for key, val in vals.items():
            c[key] = float(val)
        self.c = c
        tb = atp.tables
        self.tabs = np.ascontiguousarray(np.stack([tb.v, tb.phi, tb.ebrake]))
        self.stab = np.ascontiguousarray(np.stack([tb.mu, tb.slip]))
        self.geo = np.ascontiguousarray(np.stack([g.gsin_avg, g.curve_avg]))
        self.zeros = np.zeros(fl.n)
        self.no_axles = np.zeros((3, 0, 4))
        self.no_ts = np.zeros(0)
        self.no_sens = (np.zeros((2, 0, 0, 4)), np.zeros((2, 0, 0)), np.zeros(0, dtype=np.int64),
                        np.zeros((fl.n, 4)), np.zeros(0), 0)
        self.noise = getattr(sim.sensors, "noise", np.zeros(4))
        self.dc_auto = _driver_consts(sim, AUTO_GAIN, AUTO_LOOKAHEAD_S)
        self.auto_buf = np.zeros(fl.n)
        self.key: tuple[Any, ...] = ()
        self.key_groups: tuple[tuple[Any, ...], ...] = ()
        self.packs: tuple[Any, ...] = ()
        self.dc_key: tuple[float, float] | None = None
        self.dc = np.zeros(ks.N_DCONST)
        self.want_drv = False
        self.drv_state: tuple[Any, ...] = ()
        self.drv_blk = np.zeros((kn.N_OUT, fl.n))
        self.step_all = ks.step_all
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
        fl, en = tmp.fleet, tmp.energy
        masks, mp = self._packed(fl, tmp.atp, tmp.brakes)[:2]
        z = np.zeros(n)
        self.ks.motion(self.c, fl.x, fl.v, z, z, z, z, mp, self.geo, masks, fl.stop_x,
                       en.e_trac, en.e_elec, en.e_fric, en.e_res, en.e_curve, en.e_grade,
                       en.e_stop_corr, en.n_in_service, np.empty((self.kn.N_OUT, n)))
        self.key, self.key_groups, self.packs = (), (), ()
        self.drv_state, self.dc_key, self.want_drv = (), None, False
        return time.perf_counter() - t0

    def _packed(self, fl: Any, atp: Any, br: Any) -> tuple[Any, ...]:
        """(masks, mass constants, grids, brake ratios, axle coefficients) stacked.

        A group is re-stacked when a component rebound one of its source arrays (identity
        check; the components rebind, never edit in place, the arrays packed here).
        """
        key = (fl.run, fl.hold, fl.broken, fl.auto, fl.cand, fl.mass, fl.meff, fl.inv_meff,
               fl.davis_bc, atp.ebi_static, atp.sbi_static, atp.ceiling_phys, atp.limit_eff,
               atp.drive_env, br.slide_ratio, br.fric_mult, br.ax_coef)
        if len(key) == len(self.key) and all(map(operator.is_, key, self.key)):
            return self.packs
        groups = (key[:5], key[5:8] + fl.davis_bc, key[9:14], key[14:16], br.ax_coef[1:4])
        old = self.key_groups or ((),) * len(groups)
        packs = list(self.packs) or [None] * len(groups)
        for g, (new, prev) in enumerate(zip(groups, old)):
            if len(new) != len(prev) or not all(map(operator.is_, new, prev)):
                packs[g] = np.stack(new, dtype=bool if g == 0 else float)
        self.key, self.key_groups, self.packs = key, groups, tuple(packs)
        return self.packs

    def advance(self, sim: PlantParts, u: FloatArray, auto_u: FloatArray | None,
                axles: bool = False, ts: FloatArray | None = None
                ) -> tuple[int, BoolArray | None, FloatArray]:
        """See :func:`.physics.advance_numpy` (``axles``: fill the axle arrays now).

        ``auto_u`` None: the kernel computes the turning-back trains' commands itself
        (:func:`.driver.driver_command` with its default gains, at the start of the step).

        ``ts``: the step's sensor sample instants; once samples have been read
        (``sensors.want``) the kernel computes them with the step, from the next normals
        of the sensor stream without consuming them (``sensors.pre``; taken by
        :meth:`FastSensors.block` when they are read in order).
        """
        kn = self.kn
        fl, atp, br, en = sim.fleet, sim.atp, sim.brakes, sim.energy
        n = fl.n
        blk = np.empty((kn.N_OUT, n))
        masks, mp, grids, bk, axc = self._packed(fl, atp, br)
        coef = br.ax_coef
        ax_out = np.empty((3, n, axc.shape[2])) if axles else self.no_axles
        sen = sim.sensors
        o4, o2, sidx, slip0, zbuf, zpos = self.no_sens
        k = 0
        if axles and ts is not None and sen.want and isinstance(sen, FastSensors):
            sidx = sen.idx
            ns, m, na = ts.size, sidx.size, axc.shape[2]
            k = (2 * na + 2) * ns * m
            sen.reserve(k)
            zbuf, zpos = sen.zbuf, sen.zpos
            ax0 = br.ax
            slip0 = ax0.arrays[2] if ax0.arrays is not None else ax0.get()[2]
            o4, o2 = np.empty((2, ns, m, na)), np.empty((2, ns, m))
        t0 = sim.t
        auto = auto_u is None and fl.any_auto  # the kernel drives the turning-back trains
        if auto_u is None:
            auto_u = self.auto_buf if auto else self.zeros
        r = self.step_all(
            self.c, fl.x, fl.v, fl.status, masks, u, fl.u_last, auto_u, fl.a_dem, mp,
            fl.trac_level, atp.eb,
            atp.sb, atp.interventions, atp.violations, atp.in_violation, grids, self.tabs,
            atp.speed_code, bk, br.any_slide, br.any_wsp, blk, self.geo, fl.stop_x,
            en.e_trac, en.e_elec, en.e_fric, en.e_res, en.e_curve, en.e_grade,
            en.e_stop_corr, en.n_in_service, axc, self.stab, ax_out, self.dc, self.want_drv,
            sidx, br.r_w, slip0, self.no_ts if ts is None else ts, t0,
            t0 + sim.control_period_s, zbuf, zpos, self.noise, o4, o2, auto, atp.eoa,
            self.dc_auto)
        n_int, atp.any_atp, atp.any_violation, gmin, n_civil, n_hit = r
        if gmin < atp.min_sep:
            atp.min_sep = gmin
        atp.steps_above_civil += n_civil
        x1, v1, acc, lim, eoa, a_d, f_fa, w_ax, u_clean = blk[:kn.O_DRV]
        atp.atp_limit, atp.eoa = lim, eoa
        fl.u_last, fl.a_dem = u_clean, a_d
        if n_hit < 0:  # an axle may slide: the numpy adhesion / WSP model, then the motion
            f_brake = br.rail_force(blk[kn.O_FE], blk[kn.O_FF], w_ax, a_d, fl.v)
            n_hit = self.ks.motion(self.c, fl.x, fl.v, blk[kn.O_FTRAC], f_brake,
                                   blk[kn.O_FE], blk[kn.O_FBDEM], mp, self.geo, masks,
                                   fl.stop_x, en.e_trac, en.e_elec, en.e_fric, en.e_res,
                                   en.e_curve, en.e_grade, en.e_stop_corr, en.n_in_service,
                                   blk)
            br.follow(acc)
            self.drv_state = ()
        else:
            arrays = (ax_out[0], ax_out[1], ax_out[2]) if axles else None
            br.ax_prev, br.ax = br.ax, AxleState(f_fa, acc, w_ax, coef, arrays)
            self.drv_state = (x1, v1, eoa, fl.stop_x) if self.want_drv and not n_hit else ()
            self.drv_blk = blk
            if k:
                sen.pre = (o4, o2, zbuf, zpos, k)
        fl.acc, fl.x, fl.v = acc, x1, v1
        d = blk[kn.O_D]
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
            self.drv_state = ()
        if active_only:
            self.want_drv = True
            st = self.drv_state
            if (st and st[0] is fl.x and st[1] is fl.v and st[2] is atp.eoa
                    and st[3] is fl.stop_x):
                return self.drv_blk[self.kn.O_DRV].copy()
        out = np.empty(fl.n)
        ks.driver(self.dc, fl.x, fl.v, fl.stop_x, atp.eoa, atp.speed_code, atp.drive_env,
                  atp.sbi_static, fl.status, atp.fixed_block, active_only, out)
        return out


def _driver_consts(sim: PlantParts, gain: float, lookahead_s: float) -> FloatArray:
    """Packed constants of the compiled reference driver (``kernel_step.D_*``)."""
    from . import kernel_step as ks
    atp, g = sim.atp, sim.geometry
    c0, c2 = atp.curve.coef(atp.a_w)
    dc = np.zeros(ks.N_DCONST)
    for key, val in ((ks.D_X0, g.x0), (ks.D_INV_DX, g.inv_dx), (ks.D_B_DRIVE, atp.b_drive),
                     (ks.D_T_SBI, atp.t_sbi), (ks.D_C0, c0), (ks.D_C2, c2),
                     (ks.D_C1, atp.curve.c1), (ks.D_BS, sim.p.max_service_brake_mps2),
                     (ks.D_TOL, g.tol_stop), (ks.D_GAIN, gain), (ks.D_LA, lookahead_s)):
        dc[key] = float(val)
    return dc


def _sbi_offset() -> float:
    """The ATP's SBI offset below the EBI-derived speed [m/s]."""
    from metro_atc.core.line.atp_constants import SBI_OFFSET_MPS
    return float(SBI_OFFSET_MPS)


__all__ = ["KERNELS", "KERNEL_ENV", "FastSensors", "NumbaStepper",
           "numba_available", "resolve_kernel"]
