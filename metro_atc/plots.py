"""Outputs a user looks at: KPI JSON, events CSV, train graph and speed-profile PNGs.

:func:`write_outputs` writes into ``out_dir``:

* ``kpis.json`` -- :meth:`LineSim.kpis`;
* ``events.csv`` -- every arrival/departure with timetable time, delay, passengers, dwell;
* ``train_graph.png`` -- time-distance diagram of the trains that ran, planned (timetable,
  dashed) vs actual paths, one colour and label per train, stations by name, TSR windows
  and incidents shaded;
* ``speed_<train_id>.png`` -- speed vs position against the civil limit, the overspeed
  ceiling, the static ATP emergency-brake intervention curve and the ATP supervision speed
  actually applied (incl. the moving-block authority), the ATO's planned profile and the
  actual speed, with station markers and the gradient profile;
* ``energy.png`` -- energy breakdown per train and for the line: traction, conversion
  losses, auxiliaries, regeneration returned, braking losses, substation net.

Uses matplotlib with the Agg backend (no display needed).
"""

from __future__ import annotations

import csv
import json
import math
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Sequence

import numpy as np

from metro_atc.forked import run_jobs
from metro_atc.jsonsafe import json_safe

if TYPE_CHECKING:  # pragma: no cover
    from metro_atc.core.plant.line import LineSim

KMH = 3.6
"""m/s -> km/h."""


def _plt() -> Any:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def write_events_csv(sim: "LineSim", path: Path,
                     dispatched: Sequence[tuple[Any, int]] = ()) -> None:
    """Write the event log as CSV (one row per arrival/departure).

    ``dispatched``: the dispatcher's applied commands and their station index (-1: none),
    (:class:`metro_atc.core.dispatcher_commands.Applied`, int); each is a row at its place
    among the events (``kind`` its name, ``detail`` its step and zone).
    """
    extra = sorted(dispatched, key=lambda d: (d[0].event_index, d[0].sequence))
    with path.open("w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(["train_id", "station_index", "station_name", "kind", "t_s",
                    "scheduled_t_s", "delay_s", "boarded", "alighted", "dwell_s",
                    "stop_error_m", "detail"])
        k = 0
        for n, e in enumerate(sim.event_log()):
            while k < len(extra) and extra[k][0].event_index <= n:
                w.writerow(extra[k][0].csv_row(sim.station_names, extra[k][1]))
                k += 1
            w.writerow([sim.train_ids[e.train_idx], e.station_idx,
                        sim.station_names[e.station_idx], e.kind, f"{e.t_s:.2f}",
                        f"{e.scheduled_t_s:.2f}", f"{e.delay_s:.2f}", e.boarded, e.alighted,
                        f"{e.dwell_s:.2f}",
                        "" if math.isnan(e.stop_error_m) else f"{e.stop_error_m:.3f}", ""])
        for a, j in extra[k:]:
            w.writerow(a.csv_row(sim.station_names, j))


def _trace_arrays(sim: "LineSim") -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                                           np.ndarray]:
    tr = sim.trace
    if not tr["t"]:
        z = np.zeros((0, sim.n))
        return np.zeros(0), z, z, z.astype(bool), z
    return (np.asarray(tr["t"]), np.vstack(tr["x"]), np.vstack(tr["v"]),
            np.vstack(tr["run"]), np.vstack(tr["atp"]))


def ran_trains(sim: "LineSim") -> list[int]:
    """Indices of the trains that were in service at some step of the run."""
    _, _, _, run, _ = _trace_arrays(sim)
    if run.size == 0:
        return []
    return [int(i) for i in np.flatnonzero(run.any(axis=0))]


def _train_colours(n: int) -> list[Any]:
    """``n`` distinguishable colours (tab10 then tab20b/tab20c shades, no repeat up to 50)."""
    from matplotlib import colormaps
    cols: list[Any] = []
    for name, k in (("tab10", 10), ("tab20b", 20), ("tab20c", 20)):
        cmap = colormaps[name]
        cols += [cmap(j) for j in range(k)]  # listed colormaps: integer j = j-th colour
    return [cols[i % len(cols)] for i in range(n)]


def _station_labels(sim: "LineSim") -> list[str]:
    """``CODE name`` of each station (or the name alone)."""
    return [f"{c} {nm}" if c and c != nm else nm
            for c, nm in zip(sim.station_codes, sim.station_names)]


def _tsr_windows(sim: "LineSim",
                 t_end_s: float) -> list[tuple[float, float, float, float, float]]:
    """TSRs of the run: (start m, end m, from s, to s, km/h).

    The plant's own list (:attr:`metro_atc.core.plant.incidents.Incidents.tsrs`): the
    scenario's (line and incidents) and those a dispatcher imposed (lifted: ``to`` is the
    lift time), so the plots draw what the ATP supervised.
    """
    return [(a, b, f, min(e, t_end_s), round(v * KMH, 6))
            for (a, b, v, f, e) in sim.incidents.tsrs]


def _shade_incidents(ax: Any, sim: "LineSim", t_end_s: float) -> None:
    """Shade TSR windows (time x zone) and breakdown/hold times on a train graph [min, km]."""
    from matplotlib.patches import Rectangle
    labelled: set[str] = set()

    def once(key: str, text: str) -> str | None:
        if key in labelled:
            return None
        labelled.add(key)
        return text

    for x0, x1, t0, t1, lim in _tsr_windows(sim, t_end_s):
        if t1 <= t0:
            continue
        ax.add_patch(Rectangle((t0 / 60.0, x0 / 1000.0), (t1 - t0) / 60.0, (x1 - x0) / 1000.0,
                               facecolor="gold", alpha=0.35, edgecolor="darkgoldenrod",
                               lw=0.8, zorder=1,
                               label=once("tsr", "temporary speed restriction")))
        ax.text(t0 / 60.0, x1 / 1000.0, f" TSR {lim:g} km/h", fontsize=7, va="bottom",
                color="darkgoldenrod")
    for z in sim.scn.incidents:
        if z.kind == "breakdown" and z.at_s < t_end_s:
            ax.axvspan(z.at_s / 60.0, (z.at_s + z.duration_s) / 60.0, color="tab:red",
                       alpha=0.15, zorder=0, label=once("bd", "breakdown (incident)"))
            ax.text(z.at_s / 60.0, 1.0, f"{z.train} breakdown", fontsize=7, rotation=90,
                    va="top", ha="right", color="tab:red", transform=ax.get_xaxis_transform())
        elif z.kind == "hold":
            names = list(sim.station_codes) + list(sim.station_names)
            if z.station in names:
                j = names.index(z.station) % len(sim.station_names)
                y = sim.station_positions_m[j] / 1000.0
                ax.annotate(f"{z.train} held {z.duration_s:g} s", (0.0, y), fontsize=7,
                            color="tab:red", xytext=(4, 4), textcoords="offset points")


LABEL_ROWS = 3
"""Rows of train labels above the trains' last positions (the trains that end at the
terminus end a headway apart: one row of labels overlapped)."""


def _end_labels(fig: Any, ax: Any, ends: list[tuple[float, float, str, Any]]) -> None:
    """Label each train at its last position [min, km], rows staggered so none overlap.

    A label goes to the lowest of :data:`LABEL_ROWS` rows (2, 10, 18 pt above the point)
    whose previous label at about the same height (within 0.5 km) ends before it starts
    (label widths estimated from the font size and the axes' width in points, known once
    the x limits are set); with all rows taken, the row whose last label ends first.
    """
    if not ends:
        return
    x0, x1 = ax.get_xlim()
    width_pt = ax.get_position().width * fig.get_figwidth() * 72.0
    min_per_pt = (x1 - x0) / max(width_pt, 1.0)
    top_pt = (-math.inf, 0.0)  # (km, points above it) of the highest label
    free: list[list[float]] = []  # per height group: per row, where its last label ends
    groups: list[float] = []
    for t_min, y_km, text, col in sorted(ends, key=lambda e: e[0]):
        g = next((n for n, y in enumerate(groups) if abs(y - y_km) <= 0.5), None)
        if g is None:
            groups.append(y_km)
            free.append([-math.inf] * LABEL_ROWS)
            g = len(groups) - 1
        start = t_min + 2.0 * min_per_pt
        rows = free[g]
        row = next((r for r in range(LABEL_ROWS) if rows[r] < start),
                   int(np.argmin(rows)))
        rows[row] = start + (0.75 * 7.0 * len(text) + 3.0) * min_per_pt
        ax.annotate(text, (t_min, y_km), fontsize=7, color=col, xytext=(2, 2 + 8 * row),
                    textcoords="offset points", fontweight="bold")
        top_pt = max(top_pt, (y_km, 12.0 + 8 * row))
    # room above the highest labels (inside the axes, below the title)
    y0, y1 = ax.get_ylim()
    height_pt = ax.get_position().height * fig.get_figheight() * 72.0
    need = top_pt[0] + top_pt[1] * (y1 - y0) / max(height_pt - top_pt[1], 1.0)
    if need > y1:
        ax.set_ylim(y0, need)


def plot_train_graph(sim: "LineSim", path: Path) -> None:
    """Time-distance diagram of the trains that ran: planned (dashed) and actual (solid).

    Stations by name on the chainage axis, one colour and label per train, TSR windows and
    incidents shaded; the time axis ends with the run.
    """
    plt = _plt()
    t, x, _, run, _ = _trace_arrays(sim)
    ran = ran_trains(sim)
    t_end = float(t[-1]) if t.size else 0.0
    fig, ax = plt.subplots(figsize=(13, 8))
    pos_km = sim.station_positions_m / 1000.0
    for y in pos_km:
        ax.axhline(y, color="0.88", lw=0.6, zorder=0)
    ax.set_yticks(pos_km, _station_labels(sim), fontsize=8)
    cols = _train_colours(sim.n)
    for i in ran:
        tt = np.column_stack([sim.service.sched_arr[i], sim.service.sched_dep[i]]).ravel()
        xx = np.repeat(pos_km, 2)
        keep = np.isfinite(tt) & (tt <= t_end + 60.0)
        ax.plot(tt[keep] / 60.0, xx[keep], ls="--", lw=0.7, color=cols[i], alpha=0.7)
    ends: list[tuple[float, float, str, Any]] = []
    for i in ran:
        xi = np.where(run[:, i] & (x[:, i] <= sim.geometry.x_end), x[:, i], np.nan) / 1000.0
        ax.plot(t / 60.0, xi, lw=1.4, color=cols[i])
        ok = np.flatnonzero(np.isfinite(xi))
        if ok.size:
            k = ok[-1]
            ends.append((t[k] / 60.0, xi[k], sim.train_ids[i].replace("train_", "T"), cols[i]))
    ax.set_xlim(0.0, max(t_end / 60.0, 1.0) * 1.05)
    _end_labels(fig, ax, ends)
    ax.plot([], [], ls="--", lw=0.8, color="0.3", label="planned (timetable)")
    ax.plot([], [], lw=1.4, color="0.3", label="actual (one colour per train, T = train)")
    _shade_incidents(ax, sim, t_end)
    ax.set_xlabel("time [min]")
    ax.set_ylabel("station (chainage)")
    ax.set_title(f"{sim.scn.name}: train graph, {len(ran)} of {sim.n} trains ran "
                 f"(t = 0 - {t_end / 60.0:.0f} min)")
    ax.legend(loc="upper left", fontsize=8, framealpha=0.9)
    ax.grid(alpha=0.25, axis="x")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _gradient_steps(sim: "LineSim", lo: float, hi: float) -> tuple[np.ndarray, np.ndarray]:
    """Chainage [m] and grade [per mille] of the line's gradient steps over [lo, hi]."""
    g = sorted(sim.scn.line.gradients, key=lambda e: e.start_m)
    xs = [lo] + [e.start_m for e in g if lo < e.start_m < hi] + [hi]

    def grade_at(xm: float) -> float:
        val = 0.0
        for e in g:
            if e.start_m <= xm:
                val = e.grade_permille
        return val
    return np.asarray(xs, dtype=float), np.asarray([grade_at(v) for v in xs], dtype=float)


def plot_speed_profile(sim: "LineSim", train_idx: int, path: Path,
                       planned: dict[int, tuple[np.ndarray, np.ndarray]] | None = None
                       ) -> None:
    """Speed vs position of one train: limits, ATP curves, the ATO's plan, the actual speed.

    Station markers with names, the gradient profile (lower panel); ``planned`` maps the
    departure station index to the ATO's last planned curve for that run (chainage [m],
    speed [m/s]; from the SpeedProfile messages).
    """
    plt = _plt()
    t, x, v, run, atp = _trace_arrays(sim)
    fig, (ax, axg) = plt.subplots(2, 1, figsize=(15, 6.5), sharex=True,
                                  gridspec_kw={"height_ratios": [4, 1]})
    gx = sim.geometry.grid_x
    sel = run[:, train_idx] if t.size else np.zeros(0, dtype=bool)
    lo = sim.geometry.x_first_stop - 50.0
    hi = sim.geometry.x_end
    if sel.any():  # only the stretch the train ran (plus a little)
        hi = min(hi, float(np.nanmax(x[sel, train_idx])) + 300.0)
    m = (gx >= lo) & (gx <= hi)
    km = gx[m] / 1000.0
    ax.plot(km, sim.atp.limit_eff[m] * KMH, color="k", lw=1.1, label="civil speed limit")
    ax.plot(km, sim.atp.ceiling_phys[m] * KMH, color="tab:red", lw=0.8, ls=":",
            label="overspeed ceiling (limit + margin)")
    ax.plot(km, np.maximum(sim.atp.ebi_static[m], 0.0) * KMH, color="tab:orange", lw=0.9,
            label="ATP EBI curve (static)")
    if sel.any():
        ax.plot(x[sel, train_idx] / 1000.0, np.maximum(atp[sel, train_idx], 0.0) * KMH,
                ".", ms=1.0, color="tab:purple", label="ATP supervision applied (incl. MA)")
    for k, (st, (px, pv)) in enumerate(sorted((planned or {}).items())):
        ax.plot(px / 1000.0, pv * KMH, color="tab:green", lw=1.2, ls="--",
                label="ATO planned profile" if k == 0 else None)
    if sel.any():
        ax.plot(x[sel, train_idx] / 1000.0, v[sel, train_idx] * KMH, color="tab:blue",
                lw=1.4, label="actual speed")
    for k, (x0, x1, t0, t1, lim) in enumerate(_tsr_windows(sim, math.inf)):
        ax.axvspan(x0 / 1000.0, x1 / 1000.0, color="gold", alpha=0.3, zorder=0,
                   label="temporary speed restriction (part of the run)" if k == 0 else None)
        ax.text((x0 + x1) / 2000.0, lim, f"TSR {lim:g} km/h\n{t0 / 60:.0f}-{t1 / 60:.0f} min",
                fontsize=7, ha="center", va="bottom", color="darkgoldenrod")
    names = _station_labels(sim)
    shown = [j for j, px_m in enumerate(sim.station_positions_m) if lo - 1.0 <= px_m <= hi]
    for j in shown:
        for a in (ax, axg):
            a.axvline(sim.station_positions_m[j] / 1000.0, color="0.6", lw=0.7, zorder=0)
    top_ax = ax.secondary_xaxis("top")
    top_ax.set_xticks([sim.station_positions_m[j] / 1000.0 for j in shown],
                      [names[j] for j in shown], fontsize=7, rotation=30, ha="left")
    top = float(np.nanmax(sim.atp.ceiling_phys[m])) * KMH if m.any() else float("nan")
    ax.set_ylim(0.0, top * 1.1 if math.isfinite(top) else None)
    ax.set_ylabel("speed [km/h]")
    ax.set_title(f"{sim.scn.name}: {sim.train_ids[train_idx]} speed vs position")
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, framealpha=0.9)
    ax.grid(alpha=0.3)
    gxs, gg = _gradient_steps(sim, lo, hi)
    axg.step(gxs / 1000.0, gg, where="post", color="saddlebrown", lw=1.0)
    axg.fill_between(gxs / 1000.0, gg, step="post", color="saddlebrown", alpha=0.2)
    axg.axhline(0.0, color="0.5", lw=0.5)
    axg.set_ylabel("grade [‰]\n(+ uphill)", fontsize=8)
    axg.set_xlabel("chainage [km]")
    axg.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def energy_terms(sim: "LineSim") -> dict[str, np.ndarray]:
    """Per-train energy breakdown [kWh] from the plant's totals.

    ``traction`` at the wheel; ``conversion`` losses between substation and wheel
    (traction / efficiency - traction); ``auxiliaries``; ``regen_returned`` to the line
    (negative: it offsets the draw); ``braking_losses``: friction brake plus the electric
    brake energy not returned to the line; ``net``: substation net draw.
    """
    e = sim.energy_breakdown()
    j = 1.0 / 3.6e6
    trac = np.asarray(e["traction_wheel"]) * j
    net = np.asarray(e["substation"]) * j
    aux = np.asarray(e["aux"]) * j
    regen = np.asarray(e["regen_to_line"]) * j
    return {"traction": trac, "conversion": net - trac - aux + regen, "auxiliaries": aux,
            "regen_returned": -regen,
            "braking_losses": (np.asarray(e["friction_brake"])
                               + np.asarray(e["electric_brake"])) * j - regen,
            "net": net}


def plot_energy(sim: "LineSim", path: Path) -> None:
    """Energy breakdown per train (trains that ran) and for the whole line [kWh]."""
    plt = _plt()
    e = energy_terms(sim)
    ran = ran_trains(sim) or list(range(sim.n))
    fig, (ax, axl) = plt.subplots(1, 2, figsize=(14, 5.5),
                                  gridspec_kw={"width_ratios": [4, 1]})
    idx = np.arange(len(ran))
    up = [("traction", "traction at wheel", "tab:blue"),
          ("conversion", "traction conversion losses", "lightsteelblue"),
          ("auxiliaries", "auxiliaries", "tab:gray")]
    w = 0.38
    for ax_, xs, sel, width in ((ax, idx - w / 2, ran, w), (axl, np.array([-w / 2]), None, w)):
        bottom = np.zeros(len(xs))
        for key, label, col in up:
            vals = e[key][sel] if sel is not None else np.array([e[key].sum()])
            ax_.bar(xs, vals, width, bottom=bottom, color=col, label=label)
            bottom = bottom + vals
        rg = e["regen_returned"][sel] if sel is not None else np.array([
            e["regen_returned"].sum()])
        ax_.bar(xs, rg, width, color="tab:green", label="regeneration returned to line")
        bl = e["braking_losses"][sel] if sel is not None else np.array([
            e["braking_losses"].sum()])
        ax_.bar(xs + width, bl, width, color="tab:red", hatch="//", alpha=0.7,
                label="braking losses (friction + unreturned electric)")
        net = e["net"][sel] if sel is not None else np.array([e["net"].sum()])
        ax_.plot(xs, net, "kD", ms=5, label="substation net draw")
        ax_.axhline(0.0, color="k", lw=0.6)
        ax_.grid(alpha=0.3, axis="y")
    ax.set_xticks(idx, [sim.train_ids[i].replace("train_", "T") for i in ran], fontsize=8)
    ax.set_ylabel("energy [kWh]  (+ drawn, - returned)")
    ax.set_title(f"{sim.scn.name}: energy per train ({len(ran)} trains)")
    axl.set_xticks([0.0], ["whole line"])
    axl.set_title(f"line: net {e['net'].sum():.0f} kWh")
    h, lab = ax.get_legend_handles_labels()
    fig.legend(h, lab, loc="lower center", ncol=4, fontsize=8, frameon=False)
    fig.tight_layout(rect=(0.0, 0.08, 1.0, 1.0))
    fig.savefig(path, dpi=110)
    plt.close(fig)


def output_jobs(sim: "LineSim", out: Path, speed_trains: list[int] | None = None,
                planned: dict[int, dict[int, tuple[np.ndarray, np.ndarray]]] | None = None,
                dispatched: Sequence[tuple[Any, int]] = ()
                ) -> list[tuple[Path, Callable[[], None]]]:
    """The files of a run but ``kpis.json``: (path, a call that writes it).

    The PNGs (train graph, speed profiles, energy) and the events CSV, in the order
    :func:`write_outputs` lists them; ``speed_trains`` / ``planned`` / ``dispatched`` as
    there.
    """
    ev = out / "events.csv"
    jobs: list[tuple[Path, Callable[[], None]]] = [
        (ev, partial(write_events_csv, sim, ev, dispatched))]
    tg = out / "train_graph.png"
    jobs.append((tg, partial(plot_train_graph, sim, tg)))
    if speed_trains is None:
        ran = ran_trains(sim) or [0]
        speed_trains = sorted({ran[0], ran[len(ran) // 2], ran[-1]})
    for i in speed_trains:
        sp = out / f"speed_{sim.train_ids[i]}.png"
        jobs.append((sp, partial(plot_speed_profile, sim, i, sp, (planned or {}).get(i))))
    en = out / "energy.png"
    jobs.append((en, partial(plot_energy, sim, en)))
    return jobs[1:] + jobs[:1]  # the CSV last: dealt round-robin, it evens the shares


def write_outputs(sim: "LineSim", out_dir: str | Path,
                  speed_trains: list[int] | None = None,
                  kpis: dict[str, Any] | None = None,
                  planned: dict[int, dict[int, tuple[np.ndarray, np.ndarray]]] | None = None,
                  workers: int | None = None,
                  dispatched: Sequence[tuple[Any, int]] = ()) -> list[Path]:
    """Write KPIs JSON, events CSV and the PNGs into ``out_dir``; returns the files written.

    Files: ``kpis.json``, ``events.csv``, ``train_graph.png``, ``speed_<train>.png``,
    ``energy.png``.  ``speed_trains`` selects the speed-profile trains (default: first,
    middle and last of the trains that ran); ``kpis`` (default :meth:`LineSim.kpis`) is
    what ``kpis.json`` holds, written once; ``planned`` (train index -> departure
    station -> planned curve) adds the ATO's plans to the speed plots; ``dispatched`` the
    dispatcher's applied commands to events.csv (:func:`write_events_csv`).  The files are
    written in parallel
    (:func:`metro_atc.forked.run_jobs`, ``workers`` processes; default: the usable cores;
    the six PNGs of a whole run took 5.3 s one after another).
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    files = []
    kp = out / "kpis.json"
    kp.write_text(json.dumps(json_safe(kpis if kpis is not None else sim.kpis()), indent=2,
                             sort_keys=True, allow_nan=False), encoding="utf-8")
    files.append(kp)
    jobs = output_jobs(sim, out, speed_trains, planned, dispatched)
    _plt()  # imported before the workers fork: they share it
    run_jobs(jobs, workers)
    files += [jobs[-1][0]] + [path for path, _ in jobs[:-1]]  # events.csv, then the PNGs
    return files
