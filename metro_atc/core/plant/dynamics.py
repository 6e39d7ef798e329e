"""Longitudinal train dynamics: RK4 (seed 004) with the energy quadrature of each term.

``M_eff dv/dt = F_trac - F_brake - F_r(v) - F_grade - F_curve`` with
``M_eff = m + lambda m_nominal`` (rotary allowance on the tare+nominal mass; passengers add
non-rotating mass), Davis resistance (seed 002 eq. 1-2), grade and Roeckl curve resistance
averaged over the train length.  The efforts are held constant over a control period
(``substeps`` RK4 steps).  Trains never roll back: a sub-step that ends at or below zero
speed stops the train at the distance of a uniform deceleration to rest.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from metro_atc.core import laws
from metro_atc.core.line.geometry import LineGeometry
from metro_atc.core.line.vehicle import TrainParams

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

_cnz = np.count_nonzero


@dataclass
class StepMotion:
    """End state of one control period and the work of each force over it [m, m/s, J].

    ``clamped`` marks trains that came to rest inside the period (None if none did; trains
    that were already at rest and stay there need no correction and are not marked).
    """

    x1: FloatArray
    v1: FloatArray
    w_res: Any
    w_grade: Any
    w_curve: Any
    clamped: BoolArray | None


def rk4_motion(x: FloatArray, v: FloatArray, f_const: FloatArray, mass: FloatArray,
               meff: FloatArray, p: TrainParams, geom: LineGeometry, dt: float,
               substeps: int, cells: Any = None,
               coefs: tuple[Any, Any, Any] | None = None) -> StepMotion:
    """Integrate one control period with the constant effort ``f_const`` [N].

    ``f_const = F_trac - F_brake - A`` (Davis A); accelerations ``k(v) = q - v (cb + cc v)``
    with ``q = (F_const - F_g - F_c) / M_eff``.  ``cells``: the grid cells of ``x`` if the
    caller has them (``geom.cells(x)``; reused by the first sub-step); ``coefs``:
    ``(1 / meff, B / meff, C / meff)`` if precomputed (Davis B, C).
    """
    h = dt / substeps
    h2, h6 = 0.5 * h, h / 6.0
    if coefs is None:
        inv_m = 1.0 / meff
        coefs = (inv_m, p.davis_b_n_per_mps * inv_m, p.davis_c_n_per_mps2 * inv_m)
    inv_m, cb, cc = coefs
    xs, vs = x, v
    w_res: Any = 0.0
    w_grade: Any = 0.0
    w_curve: Any = 0.0
    clamped = None
    for s in range(substeps):
        kk = (cells if s == 0 and cells is not None
              else ((xs - geom.x0) * geom.inv_dx).astype(np.int64))
        f_g = mass * geom.gsin_avg[kk]
        f_c = mass * geom.curve_avg[kk]
        q = (f_const - f_g - f_c) * inv_m
        k1 = q - vs * (cb + cc * vs)
        v2 = vs + h2 * k1
        k2 = q - v2 * (cb + cc * v2)
        v3 = vs + h2 * k2
        k3 = q - v3 * (cb + cc * v3)
        v4 = vs + h * k3
        k4 = q - v4 * (cb + cc * v4)
        vn = vs + h6 * (k1 + 2.0 * (k2 + k3) + k4)
        dxs = h6 * (vs + 2.0 * (v2 + v3) + v4)
        # resistance work: Davis force = A + M_eff (q_A - k) with q_A = q + A / M_eff;
        # int F_r v dt by the same RK4 quadrature (the A term integrates to A dx)
        pr = ((q * dxs - h6 * (k1 * vs + 2.0 * (k2 * v2 + k3 * v3) + k4 * v4)) * meff
              + p.davis_a_n * dxs)
        stop = vn <= 0.0
        if _cnz(stop) and not _cnz(vs[stop]):
            # only trains already at rest (vs = 0): the branch below gives exactly
            # vn = 0, dx = 0, resistance work 0 (and the energy meter's stop correction is 0)
            vn = np.where(stop, 0.0, vn)
            dxs = np.where(stop, 0.0, dxs)
            pr = np.where(stop, 0.0, pr)
        elif _cnz(stop):
            # standstill reached (or kept) inside the sub-step: no roll-back; the distance
            # is that of a uniform deceleration to rest at the deceleration of the sub-step
            # start (exact for a constant deceleration), bounded by the distance covered at
            # constant speed
            vn = np.where(stop, 0.0, vn)
            d_stop = np.minimum(vs * vs / (-2.0 * np.minimum(k1, -1e-9)), h * vs)
            dxs = np.where(stop, d_stop, dxs)
            r1 = laws.on_array(laws.davis_resistance_array, vs, p.davis_a_n,
                               p.davis_b_n_per_mps, p.davis_c_n_per_mps2)
            pr = np.where(stop, r1 * d_stop, pr)
            clamped = stop if clamped is None else (clamped | stop)
        w_res = w_res + pr
        w_grade = w_grade + f_g * dxs
        w_curve = w_curve + f_c * dxs
        xs = xs + dxs
        vs = vn
    return StepMotion(xs, vs, w_res, w_grade, w_curve, clamped)
