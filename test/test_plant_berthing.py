"""Berthing and ATP-envelope KPIs: stop error per arrival, time above the
civil limit, interventions per 100 stops."""

from __future__ import annotations

import json
import math

import numpy as np

import golden
from metro_atc.core.line.scenario import load_scenario
from metro_atc.core.plant.driver import simple_driver
from metro_atc.core.plant.kpi import BERTH_TOL_M, RunLog, berthing_kpis
from metro_atc.core.plant.line import LineSim


def _log(errors: list[float], skipped: int, interventions: int, steps_above: int,
         dt: float) -> RunLog:
    z = np.zeros((1, 2))
    return RunLog(scenario="x", seed=0, train_ids=["train_01"], n_st=2, t=0.0, step_count=0,
                  completed=np.ones(1, dtype=bool), act_arr=z, act_dep=z, sched_arr=z,
                  sched_dep=z, cmd_rt=z, sched_running_s=np.zeros(1), energy={},
                  interventions=np.array([interventions]), violations=np.zeros(1, dtype=int),
                  min_sep=math.inf, margin=50.0, boarded=np.zeros(2), left_behind=np.zeros(2),
                  skipped_stops=skipped, stop_errors_m=np.array(errors, dtype=float),
                  steps_above_civil=steps_above, control_period_s=dt)


def test_berthing_kpis_known_answer() -> None:
    """Percentiles of |error|, stops outside the window, per-100-stop rate, civil time."""
    k = berthing_kpis(_log([0.1, -0.4, 0.2, math.nan], skipped=1, interventions=2,
                           steps_above=6, dt=0.25))
    assert k["stops"] == 4  # 3 berthed + 1 missed (NaN = entry placement, not a stop)
    assert k["stop_error_m"]["max"] == 0.4
    assert k["stop_error_m"]["p50"] == 0.2
    assert k["stops_outside_0p30_m"] == 1
    assert k["missed_stops"] == 1
    assert k["atp_interventions_per_100_stops"] == 50.0
    assert k["time_above_civil_limit_s"] == 1.5
    assert BERTH_TOL_M == 0.30


def test_arrival_events_carry_the_stop_error() -> None:
    """Every running arrival records front minus stop point, inside the arrival window."""
    sim = LineSim(load_scenario("mini"), seed=0)
    while not sim.done:
        sim.step(simple_driver(sim))
    arr = [e for e in sim.event_log() if e.kind == "arrival"]
    errs = np.array([e.stop_error_m for e in arr if e.station_idx > 0])
    assert errs.size > 0 and np.isfinite(errs).all()
    assert np.all(np.abs(errs) <= sim.tol_stop + 1e-9)
    k = sim.kpis()
    assert k["stop_error_m"]["max"] == float(np.max(np.abs(errs)))
    assert k["stops"] == errs.size + k["missed_stops"]


def test_time_above_civil_limit_counts_overspeed() -> None:
    """Full traction into TSRs runs above the civil limit; a cautious driver never does."""
    case = next(c for c in golden.CASES if c.name == "mini_atp_eb")
    exp = dict(np.load(golden.path_of(case)))
    got = golden.replay(case, exp.pop("u"), exp.pop("ats"))
    assert json.loads(bytes(got["kpis"]))["time_above_civil_limit_s"] > 0.0
    sim = LineSim(load_scenario("mini"), seed=0)
    while not sim.done:
        sim.step(simple_driver(sim))
    assert sim.kpis()["time_above_civil_limit_s"] == 0.0
