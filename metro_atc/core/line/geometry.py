"""The line on a grid: stop points, limits, grades and curve resistance per cell (static).

A pure function of the scenario and the train length/maximum speed (see
:mod:`metro_atc.core.line.track` for the grid conventions): cell k covers
``[x0 + k dx, x0 + (k + 1) dx)``; ceilings are minima over a cell; grade and curve terms are
averaged over the train length behind the front (mass distributed along the train).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from metro_atc.core import laws
from metro_atc.core.line.rolling_stock import KMH
from metro_atc.core.line.scenario import Scenario, ScenarioError
from metro_atc.core.line.track import G, cell_min, curve_resistance_per_kg, step_profile
from metro_atc.core.line.vehicle import TrainParams

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


@dataclass(frozen=True)
class LineGeometry:
    """Grid and chainages of a line [m, m/s, -]; build with :func:`build_geometry`."""

    dx: float
    inv_dx: float
    x0: float
    n_cells: int
    grid_x: FloatArray
    length_m: float
    n_len: int
    station_positions_m: FloatArray
    x_first_stop: float
    x_last_stop: float
    x_end: float
    x_tail_stop: float
    x_switch: float
    n_sid: int
    eoa_end: float
    x_park: float
    static_limit: FloatArray
    grade_cell: FloatArray
    max_down: float
    sin_avg: FloatArray
    gsin_avg: FloatArray
    curve_avg: FloatArray
    ceiling_tol: float
    block_len: float
    tol_stop: float

    def cell(self, x: float) -> int:
        """Grid cell of chainage ``x`` [m], clipped to the grid."""
        return int(min(max((x - self.x0) / self.dx, 0), self.n_cells - 1))

    def cells(self, x: FloatArray) -> IntArray:
        """Grid cells of chainages ``x`` [m] (inside the grid by construction)."""
        return ((x - self.x0) * self.inv_dx).astype(np.int64)


def avg_behind(c: FloatArray, n_len: int) -> FloatArray:
    """Mean of ``c`` over the ``n_len`` cells ending at each cell (fewer at the start)."""
    cs = np.concatenate([[0.0], np.cumsum(c)])
    k = np.arange(c.size)
    lo = np.maximum(k + 1 - n_len, 0)
    return np.asarray((cs[k + 1] - cs[lo]) / (k + 1 - lo))


def build_geometry(scn: Scenario, p: TrainParams) -> LineGeometry:
    """Grid of limits, grades and curve resistance of ``scn`` for trains ``p``."""
    ln = scn.line
    length_m = float(p.length_m)
    stations = np.array([s.position_m for s in ln.stations], dtype=float)
    dx = float(scn.sim.grid_m)
    x_first_stop = float(stations[0])
    x_last_stop = float(stations[-1])
    x0 = x_first_stop - length_m - 500.0
    x_end = x_last_stop + ln.tail_track_m  # buffer stop
    x_tail_stop = x_end - 15.0
    x_switch = x_last_stop + 30.0
    if x_tail_stop - length_m <= x_switch + 10.0:
        raise ScenarioError(f"scenario {scn.source_file}: line.tail_track_m: expected >= "
                            f"train length + 55 m = {length_m + 55.0:g}, "
                            f"got {ln.tail_track_m:g}")
    n_cells = int(math.ceil((x_end + 200.0 - x0) / dx)) + 1
    nodes: FloatArray = x0 + dx * np.arange(n_cells + 1, dtype=float)
    lim = step_profile([s.start_m for s in ln.speed_limits],
                       [s.limit_kmh * KMH for s in ln.speed_limits],
                       ln.line_speed_kmh * KMH, nodes)
    lim = np.minimum(lim, p.max_speed_mps)
    lim = np.where(nodes > x_last_stop + 1.0, np.minimum(lim, ln.tail_speed_kmh * KMH), lim)
    grade = step_profile([g.start_m for g in ln.gradients],
                         [g.grade_permille / 1000.0 for g in ln.gradients], 0.0,
                         nodes[:-1] + 0.5 * dx)
    max_down = float(max(0.0, -float(np.min(grade)))) if grade.size else 0.0
    curv = np.zeros(n_cells)
    xc = nodes[:-1] + 0.5 * dx
    for c in ln.curves:
        m = (xc >= c.start_m) & (xc < c.end_m)
        curv[m] = curve_resistance_per_kg(c.radius_m)
    n_len = max(int(round(length_m / dx)), 1)
    sin_avg = avg_behind(laws.on_array(laws.grade_sine_array, grade), n_len)
    return LineGeometry(
        dx=dx, inv_dx=1.0 / dx, x0=x0, n_cells=n_cells, grid_x=nodes[:-1],
        length_m=length_m, n_len=n_len, station_positions_m=stations,
        x_first_stop=x_first_stop, x_last_stop=x_last_stop, x_end=x_end,
        x_tail_stop=x_tail_stop, x_switch=x_switch, n_sid=int(ln.turnback_sidings),
        eoa_end=x_end - 5.0, x_park=x_end + 100.0,  # parked trains stay inside the grid
        static_limit=cell_min(lim), grade_cell=grade, max_down=max_down, sin_avg=sin_avg,
        gsin_avg=G * sin_avg, curve_avg=avg_behind(curv, n_len),
        ceiling_tol=scn.signalling.overspeed_margin_kmh * KMH,
        block_len=float(ln.block_length_m), tol_stop=float(ln.stop_tolerance_m))
