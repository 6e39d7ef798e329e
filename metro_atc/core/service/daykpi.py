"""Key performance indicators of a service day, from its records (ROS-free, SI units).

Input: the :mod:`metro_atc.core.service.records` of a day (stop calls, turnbacks, depot
moves) and its :class:`metro_atc.core.service.day.DayPlan`; optionally the energy of each
trip [J].  Output: a JSON-able dict (:func:`day_kpis`, for ``kpis.json``) and a plain-text
table per period (:func:`kpi_table`).

Definitions (per period of the plan and per direction; a call belongs to the period of its
scheduled departure, a trip to that of its scheduled departure from the origin):

- ``punctuality``: share of departures at most ``PUNCTUAL_S`` (60 s) late against the
  timetable -- the definition of the line simulator's KPIs
  (:data:`metro_atc.core.plant.kpi.PUNCTUAL_S`, imported, not copied); departures that did
  not happen are not counted (they show in ``trips_run`` against ``trips_planned``);
- ``schedule_deviation_s``: mean, RMS and max of actual minus scheduled departure, the
  schedule-deviation term x = t - T of the Lin 2010a cost (eq. 17);
- ``headway_deviation_s``: RMS of actual minus scheduled headway between consecutive
  departures (ordered by timetable) at each station, the headway term of Lin 2010a's
  indices (Exp. 2);
- ``headway_cv``: coefficient of variation std/mean of the actual headways at each station
  (departures sorted by actual instant, at least 3 per station), mean and max over the
  stations -- 0 for a perfectly regular service, but > 0 for a timetable whose headway
  changes inside the period (the transitions between periods); hence also
  ``headway_ratio_cv_mean``: the same on actual / scheduled headway (timetable order), 0
  for a service that runs to its timetable (shown in the table as ``irr``);
- ``trips_planned`` (the plan's trips) and ``trips_run`` (trips whose destination arrival
  was recorded);
- turnbacks: terminal delay (arrival delay of the ended trip), buffer (scheduled layover
  minus minimum turnback; Lin 2010a, Exp. 2: 210 s at 105 s), delay carried into the next
  trip (its departure delay, >= 0), whether the buffer absorbed the delay; per period (of
  the arrival) and per terminus;
- fleet in service per period from the depot moves: trains out of the depot (pull-out to
  pull-in), maximum and time-weighted mean over the period;
- energy per direction and period [kWh] from an optional trip -> energy [J] mapping.

Records that cannot be used (unknown direction, non-finite scheduled departure of a call
that should have one) are counted in ``rejected_records`` and otherwise ignored.
"""

from __future__ import annotations

import math
from typing import Any, Dict, List, Mapping, Optional, Sequence, Tuple

import numpy as np

from metro_atc.core.plant.kpi import J_PER_KWH, PUNCTUAL_S
from metro_atc.core.service.day import DayPlan, period_index, trips as plan_trips
from metro_atc.core.service.records import (DEPOT_MOVES, DIRECTIONS, DepotRecord,
                                            StopRecord, TurnbackRecord)

MIN_HEADWAYS_CV = 2
"""Fewest actual headways at a station for its coefficient of variation [-]."""


def _f(x: float) -> Optional[float]:
    return float(x) if math.isfinite(x) else None


def _stats(a: Sequence[float]) -> Dict[str, Optional[float]]:
    v = np.asarray(a, dtype=float)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return {"mean": None, "rms": None, "max": None}
    return {"mean": float(v.mean()), "rms": float(np.sqrt(np.mean(v * v))),
            "max": float(v.max())}


def fleet_profile(depot: Sequence[DepotRecord]) -> Tuple[np.ndarray, np.ndarray, int]:
    """Step function of the trains in service: (instants [s], count after each, unmatched).

    ``unmatched``: pull-ins of a train not out of the depot (then ignored).
    """
    out: Dict[str, int] = {}
    ts: List[float] = []
    ns: List[int] = []
    bad = 0
    n = 0
    for r in sorted(depot, key=lambda r: (r.t_s, r.kind != "pull_in", r.train)):
        if r.kind not in DEPOT_MOVES or not math.isfinite(r.t_s):
            bad += 1
            continue
        if r.kind == "pull_out":
            out[r.train] = out.get(r.train, 0) + 1
            n += 1
        elif out.get(r.train, 0) > 0:
            out[r.train] -= 1
            n -= 1
        else:
            bad += 1
            continue
        ts.append(r.t_s)
        ns.append(n)
    return np.asarray(ts, dtype=float), np.asarray(ns, dtype=int), bad


def _fleet_in(ts: np.ndarray, ns: np.ndarray, a: float, b: float) -> Tuple[int, float]:
    """Max and time-weighted mean of the in-service step function over [a, b)."""
    before = ts < a
    n0 = int(ns[before][-1]) if before.any() else 0
    inside = (ts >= a) & (ts < b)
    edges = np.concatenate([[a], ts[inside], [b]])
    vals = np.concatenate([[n0], ns[inside]])
    mx = int(vals.max())
    mean = float(np.sum(vals * np.diff(edges)) / (b - a)) if b > a else float(n0)
    return mx, mean


def _headway_terms(calls: List[StopRecord]
                   ) -> Tuple[List[float], List[float], List[float]]:
    """Headway deviations, per-station CVs of actual headways and of their ratio to plan."""
    by_st: Dict[int, List[StopRecord]] = {}
    for r in calls:
        by_st.setdefault(r.station, []).append(r)
    devs: List[float] = []
    cvs: List[float] = []
    rcvs: List[float] = []
    for rs in by_st.values():
        rs = sorted(rs, key=lambda r: r.sched_dep_s)
        sd = np.asarray([r.sched_dep_s for r in rs])
        ad = np.asarray([r.dep_s for r in rs])
        ok = np.isfinite(ad)
        h_dev = np.diff(ad) - np.diff(sd)
        devs.extend(h_dev[np.isfinite(h_dev)].tolist())
        h = np.diff(np.sort(ad[ok]))
        if h.size >= MIN_HEADWAYS_CV and h.mean() > 0.0:
            cvs.append(float(h.std() / h.mean()))
        hs = np.diff(sd)
        ratio = (np.diff(ad) / np.where(hs > 0.0, hs, math.nan))
        ratio = ratio[np.isfinite(ratio)]
        if ratio.size >= MIN_HEADWAYS_CV and ratio.mean() > 0.0:
            rcvs.append(float(ratio.std() / ratio.mean()))
    return devs, cvs, rcvs


def day_kpis(plan: DayPlan, stops: Sequence[StopRecord],
             turnbacks: Sequence[TurnbackRecord], depot: Sequence[DepotRecord],
             energy_j: Optional[Mapping[str, float]] = None) -> Dict[str, Any]:
    """KPIs of a day (module docstring); a JSON-able dict (None for what is undefined)."""
    periods = plan.periods
    rejected = 0
    calls: Dict[Tuple[int, str], List[StopRecord]] = {}
    trip_dir: Dict[str, str] = {}
    trip_origin_sched: Dict[str, float] = {}
    arrived: set[str] = set()
    for r in stops:
        if r.direction not in DIRECTIONS:
            rejected += 1
            continue
        trip_dir[r.trip_id] = r.direction
        if math.isfinite(r.sched_dep_s):
            n = period_index(periods, r.sched_dep_s)
            calls.setdefault((n, r.direction), []).append(r)
            if not math.isfinite(r.sched_arr_s):       # the origin call
                trip_origin_sched[r.trip_id] = r.sched_dep_s
        elif math.isfinite(r.sched_arr_s):              # the destination call
            if math.isfinite(r.arr_s):
                arrived.add(r.trip_id)
        else:
            rejected += 1
    planned: Dict[Tuple[int, str], int] = {}
    for t in plan_trips(plan):
        d = "up" if t.origin == plan.termini[0].station else "down"
        key = (period_index(periods, t.departure_s), d)
        planned[key] = planned.get(key, 0) + 1
    run: Dict[Tuple[int, str], int] = {}
    for tid in arrived:
        if tid in trip_origin_sched:
            key = (period_index(periods, trip_origin_sched[tid]), trip_dir[tid])
            run[key] = run.get(key, 0) + 1
    en: Dict[Tuple[int, str], float] = {}
    en_missing = 0
    if energy_j is not None:
        for tid, e in energy_j.items():
            if tid not in trip_origin_sched or not math.isfinite(float(e)):
                en_missing += 1
                continue
            key = (period_index(periods, trip_origin_sched[tid]), trip_dir[tid])
            en[key] = en.get(key, 0.0) + float(e)
    ts, ns, unmatched = fleet_profile(depot)
    tb_rows: List[Dict[str, Any]] = []
    for tb in turnbacks:
        delay = tb.terminal_delay_s
        carried = tb.carried_delay_s
        per = periods[period_index(periods, tb.sched_arr_s)].name
        tb_rows.append({
            "train": tb.train, "terminus": tb.terminus, "arr_trip": tb.arr_trip_id,
            "dep_trip": tb.dep_trip_id, "period": per,
            "terminal_delay_s": _f(delay), "buffer_s": _f(tb.buffer_s),
            "carried_delay_s": _f(carried),
            "absorbed": bool(math.isfinite(carried) and carried <= 0.0),
            "layover_s": _f(tb.dep_s - tb.arr_s),
        })
    rows = []
    for n, p in enumerate(periods):
        fmax, fmean = _fleet_in(ts, ns, p.start_s, p.end_s) if ts.size else (0, 0.0)
        per_dir: Dict[str, Any] = {}
        for d in DIRECTIONS:
            cs = calls.get((n, d), [])
            dev = np.asarray([r.departure_delay_s for r in cs], dtype=float)
            ok = np.isfinite(dev)
            h_dev, cvs, rcvs = _headway_terms(cs)
            per_dir[d] = {
                "departures": int(ok.sum()),
                "punctuality": float(np.mean(dev[ok] <= PUNCTUAL_S)) if ok.any() else None,
                "schedule_deviation_s": _stats(dev[ok].tolist()),
                "headway_deviation_rms_s": _stats(h_dev)["rms"],
                "headway_cv_mean": float(np.mean(cvs)) if cvs else None,
                "headway_cv_max": float(np.max(cvs)) if cvs else None,
                "headway_ratio_cv_mean": float(np.mean(rcvs)) if rcvs else None,
                "trips_planned": planned.get((n, d), 0),
                "trips_run": run.get((n, d), 0),
                "energy_kwh": en[(n, d)] / J_PER_KWH if (n, d) in en else None,
            }
        tbs = [t for t in tb_rows if t["period"] == p.name]
        rows.append({
            "period": p.name, "start_s": p.start_s, "end_s": p.end_s,
            "headway_s": p.headway_s, "directions": per_dir,
            "fleet_in_service_max": fmax, "fleet_in_service_mean": fmean,
            "turnbacks": _tb_summary(tbs),
        })
    all_dev = np.asarray([r.departure_delay_s for cs in calls.values() for r in cs])
    ok = np.isfinite(all_dev)
    termini = sorted({str(t["terminus"]) for t in tb_rows})
    return {
        "day": plan.name,
        "punctual_threshold_s": PUNCTUAL_S,
        "punctuality_definition": "share of departures at most punctual_threshold_s late "
                                  "(metro_atc.core.plant.kpi.PUNCTUAL_S)",
        "punctuality": float(np.mean(all_dev[ok] <= PUNCTUAL_S)) if ok.any() else None,
        "trips_planned": int(sum(planned.values())),
        "trips_run": int(sum(run.values())),
        "fleet_max": int(ns.max()) if ns.size else 0,
        "energy_kwh": {d: (sum(v for (n, dd), v in en.items() if dd == d) / J_PER_KWH
                           if energy_j is not None else None) for d in DIRECTIONS},
        "energy_trips_missing": en_missing if energy_j is not None else None,
        "periods": rows,
        "turnbacks_by_terminus": {s: _tb_summary([t for t in tb_rows if t["terminus"] == s])
                                  for s in termini},
        "turnbacks": tb_rows,
        "rejected_records": rejected,
        "unmatched_depot_moves": unmatched,
    }


def _tb_summary(tbs: List[Dict[str, Any]]) -> Dict[str, Any]:
    """Count, worst terminal delay, buffer range, carried delays of turnback rows."""
    def col(k: str) -> np.ndarray:
        v = np.asarray([t[k] if t[k] is not None else math.nan for t in tbs], dtype=float)
        return v[np.isfinite(v)]
    delay, buf, car = col("terminal_delay_s"), col("buffer_s"), col("carried_delay_s")
    return {
        "count": len(tbs),
        "max_terminal_delay_s": float(delay.max()) if delay.size else None,
        "min_buffer_s": float(buf.min()) if buf.size else None,
        "carried": int(np.sum(car > 0.0)),
        "max_carried_delay_s": float(car.max()) if car.size else None,
        "total_carried_delay_s": float(car.sum()) if car.size else None,
    }


def _fmt(v: Optional[float], spec: str, scale: float = 1.0) -> str:
    return "-" if v is None else format(v * scale, spec)


def kpi_table(k: Dict[str, Any]) -> str:
    """Plain-text table of :func:`day_kpis`, one row per period and direction."""
    head = (f"{'period':13s} {'dir':4s} {'trips':>9s} {'punct%':>7s} {'dev rms':>8s} "
            f"{'dev max':>8s} {'hw dev':>7s} {'hw CV':>6s} {'irr':>6s} {'fleet':>9s} {'kWh':>8s} "
            f"{'turnbk':>6s} {'tdel max':>8s} {'carried':>7s} {'car max':>8s}")
    lines = [f"Day {k['day']}: punctuality = departures <= {k['punctual_threshold_s']:.0f} s "
             f"late; dev = departure - timetable [s]; hw = headway [s]; fleet = max/mean "
             f"trains out of the depot", head, "-" * len(head)]
    for row in k["periods"]:
        tb = row["turnbacks"]
        for i, d in enumerate(DIRECTIONS):
            r = row["directions"][d]
            dev = r["schedule_deviation_s"]
            first = i == 0
            lines.append(
                f"{row['period'] if first else '':13s} {d:4s} "
                f"{r['trips_run']:>4d}/{r['trips_planned']:<4d} "
                f"{_fmt(r['punctuality'], '7.1f', 100.0)} {_fmt(dev['rms'], '8.1f')} "
                f"{_fmt(dev['max'], '8.1f')} {_fmt(r['headway_deviation_rms_s'], '7.1f')} "
                f"{_fmt(r['headway_cv_mean'], '6.3f')} "
                f"{_fmt(r['headway_ratio_cv_mean'], '6.3f')} "
                + (f"{row['fleet_in_service_max']:>3d}/{row['fleet_in_service_mean']:<5.1f}"
                   if first else f"{'':9s}")
                + f" {_fmt(r['energy_kwh'], '8.0f')} "
                + (f"{tb['count']:>6d} {_fmt(tb['max_terminal_delay_s'], '8.1f')} "
                   f"{tb['carried']:>7d} {_fmt(tb['max_carried_delay_s'], '8.1f')}"
                   if first else ""))
    lines.append(f"trips run {k['trips_run']}/{k['trips_planned']}, punctuality "
                 f"{_fmt(k['punctuality'], '.1f', 100.0)} %, fleet max {k['fleet_max']}, "
                 f"rejected records {k['rejected_records']}")
    return "\n".join(lines)
