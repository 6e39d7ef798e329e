"""The scheduled service of a scenario: dispatch, dwell and running times (Lin 2010a, eq. 10).

A pure function of the scenario (no plant): the ATS, the ATO and the line simulator build
the same deterministic timetable from the same scenario file.  Minimum running times are the
flat-out runs on the driving envelope (the reference driver's service-brake envelope of
limit - 2 km/h at ``B_DRIVE_FRACTION`` of the maximum service brake); scheduled running
times add the scenario's running-time margin.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from metro_atc.core.line.geometry import LineGeometry, build_geometry
from metro_atc.core.line.rolling_stock import KMH, train_params_for
from metro_atc.core.line.scenario import Scenario
from metro_atc.core.line.timetable import (PassengerFlow, dispatch_times, nominal_dwells,
                                           schedule)
from metro_atc.core.line.track import G, braking_envelope, window_min_behind
from metro_atc.core.line.vehicle import TrainParams, max_traction_accel, resistance_force

FloatArray = NDArray[np.float64]

B_DRIVE_FRACTION = 0.6
"""Braking of the reference driver and of the timetable, share of the max service brake."""


def drive_envelope(geom: LineGeometry, lim: FloatArray, b_drive: float) -> FloatArray:
    """Service-brake envelope [m/s] of (per-cell limit ``lim`` - 2 km/h) at ``b_drive``."""
    target = np.maximum(window_min_behind(lim, geom.n_len) - 2.0 * KMH, 1.0)
    return braking_envelope(target, geom.dx, b_drive)


def min_running_times(p: TrainParams, geom: LineGeometry, drive_env: FloatArray,
                      b_drive: float) -> FloatArray:
    """Flat-out running time per inter-station section [s] on the driving envelope.

    Forward pass ``v_{k+1}^2 = v_k^2 + 2 a(v_k) dx`` with full traction minus resistance
    and grade, capped by the driving envelope (limits and braking to the stop point); the
    sections are independent and run side by side (one vector operation per grid cell).
    """
    dx = geom.dx
    pos = geom.station_positions_m
    m = p.mass_kg
    meff = m + p.rotary_allowance * p.mass_kg
    n_sec = pos.size - 1
    k0 = np.array([geom.cell(float(pos[j])) for j in range(n_sec)], dtype=np.int64)
    k1 = np.array([geom.cell(float(pos[j + 1])) for j in range(n_sec)], dtype=np.int64)
    lens = k1 - k0
    n_max = int(lens.max()) if n_sec else 0
    cap = np.full((n_sec, n_max + 1), np.inf)
    res = np.zeros((n_sec, n_max + 1))  # (sin + curve) averages of the cells
    for j in range(n_sec):
        sl = slice(int(k0[j]), int(k1[j]) + 1)
        cap[j, :lens[j] + 1] = np.minimum(drive_env[sl], np.sqrt(
            2.0 * b_drive * np.maximum(pos[j + 1] - geom.grid_x[sl], 0.0)))
        res[j, :lens[j] + 1] = geom.sin_avg[sl] + geom.curve_avg[sl]
    v = np.zeros(n_sec)
    tsum = np.zeros(n_sec)
    for k in range(n_max):
        fa = (m * max_traction_accel(p, v) - resistance_force(p, v) - m * G * res[:, k]) / meff
        v2 = np.sqrt(np.maximum(v * v + 2.0 * np.maximum(fa, 0.0) * dx, 0.0))
        v2 = np.minimum(v2, cap[:, k + 1])
        act = k < lens
        tsum = np.where(act, tsum + 2.0 * dx / np.maximum(v + v2, 0.05), tsum)
        v = np.where(act, v2, v)
    return tsum


@dataclass(frozen=True)
class ServicePlan:
    """Timetable of a scenario [s]; rows are trains, columns stations.

    ``sched_arr``/``sched_dep``: scheduled arrival/departure; ``sched_dwell[j]`` nominal
    dwell; ``min_running_s``/``sched_running_s`` per section; ``dispatch`` departure times
    from the first station; ``alight_frac`` share of the load alighting per station (1 at the
    terminus); ``b_drive`` the driving-envelope deceleration [m/s^2].
    """

    train_ids: list[str]
    station_names: list[str]
    station_codes: list[str]
    flow: PassengerFlow
    headways: list[float]
    alight_frac: FloatArray
    sched_dwell: FloatArray
    dispatch: FloatArray
    b_drive: float
    min_running_s: FloatArray
    sched_running_s: FloatArray
    sched_arr: FloatArray
    sched_dep: FloatArray


def build_service(scn: Scenario, p: TrainParams, geom: LineGeometry) -> ServicePlan:
    """Dispatch times, minimum and scheduled running times, dwells (Lin 2010a, eq. 10)."""
    per = scn.timetable.periods
    flow = PassengerFlow([q.start_s for q in per],
                         np.array([q.boarding_pph for q in per], dtype=float))
    headways = [q.headway_s for q in per]
    ps = scn.passengers
    alight_frac = np.array(ps.alight_fraction, dtype=float)
    alight_frac[-1] = 1.0
    sched_dwell, _ = nominal_dwells(
        flow, headways, alight_frac, p.capacity_pax, scn.trains.initial_load_pax,
        ps.boarding_s_per_pax, ps.alighting_s_per_pax, ps.door_overhead_s, ps.min_dwell_s)
    dispatch = dispatch_times(scn.timetable.first_departure_s, scn.trains.count, flow,
                              headways)
    b_drive = B_DRIVE_FRACTION * p.max_service_brake_mps2
    env = drive_envelope(geom, geom.static_limit, b_drive)
    min_rt = min_running_times(p, geom, env, b_drive)
    sched_rt = min_rt * (1.0 + scn.timetable.running_time_margin)
    arr, dep = schedule(dispatch, sched_dwell, sched_rt, flow)
    st = scn.line.stations
    return ServicePlan(list(scn.train_ids), [s.name for s in st], [s.code for s in st], flow,
                       headways, alight_frac, sched_dwell, dispatch, b_drive, min_rt,
                       sched_rt, arr, dep)


@dataclass(frozen=True)
class LineDescription:
    """Everything static about a scenario's line: rolling stock, geometry, service."""

    scn: Scenario
    params: TrainParams
    geometry: LineGeometry
    service: ServicePlan


def describe(scn: Scenario, params: TrainParams | None = None) -> LineDescription:
    """The static description of ``scn`` (``params`` replaces its rolling stock)."""
    p = params if params is not None else train_params_for(scn)
    geom = build_geometry(scn, p)
    return LineDescription(scn, p, geom, build_service(scn, p, geom))


@dataclass(frozen=True)
class Timetable:
    """The scenario's timetable; times are simulation seconds.

    ``departure_s[i, j]``/``arrival_s[i, j]``: scheduled departure/arrival of train i at
    station j; ``running_s[j]``: scheduled running time from station j to j+1;
    ``dwell_s[i, j]`` scheduled dwell; ``min_running_s[j]`` flat-out
    running time.
    """

    train_ids: list[str]
    station_names: list[str]
    station_positions_m: FloatArray
    departure_s: FloatArray
    arrival_s: FloatArray
    running_s: FloatArray
    min_running_s: FloatArray
    dwell_s: FloatArray


def timetable_for(scn: Scenario) -> Timetable:
    """Scheduled departures, running and dwell times of a scenario (Lin 2010a, eq. 10)."""
    d = describe(scn)
    sv = d.service
    dep = np.asarray(sv.sched_dep, dtype=float)
    arr = np.asarray(sv.sched_arr, dtype=float)
    dwell = np.where(np.isfinite(dep - arr), dep - arr, 0.0)
    return Timetable(list(sv.train_ids), list(sv.station_names),
                     np.asarray(d.geometry.station_positions_m, dtype=float), dep, arr,
                     np.asarray(sv.sched_running_s, dtype=float),
                     np.asarray(sv.min_running_s, dtype=float), dwell)
