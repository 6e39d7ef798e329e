"""Seed 001 pre-work stage: energy / time tables per section x mode x speed code.

The inter-station distance is divided into ``N_s`` equal sections (Ke 2010, Sec. 4.2 item 1).
For every section, operation mode (accelerate / cruise / coast, item 2-3) and speed code
(40..80 km/h in 5 km/h steps by default) the section is simulated on the real track (grades,
envelope = limits + braking curves + programmed station stopping) from a grid of entry speeds;
exit speed, running time and traction energy are stored (item 4: "the results will be stored
and used during the online optimization stage").  The online stage
(:mod:`metro_atc.core.ato.mmas`) interpolates these tables linearly in the entry kinetic
energy ``e = v^2 / 2``, which makes one ant's tour evaluation a handful of table look-ups.

Mode semantics (the speed code is the ATO speed command of the section, a ceiling):

- accelerate: traction at level ``delta`` up to the code, then coast for the rest of the
  section (still braking if a down-grade pushes the speed above the code);
- cruise: hold ``min(entry speed, code)`` (partial traction / braking on grades);
- coast: no effort; the train brakes only when above the code or the envelope.

Also tabulated: the section mean gradient (heuristic information, item 3) and the highest
useful code of each section ("the upper limit of speed codes ... of each section are decided").
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np
from numpy.typing import ArrayLike, NDArray

from metro_atc.core.ato.envelope import MODE_ACCEL, MODE_COAST, MODE_CRUISE, RunModel
from metro_atc.core.ato.step_kernel import pack_train, run_substeps
from metro_atc.core.laws import G_MPS2

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

DEFAULT_CODES_KMH = tuple(range(40, 85, 5))
"""Default speed codes [km/h] (Ke 2010: 40..80 km/h in 5 km/h steps)."""

TIME_INFEASIBLE_S = 1e9
"""Stand-in running time [s] for a stalled section (kept finite for interpolation)."""


@dataclass
class SectionTables:
    """Pre-work tables of one run (Ke 2010, Fig. 2, pre-work stage).

    Arrays ``e_out`` [m^2/s^2], ``time_s`` [s], ``energy_j`` [J] have shape
    ``(n_sections, 3 modes, n_codes, n_entry)``; ``packed`` stacks them on a last axis and
    flattens for fast gathers.  ``e_grid`` is the uniform entry grid of e = v^2/2.
    """

    run: RunModel
    bounds_s: FloatArray
    codes_mps: FloatArray
    e_grid: FloatArray
    e_out: FloatArray
    time_s: FloatArray
    energy_j: FloatArray
    mean_grade: FloatArray
    code_allowed: NDArray[np.bool_]
    substep_m: float
    delta: float

    def __post_init__(self) -> None:
        """Pack the tables for the online look-ups."""
        self.packed = np.stack([self.e_out, self.time_s, self.energy_j], axis=-1).reshape(-1, 3)
        self.h_e = float(self.e_grid[1] - self.e_grid[0])

    @property
    def n_sections(self) -> int:
        """Number of sections N_s."""
        return int(self.bounds_s.size - 1)

    @property
    def n_codes(self) -> int:
        """Number of speed codes."""
        return int(self.codes_mps.size)

    def lookup(self, section: int, mode: IntArray, code: IntArray, e_in: FloatArray
               ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Interpolated (e_out, time [s], energy [J]) for arrays of ants in one section."""
        n_e = self.e_grid.size
        f = np.clip(e_in / self.h_e, 0.0, n_e - 1.000001)
        j0 = f.astype(np.int64)
        w = (f - j0)[:, None]
        base = ((section * 3 + mode) * self.n_codes + code) * n_e + j0
        val = self.packed[base] * (1.0 - w) + self.packed[base + 1] * w
        return val[:, 0], val[:, 1], val[:, 2]


def build_section_tables(run: RunModel, n_sections: int = 50,
                         codes_mps: Optional[ArrayLike] = None, n_entry: int = 64,
                         substep_m: float = 2.0, delta: float = 1.0) -> SectionTables:
    """Pre-work stage: simulate every section x mode x code x entry speed (Ke 2010, Sec. 4.1).

    n_sections: N_s; codes_mps: speed codes [m/s] (default 40..80 km/h step 5);
    n_entry: entry-speed grid size (uniform in v^2/2 up to the run's highest envelope);
    substep_m: integration step [m]; delta: traction level of the accelerate mode.
    """
    codes = np.asarray(codes_mps if codes_mps is not None
                       else np.array(DEFAULT_CODES_KMH, dtype=float) / 3.6, dtype=float)
    bounds = np.linspace(0.0, run.length_m, n_sections + 1)
    seg = run.length_m / n_sections
    n_sub = max(1, int(np.ceil(seg / substep_m - 1e-9)))
    h = seg / n_sub
    e_top = float(np.max(run.e_ceiling)) * 1.0001 + 1e-6
    e_grid = np.linspace(0.0, e_top, n_entry)
    shape = (n_sections, codes.size, n_entry)
    e_code = np.broadcast_to((0.5 * codes * codes)[None, :, None], shape)
    e_start_cap = run.ceiling_e(bounds[:-1])[:, None, None]
    e_in = np.minimum(np.broadcast_to(e_grid[None, None, :], shape), e_start_cap)
    out_e = np.empty((n_sections, 3) + shape[1:])
    out_t = np.empty_like(out_e)
    out_j = np.empty_like(out_e)
    n_sub_s = np.arange(n_sub) * h
    s0 = bounds[:-1, None] + n_sub_s[None, :]
    fg = run.mean_grade_force(s0, s0 + h)
    cap = run.ceiling_e(s0 + h)
    tr = pack_train(run.train, run.limits).view(np.recarray)
    e_flat = np.ascontiguousarray(e_in).reshape(-1)
    code_flat = np.ascontiguousarray(e_code).reshape(-1)
    hold = np.minimum(e_flat, code_flat)
    for mode in (MODE_ACCEL, MODE_CRUISE, MODE_COAST):
        latch = (e_flat >= code_flat) if mode == MODE_ACCEL else np.zeros(e_flat.size, bool)
        e, t, en, stalled = run_substeps(tr, e_flat, h, fg, cap, mode, code_flat, hold,
                                         float(delta), run.limits.brake_decel_mps2, latch,
                                         True)
        out_e[:, mode] = e.reshape(shape)
        out_t[:, mode] = np.where(stalled, TIME_INFEASIBLE_S, t).reshape(shape)
        out_j[:, mode] = en.reshape(shape)
    v_up = np.sqrt(2.0 * np.array([np.max(run.ceiling_e(np.linspace(a, b, 9)))
                                   for a, b in zip(bounds[:-1], bounds[1:])]))
    allowed = codes[None, :] <= v_up[:, None] + 1e-9
    # keep the lowest code at or above the section's highest useful speed as well
    first_above = np.argmax(codes[None, :] >= v_up[:, None] - 1e-9, axis=1)
    has_above = np.any(codes[None, :] >= v_up[:, None] - 1e-9, axis=1)
    allowed[np.arange(n_sections)[has_above], first_above[has_above]] = True
    allowed[~np.any(allowed, axis=1), 0] = True
    gbar = (run.grade_force_integral(bounds[1:]) - run.grade_force_integral(bounds[:-1])) \
        / (seg * run.train.mass_kg * G_MPS2)
    return SectionTables(run=run, bounds_s=bounds, codes_mps=codes, e_grid=e_grid,
                         e_out=out_e, time_s=out_t, energy_j=out_j, mean_grade=gbar,
                         code_allowed=allowed, substep_m=h, delta=float(delta))
