"""Outputs a user looks at: KPI JSON, events CSV, train graph and speed-profile PNGs.

:func:`write_outputs` writes into ``out_dir``:

* ``kpis.json`` -- :meth:`LineSim.kpis`;
* ``events.csv`` -- every arrival/departure with timetable time, delay, passengers, dwell;
* ``train_graph.png`` -- time-distance diagram, planned (timetable, dashed) vs actual paths;
* ``speed_<train_id>.png`` -- speed vs position against the permanent/temporary limit, the
  overspeed ceiling, the static ATP emergency-brake intervention curve and the ATP
  supervision speed actually applied (incl. the moving-block authority);
* ``energy.png`` -- per-train energy at the wheel, regenerated and at the substation.

Uses matplotlib with the Agg backend (no display needed).
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

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


def write_events_csv(sim: "LineSim", path: Path) -> None:
    """Write the event log as CSV (one row per arrival/departure)."""
    with path.open("w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(["train_id", "station_index", "station_name", "kind", "t_s",
                    "scheduled_t_s", "delay_s", "boarded", "alighted", "dwell_s"])
        for e in sim.event_log():
            w.writerow([sim.train_ids[e.train_idx], e.station_idx,
                        sim.station_names[e.station_idx], e.kind, f"{e.t_s:.2f}",
                        f"{e.scheduled_t_s:.2f}", f"{e.delay_s:.2f}", e.boarded, e.alighted,
                        f"{e.dwell_s:.2f}"])


def _trace_arrays(sim: "LineSim") -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                                           np.ndarray]:
    tr = sim.trace
    if not tr["t"]:
        z = np.zeros((0, sim.n))
        return np.zeros(0), z, z, z.astype(bool), z
    return (np.asarray(tr["t"]), np.vstack(tr["x"]), np.vstack(tr["v"]),
            np.vstack(tr["run"]), np.vstack(tr["atp"]))


def plot_train_graph(sim: "LineSim", path: Path) -> None:
    """Time-distance diagram: planned (dashed) and actual (solid) train paths."""
    plt = _plt()
    t, x, _, run, _ = _trace_arrays(sim)
    fig, ax = plt.subplots(figsize=(12, 7))
    pos_km = sim.station_positions_m / 1000.0
    for j, name in enumerate(sim.station_names):
        ax.axhline(pos_km[j], color="0.85", lw=0.6, zorder=0)
        ax.text(0.0, pos_km[j], f" {sim.station_codes[j] or name}", fontsize=6, va="bottom",
                transform=ax.get_yaxis_transform(), color="0.4")
    for i in range(sim.n):
        tt = np.column_stack([sim.sched_arr[i], sim.sched_dep[i]]).ravel()
        xx = np.repeat(pos_km, 2)
        ax.plot(tt / 60.0, xx, ls="--", lw=0.7, color="tab:gray",
                label="planned (timetable)" if i == 0 else None)
    for i in range(sim.n):
        if t.size == 0:
            break
        xi = np.where(run[:, i] & (x[:, i] <= sim.x_end), x[:, i], np.nan) / 1000.0
        ax.plot(t / 60.0, xi, lw=1.0, label="actual" if i == 0 else None)
    ax.set_xlabel("time [min]")
    ax.set_ylabel("chainage [km]")
    ax.set_title(f"{sim.scn.name}: train graph (time-distance), {sim.n} trains")
    ax.legend(loc="lower right")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_speed_profile(sim: "LineSim", train_idx: int, path: Path) -> None:
    """Speed vs position of one train against limits and the ATP supervision curves."""
    plt = _plt()
    t, x, v, run, atp = _trace_arrays(sim)
    fig, ax = plt.subplots(figsize=(12, 5))
    gx = sim.grid_x
    lo = sim.x_first_stop - 50.0
    hi = sim.x_end
    m = (gx >= lo) & (gx <= hi)
    ax.plot(gx[m] / 1000.0, sim.limit_eff[m] * KMH, color="k", lw=1.0,
            label="speed limit (over train length)")
    ax.plot(gx[m] / 1000.0, sim.ceiling_phys[m] * KMH, color="tab:red", lw=0.8, ls=":",
            label="overspeed ceiling (limit + margin)")
    ax.plot(gx[m] / 1000.0, np.maximum(sim.ebi_static[m], 0.0) * KMH, color="tab:orange",
            lw=0.8, label="ATP EBI curve (static)")
    if t.size:
        sel = run[:, train_idx]
        ax.plot(x[sel, train_idx] / 1000.0, np.maximum(atp[sel, train_idx], 0.0) * KMH,
                ".", ms=1.0, color="tab:purple", label="ATP supervision applied (incl. MA)")
        ax.plot(x[sel, train_idx] / 1000.0, v[sel, train_idx] * KMH, color="tab:blue", lw=1.2,
                label="train speed")
    for j, px in enumerate(sim.station_positions_m):
        ax.axvline(px / 1000.0, color="0.85", lw=0.6, zorder=0)
    top = float(np.nanmax(sim.ceiling_phys[m])) * KMH
    ax.set_ylim(0.0, top * 1.1 if math.isfinite(top) else None)
    ax.set_xlabel("chainage [km]")
    ax.set_ylabel("speed [km/h]")
    ax.set_title(f"{sim.scn.name}: {sim.train_ids[train_idx]} speed profile")
    ax.legend(loc="lower right", fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_energy(sim: "LineSim", path: Path) -> None:
    """Per-train energy [kWh]: traction at the wheel, regenerated, substation net."""
    plt = _plt()
    e = sim.energy_breakdown()
    idx = np.arange(sim.n)
    fig, ax = plt.subplots(figsize=(12, 4))
    w = 0.28
    ax.bar(idx - w, e["traction_wheel"] / 3.6e6, w, label="traction at wheel")
    ax.bar(idx, e["regen_to_line"] / 3.6e6, w, label="regenerated to line")
    ax.bar(idx + w, e["substation"] / 3.6e6, w, label="substation net (incl. auxiliary)")
    ax.set_xticks(idx, [s.replace("train_", "") for s in sim.train_ids], fontsize=7)
    ax.set_xlabel("train")
    ax.set_ylabel("energy [kWh]")
    ax.set_title(f"{sim.scn.name}: energy per train")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3, axis="y")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_outputs(sim: "LineSim", out_dir: str | Path,
                  speed_trains: list[int] | None = None,
                  kpis: dict[str, Any] | None = None) -> list[Path]:
    """Write KPIs JSON, events CSV and the PNGs into ``out_dir``; returns the files written.

    ``speed_trains`` selects the speed-profile trains (default: first, middle and last);
    ``kpis`` (default :meth:`LineSim.kpis`) is what ``kpis.json`` holds, written once.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    files = []
    kp = out / "kpis.json"
    kp.write_text(json.dumps(json_safe(kpis if kpis is not None else sim.kpis()), indent=2,
                             sort_keys=True, allow_nan=False), encoding="utf-8")
    files.append(kp)
    ev = out / "events.csv"
    write_events_csv(sim, ev)
    files.append(ev)
    tg = out / "train_graph.png"
    plot_train_graph(sim, tg)
    files.append(tg)
    if speed_trains is None:
        speed_trains = sorted({0, sim.n // 2, sim.n - 1})
    for i in speed_trains:
        sp = out / f"speed_{sim.train_ids[i]}.png"
        plot_speed_profile(sim, i, sp)
        files.append(sp)
    en = out / "energy.png"
    plot_energy(sim, en)
    files.append(en)
    return files
