"""ROS-free closed loop: plant + real ATO + real ATS in lockstep, the graph's data flow.

:func:`run_closed_loop` runs a scenario through :class:`metro_atc.core.plant.line.LineSim`
with one :class:`metro_atc.core.ato.onboard.OnboardAto` per train (what every
``ato_controller`` node runs) and the :class:`metro_atc.core.atr.dispatch.AtsDispatcher` of
``make_dispatcher`` (what the ``ats_regulator`` node runs), step by step:

1. the ATS's start-up commands go to the plant (``set_departure``) and to each ATO
   (``on_departure``, stamped with the departure time, as the node stamps its messages);
2. every step the plant's state of each active train becomes the dict the ATO node gets from
   :func:`metro_atc.nodes.conversions.state_from_msg` (a non-finite supervision speed or
   authority becomes inf) and the ATO's effort is applied; trains without a fresh command
   keep the last one (NaN, as the line simulator node does);
3. every event of the step goes to the ATS; its decision goes to the plant and the ATO before
   the next step (the lockstep barrier of the line simulator waits for it).

Besides the plant's KPIs it measures, from the plant's public state, what a berthing and
TSR study asks of an
ATO that drives inside the ATP envelope (all SI):

- stop error of each arrival [m] (front position at the arrival minus the stop point) the
  ATO berthed; an arrival where the train came to rest under a breakdown or an ATP
  emergency brake (the plant takes any standstill within its +-1 m tolerance as the
  arrival) is no programmed station stop: its error is kept apart (``forced_stop_errors_m``);
- ATP interventions (service or emergency brake onsets) per 100 stops; those within
  ``TSR_NOTICE_ONSET_S`` of a TSR becoming known, with the train inside the zone or within
  ``TSR_APPROACH_M`` of it, are also counted apart (``atp_interventions_at_tsr_notice``): the
  ATP supervises a TSR from its notice time and the ATO learns of it at that same instant,
  so a train already too close to brake for it (or inside it) meets the ATP whatever it does;
- time above the civil limit [s]: train-seconds of trains in service whose speed exceeds the
  permanent/temporary limit in force for the whole train (``LineSim.atp.ceiling_phys`` minus
  the overspeed margin) by more than ``CIVIL_TOL_MPS``;
- speed minima per TSR approach (hunting): the speed of each train from
  ``TSR_APPROACH_M`` before a zone in force (or the last platform before it) to where its
  rear leaves the zone, reduced to its turning points
  (:class:`metro_atc.core.tsr_hunting.SpeedMinima`); a minimum explained by a lower
  permanent limit, a station stop or a stop/hold forced by the incident
  (:func:`metro_atc.core.tsr_hunting.explain`) is no hunting; one approach (brake, hold,
  release) has at most one unexplained minimum (``tsr_speed_minima_max``; all minima:
  ``tsr_speed_minima_raw_max``).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any, Optional

import numpy as np

from metro_atc.core.ato.wiring import AtoWiring, MmasSettings, ato_wiring
from metro_atc.core.atr.dispatch import Dispatch, make_dispatcher
from metro_atc.core.brake.line_monitor import LineBrakeMonitor
from metro_atc.core.bridge import timetable_for
from metro_atc.core.plant.line import LineSim
from metro_atc.core.line.scenario import Scenario
from metro_atc.core.line.track import window_min_ahead, window_min_behind
from metro_atc.core.tsr_hunting import LIMIT_REACH_M, SpeedMinima, explain

CIVIL_TOL_MPS = 0.01
"""Speed above the civil limit that counts as 'above the limit' [m/s] (numerical noise)."""
TSR_APPROACH_M = 800.0
"""Distance before a TSR zone from which a train's speed is watched for hunting [m]."""
TSR_NOTICE_ONSET_S = 1.0
"""An intervention onset this soon after a TSR becomes known counts as one at its notice [s]."""
STOP_WINDOW_M = 0.30
"""Berthing tolerance (platform screen doors, +-0.30 m) [m]."""


@dataclass
class ClosedLoopResult:
    """Figures of one closed-loop run (SI units; see the module docstring)."""

    scenario: str
    regulator: str
    planner: str
    tracker: str
    stops: int
    stop_errors_m: list[float]
    missed_stops: int
    atp_violations: int
    atp_interventions: int
    time_above_civil_s: float
    tsr_minima: list[SpeedMinima]
    energy_kwh: float
    train_km: float
    sim_time_s: float
    wall_s: float
    finished: bool
    kpis: dict[str, Any] = field(default_factory=dict)
    arrivals: list[tuple[int, int, float, float, bool]] = field(default_factory=list)
    """Every arrival: (train index, station index, time [s], stop error [m], forced)."""
    brake: dict[str, Any] = field(default_factory=dict)
    """Brake-diagnosis figures (:meth:`LineBrakeMonitor.summary`) when it ran."""
    interventions_at_tsr_notice: int = 0
    """ATP intervention onsets at a TSR's notice time (module docstring)."""
    ato: Optional[AtoWiring] = None
    """What every train's ATO was built from (:func:`metro_atc.core.ato.wiring.ato_wiring`)."""

    @property
    def forced_stop_errors_m(self) -> list[float]:
        """Errors [m] of arrivals at a standstill forced by a breakdown or an ATP EB."""
        return [err for *_, err, forced in self.arrivals if forced]

    def row(self) -> dict[str, Any]:
        """One JSON-friendly row of the bench (``bench lines``)."""
        err = np.abs(np.asarray(self.stop_errors_m, dtype=float))
        q = (lambda p: float(np.percentile(err, p))) if err.size else (lambda p: math.nan)
        return {
            "scenario": self.scenario, "regulator": self.regulator, "planner": self.planner,
            "tracker": self.tracker, "stops": self.stops,
            "missed_stops": self.missed_stops, "atp_violations": self.atp_violations,
            "atp_interventions": self.atp_interventions,
            "atp_interventions_at_tsr_notice": self.interventions_at_tsr_notice,
            "atp_interventions_per_100_stops": (100.0 * self.atp_interventions
                                                / max(self.stops, 1)),
            "stop_error_p50_m": q(50), "stop_error_p95_m": q(95),
            "stop_error_max_m": float(err.max()) if err.size else math.nan,
            "stops_outside_0p30_m": int(np.count_nonzero(err > STOP_WINDOW_M)),
            "forced_stops": len(self.forced_stop_errors_m),
            "forced_stop_error_max_m": max((abs(e) for e in self.forced_stop_errors_m),
                                           default=0.0),
            "time_above_civil_limit_s": self.time_above_civil_s,
            "tsr_approaches": len(self.tsr_minima),
            "tsr_speed_minima_max": max((m.hunting for m in self.tsr_minima), default=0),
            "tsr_speed_minima_raw_max": max((m.minima for m in self.tsr_minima), default=0),
            "tsr_minima_explained": {c: sum(m.causes.get(c, 0) for m in self.tsr_minima)
                                     for c in sorted({c for m in self.tsr_minima
                                                      for c in m.causes})},
            "energy_kwh": self.energy_kwh,
            "energy_kwh_per_train_km": self.energy_kwh / max(self.train_km, 1e-9),
            "train_km": self.train_km, "sim_time_s": self.sim_time_s,
            "wall_s": self.wall_s, "finished": self.finished, **self.brake,
        }


def run_closed_loop(scn: Scenario, regulator: str = "none", planner: str = "ectp",
                    tracker: str = "fuzzy", seed: int = 0,
                    duration_s: Optional[float] = None, brake: bool = False,
                    mmas: Optional[MmasSettings] = None) -> ClosedLoopResult:
    """Run ``scn`` to its end (or ``duration_s``) in the ROS-free lockstep; see module doc.

    The ATOs are wired as the ``ato_controller`` node wires them
    (:func:`metro_atc.core.ato.wiring.ato_wiring`; ``mmas``: the node's MMAS parameters,
    default theirs).  With ``brake`` the brake sensor samples also go to the brake
    diagnosis (:class:`metro_atc.core.brake.line_monitor.LineBrakeMonitor`).
    """
    w0 = time.perf_counter()
    sim = LineSim(scn, seed=seed, trace_period_s=0.0)
    tt = timetable_for(scn)
    wiring = ato_wiring(scn, planner, tracker, mmas=mmas, tt=tt)
    shared: dict[str, Any] = {}
    tsrs = list(wiring.tsrs)
    atos = [wiring.onboard(shared) for _ in tt.train_ids]
    ats = make_dispatcher(scn, regulator, tt=tt)
    mon = LineBrakeMonitor(scn) if brake else None
    ids = list(tt.train_ids)
    n = len(ids)

    def dispatch(d: Dispatch) -> None:
        sim.set_departure(d.train, d.station, d.departure_s, d.running_s, d.dwell_limit_s)
        atos[d.train].on_departure(d.station, d.departure_s, d.running_s, d.departure_s)

    for d in ats.initial():
        dispatch(d)
    limit_s = sim.duration_s if duration_s is None else min(float(duration_s), sim.duration_s)
    u = np.full(n, math.nan)
    dt = sim.control_period_s
    above = 0.0
    stop_err: list[float] = []
    arrivals: list[tuple[int, int, float, float, bool]] = []
    x_prev = sim.fleet.x.copy()
    dist = 0.0
    approaches: dict[tuple[int, int], SpeedMinima] = {}
    minima: list[SpeedMinima] = []
    itv_prev = np.asarray(sim.atp.interventions).copy()
    at_notice = 0
    reach = int(math.ceil(LIMIT_REACH_M * sim.geometry.inv_dx))
    perm = window_min_ahead(window_min_behind(np.asarray(sim.geometry.static_limit, dtype=float),
                                              int(sim.geometry.n_len) + reach), reach)
    step = 0
    while not sim.done and sim.t < limit_s - 1e-9:
        st = sim.states()
        active = np.flatnonzero(sim.active_mask())
        t = float(sim.t)
        for i in active:
            u[i] = atos[i].control(ato_input(st, int(i), step, t))[0]
        run = sim.active_mask()
        res = sim.step(u.copy())
        step += 1
        if mon is not None:
            mon.on_step(res)
        # ---- measurements on the state after the step (public plant state)
        x, v = sim.fleet.x, sim.fleet.v
        geo = sim.geometry
        k = np.clip(((x - geo.x0) * geo.inv_dx).astype(np.int64), 0,
                    sim.atp.ceiling_phys.size - 1)
        civil = sim.atp.ceiling_phys[k] - sim.geometry.ceiling_tol
        above += dt * float(np.count_nonzero(run & (v > civil + CIVIL_TOL_MPS)))
        moved = np.where(run, np.abs(x - x_prev), 0.0)
        dist += float(np.sum(np.minimum(moved, 100.0)))
        x_prev = x.copy()
        _watch_tsrs(sim, tsrs, run, approaches, minima, perm)
        itv = np.asarray(sim.atp.interventions)
        if (itv != itv_prev).any():
            at_notice += _at_tsr_notice(sim, tsrs, np.flatnonzero(itv > itv_prev))
            itv_prev = itv.copy()
        for ev in res.events:
            if ev.kind == "arrival":
                j = int(ev.train_idx)
                err = float(sim.fleet.x[j] - sim.station_positions_m[ev.station_idx])
                hit = bool(sim.fleet.broken[j] or sim.atp.eb[j])
                if not hit:
                    stop_err.append(err)
                arrivals.append((j, int(ev.station_idx), float(ev.t_s), err, hit))
            cmd = ats.on_event(ids[ev.train_idx], ev.station_idx, ev.kind, ev.t_s)
            if cmd is not None:
                dispatch(cmd)
    minima.extend(a.close() for a in approaches.values())
    kp = sim.kpis()
    return ClosedLoopResult(
        scenario=scn.name, regulator=regulator, planner=planner, tracker=tracker,
        stops=len(arrivals), stop_errors_m=stop_err,
        missed_stops=int(sim.stations.skipped_stops),
        atp_violations=int(kp["atp_violations"]),
        atp_interventions=int(np.sum(sim.atp.interventions)), time_above_civil_s=above,
        tsr_minima=minima, energy_kwh=float(kp["energy_kwh"]), train_km=dist / 1000.0,
        sim_time_s=float(sim.t), wall_s=time.perf_counter() - w0, finished=bool(sim.done),
        kpis=kp, arrivals=arrivals,
        brake=mon.summary() if mon is not None else {}, interventions_at_tsr_notice=at_notice,
        ato=wiring)


def ato_input(st: dict[str, Any], i: int, step: int, t: float) -> dict[str, Any]:
    """The state dict an ATO node gets for train ``i`` from the plant's ``states()`` ``st``.

    As :func:`metro_atc.nodes.conversions.state_from_msg` builds it: a non-finite
    supervision speed or movement authority becomes inf.
    """
    sup = float(st["atp_limit_mps"][i])
    ma = float(st["movement_authority_m"][i])
    return {"step": step, "t_s": t, "x_m": float(st["x_m"][i]),
            "v_mps": float(st["v_mps"][i]), "a_mps2": float(st["a_mps2"][i]),
            "current_station": int(st["current_station"][i]),
            "next_station": int(st["next_station"][i]), "mode": int(st["mode"][i]),
            "departure_time_s": float(st["departure_time_s"][i]),
            "target_running_time_s": float(st["target_running_time_s"][i]),
            "supervision_speed_mps": sup if math.isfinite(sup) else math.inf,
            "movement_authority_m": ma if math.isfinite(ma) else math.inf,
            "mass_kg": float(st["mass_kg"][i])}


def _at_tsr_notice(sim: LineSim, tsrs: list[Any], trains: Any) -> int:
    """How many of the trains with an intervention onset now met it at a TSR's notice."""
    t = float(sim.t)
    n = 0
    for i in trains:
        x = float(sim.fleet.x[i])
        n += any(0.0 <= t - z.known_s <= TSR_NOTICE_ONSET_S
                 and z.start_m - TSR_APPROACH_M <= x <= z.end_m + sim.length_m for z in tsrs)
    return n


def _watch_tsrs(sim: LineSim, tsrs: list[Any], run: Any,
                approaches: dict[tuple[int, int], SpeedMinima], minima: list[SpeedMinima],
                perm: Any) -> None:
    """Update the speed minima of every train inside a TSR approach window (hunting).

    ``perm``: the permanent civil limit over the whole train and ``LIMIT_REACH_M`` either
    side per plant cell of the front [m/s].
    """
    t = float(sim.t)
    st = sim.station_positions_m
    for z_i, z in enumerate(tsrs):
        if not (z.from_s <= t < z.to_s):
            continue
        before = st[st <= z.start_m]
        w0 = max(z.start_m - TSR_APPROACH_M, float(before[-1]) + 1.0 if before.size
                 else -math.inf)
        for i in np.flatnonzero(run):
            x, v = float(sim.fleet.x[i]), float(sim.fleet.v[i])
            key = (z_i, int(i))
            inside = w0 <= x <= z.end_m + sim.length_m
            a = approaches.get(key)
            if not inside:
                if a is not None:
                    minima.append(a.close())
                    del approaches[key]
                continue
            if a is None:
                a = approaches[key] = SpeedMinima()
            k = min(max(int((x - sim.geometry.x0) * sim.geometry.inv_dx), 0), perm.size - 1)
            a.feed(v, explain(v, float(perm[k]), float(np.min(np.abs(st - x))),
                              bool(sim.fleet.broken[i]), float(sim.atp.eoa[i]) - x))
