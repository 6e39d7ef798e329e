"""Pictures of a service day from its records (matplotlib, Agg; no display needed).

- :func:`plot_day_train_graph` -- the train graph of the day: both directions on one
  time-distance diagram (x: time of day hh:mm, y: stations by chainage; up trips climb, down
  trips descend), one colour per train kept across its trips, turnback layovers drawn at
  the termini, pull-outs (^) and pull-ins (v) marked, late departures highlighted; a
  full-day panel plus zoom panels (default: the first hour of the morning peak);
- :func:`plot_circulation` -- one row per train: its trips across the day as bars coloured
  by direction, late trips outlined, turnbacks as thin links, depot spells as gaps between
  pull-in and pull-out markers;
- :func:`plot_kpi_table` -- the per-period KPI table of :func:`metro_atc.core.service.
  daykpi.day_kpis` as a figure.

Colours per train and the Agg backend come from :mod:`metro_atc.plots` (one source).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Dict, List, Optional, Sequence, Tuple

import numpy as np

from metro_atc.core.plant.kpi import PUNCTUAL_S
from metro_atc.core.service.day import DayPlan
from metro_atc.core.service.records import (DepotRecord, StopRecord, TurnbackRecord,
                                            write_records_csv)
from metro_atc.plots import _plt, _train_colours

UP_COLOUR = "tab:blue"
"""Bar colour of up trips in the circulation chart."""
DOWN_COLOUR = "tab:orange"
"""Bar colour of down trips in the circulation chart."""


def _hhmm(x: float, _pos: Any = None) -> str:
    """Seconds after midnight -> hh:mm."""
    t = int(round(x))
    return f"{t // 3600:02d}:{t % 3600 // 60:02d}"


def _time_axis(ax: Any, t0: float, t1: float) -> None:
    """x axis in hh:mm with ticks every 1 h (full day) or 10 min (zoom)."""
    from matplotlib.ticker import FuncFormatter, MultipleLocator
    span = t1 - t0
    major = 3600.0 if span > 4 * 3600 else (1800.0 if span > 2 * 3600 else 600.0)
    ax.xaxis.set_major_locator(MultipleLocator(major))
    ax.xaxis.set_minor_locator(MultipleLocator(major / (4 if major >= 3600 else 2)))
    ax.xaxis.set_major_formatter(FuncFormatter(_hhmm))
    ax.set_xlim(t0, t1)
    ax.grid(alpha=0.3, axis="x", which="major")


def _chainage_km(plan: DayPlan) -> np.ndarray:
    """Station chainage [km] from the first station."""
    return np.concatenate([[0.0], np.cumsum(plan.line.distance_m)]) / 1000.0


def _train_order(stops: Sequence[StopRecord], depot: Sequence[DepotRecord]) -> List[str]:
    """Trains in order of their first appearance (pull-out or first call)."""
    first: Dict[str, float] = {}
    for r in depot:
        if math.isfinite(r.t_s):
            first[r.train] = min(first.get(r.train, math.inf), r.t_s)
    for s in stops:
        t = s.dep_s if math.isfinite(s.dep_s) else s.arr_s
        if math.isfinite(t):
            first[s.train] = min(first.get(s.train, math.inf), t)
    return sorted(first, key=lambda k: (first[k], k))


def _trip_paths(stops: Sequence[StopRecord], y_km: np.ndarray
                ) -> Dict[str, Tuple[str, str, np.ndarray, np.ndarray, float]]:
    """trip -> (train, direction, t [s], y [km], worst departure delay [s])."""
    by: Dict[str, List[StopRecord]] = {}
    for r in stops:
        by.setdefault(r.trip_id, []).append(r)
    out = {}
    for tid, rs in by.items():
        tt: List[float] = []
        yy: List[float] = []
        for r in rs:                      # records are in calling order
            for t in (r.arr_s, r.dep_s):
                if math.isfinite(t):
                    tt.append(t)
                    yy.append(float(y_km[r.station]))
        d = [r.departure_delay_s for r in rs if math.isfinite(r.departure_delay_s)]
        out[tid] = (rs[0].train, rs[0].direction, np.asarray(tt), np.asarray(yy),
                    max(d) if d else 0.0)
    return out


def _draw_graph(ax: Any, plan: DayPlan, paths: Dict[str, Any],
                turnbacks: Sequence[TurnbackRecord], depot: Sequence[DepotRecord],
                colours: Dict[str, Any], t0: float, t1: float, lw: float,
                planned: Optional[Dict[str, Any]], markers: float) -> None:
    """One train-graph panel over [t0, t1] [s]."""
    y_km = _chainage_km(plan)
    end_y = {plan.termini[0].station: y_km[0], plan.termini[1].station: y_km[-1]}
    for y in y_km:
        ax.axhline(y, color="0.9", lw=0.5, zorder=0)
    if planned is not None:
        for tid, (_, _, tt, yy, _) in planned.items():
            if paths.get(tid, (0, 0, 0, 0, 0.0))[4] > PUNCTUAL_S and tt.size and \
                    tt[-1] >= t0 and tt[0] <= t1:
                ax.plot(tt, yy, ls=(0, (3, 2)), lw=0.8, color="0.35", zorder=2)
    for tid, (train, _d, tt, yy, late) in paths.items():
        if not tt.size or tt[-1] < t0 or tt[0] > t1:
            continue
        bad = late > PUNCTUAL_S
        ax.plot(tt, yy, lw=lw * (2.2 if bad else 1.0), color=colours[train],
                alpha=1.0 if bad or planned is not None else 0.55, zorder=4 if bad else 3)
    for tb in turnbacks:
        if not (math.isfinite(tb.arr_s) and math.isfinite(tb.dep_s)) or tb.dep_s < t0 \
                or tb.arr_s > t1:
            continue
        y = end_y.get(tb.terminus, math.nan)
        ax.plot([tb.arr_s, tb.dep_s], [y, y], lw=lw * 3.0, color=colours[tb.train],
                alpha=0.45, solid_capstyle="butt", zorder=2)
    for r in depot:
        if not (t0 <= r.t_s <= t1):
            continue
        y = end_y.get(r.terminus, math.nan)
        up = r.kind == "pull_out"
        ax.plot(r.t_s, y, marker="^" if up else "v", ms=markers, color=colours[r.train],
                mec="k", mew=0.5, zorder=4, clip_on=False)
    _time_axis(ax, t0, t1)
    ax.set_ylim(y_km[0] - 0.6, y_km[-1] + 0.6)


def plot_day_train_graph(plan: DayPlan, stops: Sequence[StopRecord],
                         turnbacks: Sequence[TurnbackRecord],
                         depot: Sequence[DepotRecord], path: Path,
                         zooms: Sequence[Tuple[float, float]] = ((7 * 3600.0, 8 * 3600.0),),
                         planned: Optional[Sequence[StopRecord]] = None,
                         title: str = "") -> None:
    """Train graph of the day (module docstring); ``zooms``: (from, to) [s] panels.

    ``planned``: the timetable's records (e.g. the day run without incidents); when given,
    the planned path of every trip more than PUNCTUAL_S late is drawn dashed in the panels.
    """
    plt = _plt()
    from matplotlib.lines import Line2D
    y_km = _chainage_km(plan)
    trains = _train_order(stops, depot)
    cols = dict(zip(trains, _train_colours(len(trains))))
    paths = _trip_paths(stops, y_km)
    ref = _trip_paths(planned, y_km) if planned is not None else None
    times = [t for _, _, tt, _, _ in paths.values() for t in tt]
    t0 = math.floor(min(times) / 3600.0) * 3600.0 if times else 0.0
    t1 = math.ceil(max(times) / 3600.0) * 3600.0 if times else 3600.0
    n = 1 + len(zooms)
    fig, axes = plt.subplots(n, 1, figsize=(20, 1.0 + 7.0 * n),
                             gridspec_kw={"height_ratios": [0.8] + [1.0] * (n - 1)})
    axes = np.atleast_1d(axes)
    labels = [f"{c} {nm}" for c, nm in zip(plan.line.station_codes, plan.line.station_names)]
    _draw_graph(axes[0], plan, paths, turnbacks, depot, cols, t0, t1, 0.45, None, 4.0)
    axes[0].set_yticks(y_km[::2], labels[::2], fontsize=7)
    n_late = sum(1 for p in paths.values() if p[4] > PUNCTUAL_S)
    axes[0].set_title((title + ": " if title else "") +
                      f"train graph of the day, {len(paths)} trips, {len(trains)} trains "
                      f"(one colour per train); {n_late} trips depart > {PUNCTUAL_S:.0f} s "
                      f"late (thick)", fontsize=12)
    for k, (a, b) in enumerate(zooms):
        ax = axes[k + 1]
        _draw_graph(ax, plan, paths, turnbacks, depot, cols, a, b, 1.1, ref, 8.0)
        ax.set_yticks(y_km, labels, fontsize=7)
        ax.set_title(f"zoom {_hhmm(a)}-{_hhmm(b)}: both directions (up BL01 -> BL23 climbs, "
                     f"down descends); bars at the termini = turnback layovers", fontsize=11)
    for ax in axes:
        ax.set_ylabel("station (chainage)")
    axes[-1].set_xlabel("time of day [hh:mm]")
    handles = [Line2D([], [], lw=1.2, color="0.3", label="trip (one colour per train)"),
               Line2D([], [], lw=2.6, color="0.3", label=f"trip departing > "
                      f"{PUNCTUAL_S:.0f} s late"),
               Line2D([], [], lw=4, color="0.3", alpha=0.45, label="turnback layover"),
               Line2D([], [], ls="", marker="^", mec="k", color="0.6", label="pull-out "
                      "(from depot)"),
               Line2D([], [], ls="", marker="v", mec="k", color="0.6", label="pull-in "
                      "(to depot)")]
    if ref is not None:
        handles.append(Line2D([], [], ls=(0, (3, 2)), color="0.35",
                              label="timetable of a late trip"))
    axes[0].legend(handles=handles, loc="upper left", bbox_to_anchor=(1.0, 1.0),
                   fontsize=8, framealpha=0.95)
    fig.tight_layout(rect=(0.0, 0.0, 0.9, 1.0))
    fig.savefig(path, dpi=90)
    plt.close(fig)


def plot_circulation(plan: DayPlan, stops: Sequence[StopRecord],
                     turnbacks: Sequence[TurnbackRecord], depot: Sequence[DepotRecord],
                     path: Path, title: str = "") -> None:
    """Circulation chart: one row per train, trips as bars by direction (module docstring)."""
    plt = _plt()
    from matplotlib.patches import Patch
    from matplotlib.lines import Line2D
    trains = _train_order(stops, depot)
    row = {t: i for i, t in enumerate(trains)}
    y_km = _chainage_km(plan)
    paths = _trip_paths(stops, y_km)
    fig, ax = plt.subplots(figsize=(20, max(6.0, 0.22 * len(trains) + 2.0)))
    times: List[float] = []
    for tid, (train, d, tt, _, late) in paths.items():
        if not tt.size:
            continue
        times += [tt[0], tt[-1]]
        ax.broken_barh([(tt[0], tt[-1] - tt[0])], (row[train] - 0.38, 0.76),
                       facecolors=UP_COLOUR if d == "up" else DOWN_COLOUR,
                       edgecolors="red" if late > PUNCTUAL_S else "none",
                       linewidth=1.6 if late > PUNCTUAL_S else 0.0)
    for tb in turnbacks:
        if math.isfinite(tb.arr_s) and math.isfinite(tb.dep_s) and tb.train in row:
            ax.plot([tb.arr_s, tb.dep_s], [row[tb.train]] * 2, color="0.45", lw=0.8)
    for r in depot:
        if r.train in row and math.isfinite(r.t_s):
            ax.plot(r.t_s, row[r.train], marker="^" if r.kind == "pull_out" else "v",
                    color="k", ms=4, ls="")
    t0 = math.floor(min(times) / 3600.0) * 3600.0 if times else 0.0
    t1 = math.ceil(max(times) / 3600.0) * 3600.0 if times else 3600.0
    shown = [p for p in plan.periods if t0 <= p.start_s < t1]
    for n, p in enumerate(shown):        # labels on two rows: short periods do not overlap
        ax.axvline(p.start_s, color="0.6", lw=0.8, ls=":")
        ax.text(p.start_s, 1.0 + 0.022 * (n % 2), f" {p.name} (H {p.headway_s:.0f} s)",
                fontsize=8, transform=ax.get_xaxis_transform(), va="bottom", ha="left")
    _time_axis(ax, t0, t1)
    ax.set_yticks(range(len(trains)), [t.replace("train_", "T") for t in trains], fontsize=7)
    ax.set_ylim(len(trains) - 0.5, -0.5)
    ax.set_xlabel("time of day [hh:mm]")
    ax.set_ylabel("train (in order of first pull-out)")
    ax.legend(handles=[Patch(color=UP_COLOUR, label="up trip (BL01 -> BL23)"),
                       Patch(color=DOWN_COLOUR, label="down trip (BL23 -> BL01)"),
                       Patch(facecolor="white", edgecolor="red", lw=1.6,
                             label=f"trip departing > {PUNCTUAL_S:.0f} s late"),
                       Line2D([], [], color="0.45", lw=0.8, label="turnback"),
                       Line2D([], [], marker="^", color="k", ls="", label="pull-out"),
                       Line2D([], [], marker="v", color="k", ls="", label="pull-in "
                              "(gap = in depot)")],
              loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize=8)
    ax.set_title((title + ": " if title else "") +
                 f"circulation of the day, {len(trains)} trains, {len(paths)} trips",
                 fontsize=12, pad=30)
    fig.tight_layout(rect=(0.0, 0.0, 0.9, 1.0))
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _cell(v: Optional[float], spec: str, scale: float = 1.0) -> str:
    return "-" if v is None else format(v * scale, spec)


def plot_kpi_table(kpis: Dict[str, Any], path: Path, title: str = "") -> None:
    """The per-period KPIs of :func:`metro_atc.core.service.daykpi.day_kpis` as a table."""
    plt = _plt()
    cols = ["period", "dir", "trips run /\nplanned", "punctual\n[%]", "dep. dev.\nRMS [s]",
            "dep. dev.\nmax [s]", "headway\ndev RMS [s]", "headway\nirregularity",
            "fleet max /\nmean", "energy\n[kWh]", "turnbacks", "terminal\ndelay max [s]",
            "carried\n(count)", "carried\nmax [s]"]
    energy = any(p["directions"][d]["energy_kwh"] is not None
                 for p in kpis["periods"] for d in ("up", "down"))
    rows: List[List[str]] = []
    shade: List[List[str]] = []
    for p in kpis["periods"]:
        tb = p["turnbacks"]
        for i, d in enumerate(("up", "down")):
            r = p["directions"][d]
            dev = r["schedule_deviation_s"]
            first = i == 0
            rows.append([
                f"{p['period']}\n{_hhmm(p['start_s'])}-{_hhmm(p['end_s'])}, "
                f"H {p['headway_s']:.0f} s" if first else "", d,
                f"{r['trips_run']} / {r['trips_planned']}",
                _cell(r["punctuality"], ".1f", 100.0), _cell(dev["rms"], ".1f"),
                _cell(dev["max"], ".0f"), _cell(r["headway_deviation_rms_s"], ".1f"),
                _cell(r["headway_ratio_cv_mean"], ".3f"),
                f"{p['fleet_in_service_max']} / {p['fleet_in_service_mean']:.1f}"
                if first else "", _cell(r["energy_kwh"], ".0f"),
                str(tb["count"]) if first else "",
                _cell(tb["max_terminal_delay_s"], ".0f") if first else "",
                str(tb["carried"]) if first else "",
                _cell(tb["max_carried_delay_s"], ".0f") if first else ""])
            bad = r["punctuality"] is not None and r["punctuality"] < 0.95
            shade.append(["#fde0dd" if bad else ("#f7f7f7" if first else "white")]
                         * len(cols))
    if not energy:
        k = cols.index("energy\n[kWh]")
        cols = cols[:k] + cols[k + 1:]
        rows = [r[:k] + r[k + 1:] for r in rows]
        shade = [r[:k] + r[k + 1:] for r in shade]
    fig, ax = plt.subplots(figsize=(20, 0.8 + 0.45 * len(rows)))
    ax.axis("off")
    tab = ax.table(cellText=rows, colLabels=cols, cellColours=shade, loc="center",
                   cellLoc="center")
    tab.auto_set_font_size(False)
    tab.set_fontsize(9)
    tab.scale(1.0, 2.1)
    for (r, _c), cell in tab.get_celld().items():
        if r == 0:
            cell.set_facecolor("#dbe5f1")
            cell.set_text_props(fontweight="bold")
    ax.set_title((title + ": " if title else "") +
                 f"KPIs per period -- punctual = departure <= {kpis['punctual_threshold_s']:.0f}"
                 f" s late; headway irregularity = CV of actual/scheduled headway; carried = "
                 f"delay carried through a turnback (rows < 95 % punctual shaded); overall "
                 f"{_cell(kpis['punctuality'], '.1f', 100.0)} % punctual, "
                 f"{kpis['trips_run']}/{kpis['trips_planned']} trips", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def write_day_outputs(plan: DayPlan, stops: Sequence[StopRecord],
                      turnbacks: Sequence[TurnbackRecord], depot: Sequence[DepotRecord],
                      out_dir: Path, energy_j: Optional[Dict[str, float]] = None,
                      planned: Optional[Sequence[StopRecord]] = None,
                      zooms: Sequence[Tuple[float, float]] = ((7 * 3600.0, 8 * 3600.0),)
                      ) -> Dict[str, str]:
    """Write ``day_kpis.json``, ``day_kpis.txt``, the three PNGs and the records into ``out_dir``.

    The records: ``day_calls.csv`` (every call of every trip, scheduled and actual),
    ``day_turnbacks.csv``, ``day_depot.csv`` (:func:`records.write_records_csv`).

    Returns name -> path of what was written.
    """
    import json

    from metro_atc.core.service.daykpi import day_kpis, kpi_table
    from metro_atc.jsonsafe import json_safe
    out_dir.mkdir(parents=True, exist_ok=True)
    k = day_kpis(plan, stops, turnbacks, depot, energy_j)
    paths = {"kpis_json": out_dir / "day_kpis.json", "kpis_txt": out_dir / "day_kpis.txt",
             "train_graph": out_dir / "day_train_graph.png",
             "circulation": out_dir / "day_circulation.png",
             "kpi_table": out_dir / "day_kpi_table.png",
             "calls": out_dir / "day_calls.csv", "turnbacks": out_dir / "day_turnbacks.csv",
             "depot": out_dir / "day_depot.csv"}
    paths["kpis_json"].write_text(json.dumps(json_safe(k), indent=1), encoding="utf-8")
    write_records_csv(stops, paths["calls"])
    write_records_csv(turnbacks, paths["turnbacks"])
    write_records_csv(depot, paths["depot"])
    paths["kpis_txt"].write_text(kpi_table(k) + "\n", encoding="utf-8")
    plot_day_train_graph(plan, stops, turnbacks, depot, paths["train_graph"], zooms, planned,
                         plan.name)
    plot_circulation(plan, stops, turnbacks, depot, paths["circulation"], plan.name)
    plot_kpi_table(k, paths["kpi_table"], plan.name)
    return {n: str(p) for n, p in paths.items()}
