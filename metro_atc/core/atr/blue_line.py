"""Taipei Metro Blue (Bannan) line description for automatic train regulation (ROS-free).

Self-contained line data for the ATR core (Lin 2010a, Experiment 2: "Taipei metro Blue line,
initial delay 180 s at the first station, peak headway 105 s"). The seed's pages that describe
the experiment data (page 8 of the report) are missing from the extraction, so every number
below is an *engineering estimate* documented here; none is taken from the seed except the
peak headway of 105 s (Lin 2010a, Exp. 2 text) and the six-duration daily split (Lin 2010a,
Fig. 2).

Sources and estimates
---------------------
- Stations BL01 Dingpu .. BL23 Taipei Nangang Exhibition Center (23 stations, 22 runs),
  direction Dingpu -> Nangang Exhibition Center.
- Inter-station distances: relative spacing estimated from public route maps (the long run
  is BL09 Jiangzicui -> BL10 Longshan Temple under the Tamsui river), then scaled so that the
  mean spacing is 1.28 km (project brief), i.e. 28.2 km in total.  Uncertainty ~ +-200 m.
- Minimum running time: flat-out run (trapezoidal profile) with line speed 80 km/h,
  acceleration 1.0 m/s^2 and service braking 1.0 m/s^2 (Blue line EMU class, estimate).
- Scheduled running time: minimum time plus a 7 % running-time supplement (recovery margin,
  typical metro practice, UIC 451-1 order of magnitude).  Maximum running time: +15 %
  (coasting); longer runs are not used for regulation.
- Dwell: a fixed part S_j = 20 s (door cycle + dispatch) that can be cut to 15 s, plus the
  passenger boarding part t_b * p_j * h (Lin 2010a, eq. 4-5 via c_j = t_b p_j, see
  :mod:`metro_atc.core.atr.traffic`); holding at a platform is limited to +60 s per stop.
- Passenger boarding rates p_j (pax/h, peak direction, AM peak): estimates from station
  rank (Taipei Main Station and Banqiao busiest); t_b = 0.06 s per boarding passenger for a
  six-car train (about 1.5 s per passenger and door channel over 24 channels).
- Truth-model crowding: boarding slows by up to 50 % when the gap since the previous train
  doubles; a train takes at most 45 s of boarding (about 750 boarders at t_b, i.e. a
  six-car train (~1900 places) arriving well loaded).
- Minimum platform re-occupation separation: 60 s from a departure until the follower may
  arrive (90 s technical headway with about 30 s dwell), which produces knock-on delays.
- Disturbances: departure delays are exponential (Lin 2010a, sec. 2, refs [3, 8]); mean 1 s
  per stop (estimate).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import List, Tuple

import numpy as np

STATION_CODES: Tuple[str, ...] = tuple(f"BL{i:02d}" for i in range(1, 24))
STATION_NAMES: Tuple[str, ...] = (
    "Dingpu", "Yongning", "Tucheng", "Haishan", "Far Eastern Hospital", "Fuzhong",
    "Banqiao", "Xinpu", "Jiangzicui", "Longshan Temple", "Ximen", "Taipei Main Station",
    "Shandao Temple", "Zhongxiao Xinsheng", "Zhongxiao Fuxing", "Zhongxiao Dunhua",
    "Sun Yat-Sen Memorial Hall", "Taipei City Hall", "Yongchun", "Houshanpi", "Kunyang",
    "Nangang", "Taipei Nangang Exhibition Center",
)
# relative spacing estimates [km] before scaling to the 1.28 km mean (see module docstring)
_REL_SPACING_KM = (1.7, 1.2, 1.2, 1.5, 1.0, 0.9, 1.2, 1.1, 2.3, 1.0, 0.9, 0.9, 0.9, 1.2,
                   0.9, 0.9, 0.8, 1.0, 1.2, 1.4, 1.6, 1.3)
# boarding rate estimates [passengers / hour] towards Nangang Exhibition Center, AM peak
_BOARDING_PAX_H = (2500, 2000, 2500, 2000, 2500, 3000, 5000, 2500, 2000, 3000, 4000, 6000,
                   2000, 3000, 4000, 3000, 2500, 3500, 2000, 1500, 1500, 1000, 0)
MEAN_SPACING_M = 1280.0
PEAK_HEADWAY_S = 105.0


def min_running_time(distance_m: np.ndarray, v_max: float = 80.0 / 3.6,
                     accel: float = 1.0, decel: float = 1.0) -> np.ndarray:
    """Flat-out (minimum) running time [s] of a trapezoidal/triangular speed profile.

    distance_m [m], v_max [m/s], accel and decel [m/s^2]; returns seconds.
    """
    d = np.asarray(distance_m, dtype=float)
    d_ramp = v_max ** 2 / (2.0 * accel) + v_max ** 2 / (2.0 * decel)
    t_trap = d / v_max + v_max / (2.0 * accel) + v_max / (2.0 * decel)
    # triangular profile when the line speed is never reached
    v_peak = np.sqrt(2.0 * d * accel * decel / (accel + decel))
    t_tri = v_peak / accel + v_peak / decel
    return np.where(d >= d_ramp, t_trap, t_tri)


@dataclass(frozen=True)
class Period:
    """One duration of the daily operation (Lin 2010a, eq. 7-8, Fig. 2).

    start_s/end_s: boundaries z_{n-1}, z_n [s after midnight]; headway_s: H_n [s];
    flow_factor: passenger flow of the duration relative to the AM peak [-].
    """

    start_s: float
    end_s: float
    headway_s: float
    flow_factor: float


def default_periods() -> List[Period]:
    """Six daily durations like Lin 2010a, Fig. 2, from the shipped day table.

    The periods (start, end [s], headway [s], up-direction flow factor [-]) are read from
    ``metro_atc/data/taipei_blue_day_periods.yaml`` (the service day's table; its entries say
    which values are estimates), so the regulator's TSK model and the day agree by construction.
    """
    from importlib import resources

    from metro_atc.core.safe_yaml import load_yaml_file
    raw = load_yaml_file(str(resources.files("metro_atc").joinpath(
        "data", "taipei_blue_day_periods.yaml")))
    h = 3600.0
    return [Period(float(p["start_h"]) * h, float(p["end_h"]) * h, float(p["headway_s"]),
                   float(p["flow_up"])) for p in raw["periods"]]


@dataclass(frozen=True)
class LineData:
    """Parameters of a one-direction metro line for the ATR traffic model (SI units).

    Arrays are indexed by station j = 0..N-1 (``run_*`` by run j -> j+1, length N-1).
    """

    name: str
    station_codes: Tuple[str, ...]
    station_names: Tuple[str, ...]
    distance_m: np.ndarray          # (N-1,) inter-station distances [m]
    run_s: np.ndarray               # (N-1,) scheduled running times R_j [s]
    run_min_s: np.ndarray           # (N-1,) minimum running times [s]
    run_max_s: np.ndarray           # (N-1,) maximum running times used by regulation [s]
    dwell_fixed_s: np.ndarray       # (N,) fixed dwell part S_j [s]
    dwell_fixed_min_s: np.ndarray   # (N,) minimum fixed dwell part [s]
    hold_max_s: float               # maximum extra holding at one stop [s]
    boarding_pax_h: np.ndarray      # (N,) peak boarding rate p_j [pax/h]
    t_board_s: float                # boarding time per passenger t_b [s/pax]
    headway_s: float                # scheduled (peak) headway H [s]
    separation_min_s: float         # min time departure -> next arrival at a platform [s]
    disturbance_mean_s: float       # mean of the exponential departure delay [s]
    crowding_gain: float            # truth: relative boarding slow-down per unit excess gap
    board_max_s: float              # truth: boarding time of a full train [s]
    periods: Tuple[Period, ...] = field(default_factory=tuple)

    @property
    def n_stations(self) -> int:
        """Number of stations N."""
        return len(self.station_codes)

    def c(self, flow_factor: float = 1.0) -> np.ndarray:
        """Dimensionless boarding coefficients c_j = t_b * p_j (Lin 2010a, eq. 9), shape (N,)."""
        return self.t_board_s * self.boarding_pax_h * flow_factor / 3600.0


def taipei_blue() -> LineData:
    """Return the Taipei Metro Blue line (BL01 Dingpu .. BL23) description (estimates)."""
    rel = np.asarray(_REL_SPACING_KM, dtype=float)
    dist = rel / rel.mean() * MEAN_SPACING_M
    r_min = min_running_time(dist)
    n = len(STATION_CODES)
    return LineData(
        name="taipei_blue",
        station_codes=STATION_CODES,
        station_names=STATION_NAMES,
        distance_m=dist,
        run_s=np.round(1.07 * r_min, 1),
        run_min_s=np.round(r_min, 1),
        run_max_s=np.round(1.15 * r_min, 1),
        dwell_fixed_s=np.full(n, 20.0),
        dwell_fixed_min_s=np.full(n, 15.0),
        hold_max_s=60.0,
        boarding_pax_h=np.asarray(_BOARDING_PAX_H, dtype=float),
        t_board_s=0.06,
        headway_s=PEAK_HEADWAY_S,
        separation_min_s=60.0,
        disturbance_mean_s=1.0,
        crowding_gain=0.5,
        board_max_s=45.0,
        periods=tuple(default_periods()),
    )


def small_line(n: int = 3, headway_s: float = 120.0) -> LineData:
    """Return a small synthetic n-station line with round numbers (for tests and examples)."""
    return LineData(
        name=f"small{n}",
        station_codes=tuple(f"S{i}" for i in range(n)),
        station_names=tuple(f"Station {i}" for i in range(n)),
        distance_m=np.full(n - 1, 1000.0),
        run_s=np.full(n - 1, 80.0),
        run_min_s=np.full(n - 1, 74.0),
        run_max_s=np.full(n - 1, 92.0),
        dwell_fixed_s=np.full(n, 20.0),
        dwell_fixed_min_s=np.full(n, 15.0),
        hold_max_s=60.0,
        boarding_pax_h=np.full(n, 3000.0),
        t_board_s=0.06,
        headway_s=headway_s,
        separation_min_s=60.0,
        disturbance_mean_s=1.0,
        crowding_gain=0.5,
        board_max_s=45.0,
        periods=(Period(0.0, 86400.0, headway_s, 1.0),),
    )
