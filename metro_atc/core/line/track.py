"""Line geometry on a grid and the ATP braking-curve mathematics (ROS-free, vectorised).

The line chainage x [m] is sampled on a uniform grid ``x_k = x0 + k dx``; grid cell k covers
``[x_k, x_k + dx)`` and every *ceiling* stored for a cell is the minimum over the cell, so a
lookup ``k = floor((x - x0) / dx)`` is conservative.

ATP supervision (Ke 2010, Fig. 1: response distance + guaranteed emergency-braking distance
+ safety margin).  Worst case assumed by ATP: during the response time ``t_r`` the train may
still accelerate at ``a_w`` (full traction plus the steepest downhill grade); afterwards it
decelerates at least at ``b_g`` (guaranteed emergency decel minus the steepest downhill).

* Emergency-brake intervention (EBI) speed for a distance ``D`` to a target where speed must
  be at most ``v_t`` (``v_t = 0`` for the end of authority):
  ``w = v + a_w t_r``, ``v t_r + a_w t_r^2 / 2 + (w^2 - v_t^2) / (2 b_g) <= D``, i.e.
  ``w = -b_g t_r + sqrt((b_g t_r)^2 + 2 b_g (D + a_w t_r^2 / 2) + v_t^2)``, ``v = w - a_w t_r``.
* Static speed-limit supervision: the braking envelope ``E(x)`` below the ceiling profile
  ``c(y)`` ahead, ``E(x)^2 = min_{y >= x} (c(y)^2 + 2 b_g (y - x))``, computed as a reversed
  cumulative minimum; the EBI speed is ``min_{y in [x, x + d_r]} E(y) - a_w t_r`` with the
  worst-case response distance ``d_r = v_max t_r + a_w t_r^2 / 2``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from metro_atc.core import laws

FloatArray = NDArray[np.float64]

G = laws.G_MPS2
"""Standard gravity [m/s^2] (:data:`metro_atc.core.laws.G_MPS2`)."""


class BrakingCurve:
    """The ATP braking curve of Ke 2010, Fig. 1 in closed form (the one implementation).

    ``v_ebi(D) = sqrt(c0 + c1 D + v_t^2) - c2`` with ``c0 = (b_g t_r)^2 + b_g t_r^2 a_w``,
    ``c1 = 2 b_g`` and ``c2 = b_g t_r + a_w t_r`` (module docstring; ``a_w`` may be an
    array, e.g. the worst-case response acceleration at each train's current speed).
    """

    def __init__(self, b_g: float, t_r: float) -> None:
        """Guaranteed deceleration ``b_g`` [m/s^2] and response time ``t_r`` [s]."""
        self.b_g, self.t_r = float(b_g), float(t_r)
        b, tr = self.b_g, self.t_r
        # laws.ebi_coef at a_w = 0, and the a_w coefficient of its c0
        self.c0a, self.c1, self.c2a = (float(c) for c in laws.ebi_coef(b, tr, 0.0))
        self.c0b = b * tr * tr

    def coef(self, a_w: ArrayLike) -> tuple[Any, Any]:
        """(c0, c2) for the response acceleration ``a_w`` [m/s^2]."""
        return self.c0a + self.c0b * a_w, self.c2a + self.t_r * a_w  # type: ignore[operator]

    def speed_from(self, c0: Any, c2: Any, dist_m: Any, below_mps: float = 0.0) -> FloatArray:
        """EBI speed [m/s] at ``dist_m`` [m] to a stop, ``below_mps`` lower, from :meth:`coef`."""
        if below_mps:
            c2 = c2 + below_mps
        return np.asarray(np.sqrt(np.maximum(c0 + self.c1 * dist_m, 0.0)) - c2)

    def speed(self, dist_m: ArrayLike, a_w: ArrayLike, target_mps: ArrayLike = 0.0,
              below_mps: float = 0.0) -> FloatArray:
        """EBI speed [m/s] for distance [m] to a point where speed must be <= target [m/s]."""
        c0, c2 = self.coef(a_w)
        vt = np.asarray(target_mps, dtype=float)
        if np.any(vt != 0.0):
            c0 = c0 + vt * vt
        return self.speed_from(c0, c2, np.asarray(dist_m, dtype=float), below_mps)


def ebi_speed(dist_m: ArrayLike, target_mps: ArrayLike, a_w: float, t_r: float,
              b_g: float) -> FloatArray:
    """EBI speed [m/s] for distance [m] to a point where speed must be <= target [m/s].

    Closed form of the Ke 2010, Fig. 1 construction (:class:`BrakingCurve`); negative
    results mean the train must already be stopped.
    """
    return BrakingCurve(b_g, t_r).speed(dist_m, a_w, target_mps)


def ebi_speed_at(dist_m: float, target_mps: float, a_w: float, t_r: float,
                 b_g: float) -> float:
    """:func:`ebi_speed` for one distance (plain floats, the same IEEE result) [m/s].

    The per-train ATO evaluates the curve a few times per control step:
    :func:`metro_atc.core.laws.ebi_speed`.
    """
    return float(laws.ebi_speed(dist_m, target_mps, a_w, t_r, b_g))


def stopping_distance(v_mps: ArrayLike, a_w: float, t_r: float, b_g: float) -> FloatArray:
    """Worst-case ATP stopping distance [m] from speed v (response + braking), inverse of EBI."""
    return np.asarray(laws.on_array(laws.stopping_distance_array, v_mps, a_w, t_r, b_g))


def step_profile(starts: ArrayLike, values: ArrayLike, default: float,
                 x: FloatArray) -> FloatArray:
    """Evaluate a step function (value i from starts[i] to starts[i+1]) at points x."""
    st = np.asarray(starts, dtype=float)
    va = np.asarray(values, dtype=float)
    if st.size == 0:
        return np.full_like(x, default)
    i = np.searchsorted(st, x, side="right") - 1
    out = va[np.clip(i, 0, va.size - 1)]
    return np.where(i < 0, default, out)


def cell_min(profile_at: FloatArray) -> FloatArray:
    """Per-cell minimum of a step profile sampled at grid nodes x_k (cell k = [x_k, x_k+1)).

    ``profile_at`` has one more sample than cells (node values incl. the right end); the
    minimum of the two ends bounds a step function that changes at most once per cell.
    """
    return np.minimum(profile_at[:-1], profile_at[1:])


def window_min_ahead(c: FloatArray, n: int) -> FloatArray:
    """out[k] = min(c[k .. k + n]) (window clipped at the array end), exact, O(N log n)."""
    out = np.array(c, dtype=float, copy=True)
    span = 1  # invariant: out[k] = min c[k .. k + span - 1]
    while span < n + 1:
        step = min(span, n + 1 - span)
        shifted = np.empty_like(out)
        shifted[:-step] = out[step:]
        shifted[-step:] = out[-1]
        np.minimum(out, shifted, out=out)
        span += step
    return out


def window_min_behind(c: FloatArray, n: int) -> FloatArray:
    """out[k] = min(c[k - n .. k]) (the train occupies n cells behind its front)."""
    return window_min_ahead(np.asarray(c, dtype=float)[::-1], n)[::-1].copy()


def braking_envelope(ceiling: FloatArray, dx: float, b: float) -> FloatArray:
    """Envelope E_k = min_{j >= k} sqrt(c_j^2 + 2 b (j - k) dx) [m/s] (reverse cumulative min).

    ``ceiling[j]`` is the speed ceiling of cell j [m/s]; the train front entering cell j must
    be at or below it.  E is what a train braking at ``b`` [m/s^2] can have at cell k.
    """
    j = np.arange(ceiling.size, dtype=float) * dx
    q = ceiling * ceiling + 2.0 * b * j
    qmin = np.minimum.accumulate(q[::-1])[::-1]
    return np.sqrt(np.maximum(qmin - 2.0 * b * j, 0.0))


def curve_resistance_per_kg(radius_m: ArrayLike) -> FloatArray:
    """Curve resistance [N/kg] by the Roeckl formula (standard gauge).

    w_r [N/kN] = 650 / (R - 55) for R >= 300 m, 500 / (R - 30) below (R in m).
    """
    return np.asarray(laws.on_array(laws.curve_resistance_per_kg_array, radius_m))
