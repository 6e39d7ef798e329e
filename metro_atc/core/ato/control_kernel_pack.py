"""Loading and packing of the compiled ATO control step (:mod:`.control_kernel_step`).

:class:`metro_atc.core.ato.onboard.OnboardAto` takes every control step there (no switch,
no other path: numba is a pinned dependency; ``NUMBA_DISABLE_JIT=1`` runs the same source
as Python).  The vectors the kernel reads are packed here from plain floats and arrays the
objects hand over through their public methods (``AtoCore.kernel_constants`` /
``kernel_plan``, ``AtpModel.kernel_fields`` / ``sbi_table``, ``OnboardAto``'s own
tables).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
from numpy.typing import NDArray

from metro_atc.core.ato import control_kernel as ck
from metro_atc.core.ato.step_kernel import TRACTION_FIELDS, train_fields
from metro_atc.core.line.vehicle import TrainParams

FloatArray = NDArray[np.float64]

ATP_FIELDS = ck.CONSTANT_FIELDS[ck.CONSTANT_FIELDS.index("g_down"):
                                ck.CONSTANT_FIELDS.index("b_g") + 1]
"""The ATP's fields of :data:`.control_kernel.CONSTANTS`, in :func:`pack_constants`' order."""
CORE_FIELDS = ck.CONSTANT_FIELDS[ck.CONSTANT_FIELDS.index("period"):]
"""The controller's fields of :data:`.control_kernel.CONSTANTS` (``AtoCore.kernel_constants``)."""


def pack_constants(train: TrainParams, atp_train: TrainParams, core: Sequence[float],
                   atp: Sequence[float]) -> FloatArray:
    """The constants vector (float64, read as :data:`.control_kernel.CONSTANTS` by the kernel).

    ``core``: (period [s], swing [s], effort rate [1/s], brake share [-], approach jerk
    [m/s^3], feedforward 0/1, fuzzy e scale [m/s], d scale [m/s], gain [-], tracker, kp
    [1/(m/s)], ki [1/m], restriction lead [m], TSR speed margin [m/s], accel limit [m/s^2]);
    ``atp``: (g_down [m/s^2], SBI offset [m/s], (b_g t_r)^2, b_g t_r, b_g t_r t_r, t_r [s],
    2 b_g, t_sbi [s], grid x0 [m], grid dx [m], ceiling tolerance [m/s], response and SBI
    look-ahead distances [m], b_g [m/s^2]).
    """
    if len(core) != len(CORE_FIELDS) or len(atp) != len(ATP_FIELDS):
        raise ValueError("inconsistent ATO kernel constants")
    c = np.zeros(1, dtype=ck.CONSTANTS)
    r = c[0]
    for name, val in train_fields(train):
        r[name] = val
    r["brake_service"] = train.max_service_brake_mps2
    r["length"] = train.length_m
    for name, val in zip(TRACTION_FIELDS, atp_train.traction_law):
        r["w_" + name] = val
    for name, val in zip(ATP_FIELDS + CORE_FIELDS, list(atp) + list(core)):
        r[name] = float(val)
    return c.view(np.float64)


def pack_plan(head: Sequence[float], ref_s: FloatArray, ref_e: FloatArray,
              grade_bp: FloatArray, grade_cum: FloatArray, s_env: FloatArray,
              e_ceiling: FloatArray, b_tab: FloatArray) -> FloatArray:
    """The plan vector: ``head`` (the ``PLAN`` fields up to ``creep_speed``), counts, tables."""
    tabs = (ref_s, ref_e, grade_bp, grade_cum, s_env, e_ceiling, b_tab)
    hdr = [float(a) for a in head] + [float(len(ref_s)), float(len(grade_bp)),
                                      float(len(s_env)), float(len(b_tab))]
    if len(hdr) != ck.N_PH or len(ref_s) != len(ref_e) or len(grade_bp) != len(grade_cum) \
            or len(s_env) != len(e_ceiling) or min(len(ref_s), len(grade_bp), len(s_env),
                                                   len(b_tab)) < 1:
        raise ValueError("inconsistent ATO kernel plan tables")
    return np.concatenate([np.asarray(hdr, dtype=float)]
                          + [np.asarray(a, dtype=float).ravel() for a in tabs])


def pack_line(sbi: FloatArray, grade_starts: FloatArray, grades: FloatArray,
              stations: FloatArray, tsrs: FloatArray) -> FloatArray:
    """The line vector: counts, static SBI table [m/s], grade starts [m], grades, stops [m].

    Then the TSRs ``tsrs`` (n, 5): start [m], end [m], limit [m/s], known from [s], until [s].
    """
    tz = np.asarray(tsrs, dtype=float).reshape(-1, 5)
    if len(sbi) < 1 or len(grades) < 1 or len(grade_starts) != len(grades):
        raise ValueError("inconsistent ATO kernel line tables")
    return np.concatenate([np.asarray([len(sbi), len(grades), len(stations), len(tz)],
                                      dtype=float),
                           np.asarray(sbi, dtype=float), np.asarray(grade_starts, dtype=float),
                           np.asarray(grades, dtype=float), np.asarray(stations, dtype=float),
                           tz.ravel()])


_LOADED: list[bool] = []


def control_step_fn():  # type: ignore[no-untyped-def]
    """The compiled :func:`.control_kernel_step.control_step` (imported on first use).

    Its one type signature is loaded from the on-disk cache (compiled at install) here,
    once per process, so that a node pays it while it starts, not in its first step.
    """
    from metro_atc.core.ato.control_kernel_step import control_step
    if not _LOADED and hasattr(control_step, "compile"):
        from numba import types
        arr = types.float64[::1]
        control_step.compile((arr, arr, arr, arr) + (types.float64,) * 5 + (types.int64,))
        _LOADED.append(True)
    return control_step


def sbi_speed_to_fn():  # type: ignore[no-untyped-def]
    """The compiled :func:`.control_kernel_step.sbi_speed_of` (constants, distance, target)."""
    from metro_atc.core.ato.control_kernel_step import sbi_speed_of
    return sbi_speed_of
