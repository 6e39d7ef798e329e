"""Brake diagnosis on generated steep lines, ROS-free.

The ROS-free closed loop (plant with sensors, real ATO and ATS cores,
:func:`metro_atc.core.closed_loop.run_closed_loop`) runs generated 3-train lines with a TSR
on their steepest descent (grades to -40 per mille) and the brake diagnosis of every train
(:class:`metro_atc.core.brake.line_monitor.LineBrakeMonitor`, the node's per-train watch):

* fault free: no level rise at all (no OK -> WARN, no ERROR).  The previous decision rule
  (mu_b_hat judged alone once the filter's std < 0.012) gave 4 WARNs on seed 0;
* a pad-friction fault (mu_b 0.10 on every axle of the instrumented car of the train that
  breaks down, from 60 s), on the same lines: announced while in force and at the latest
  ``PAD_DETECT_AFTER_EB_S`` into the breakdown's emergency brake.  The bound is the
  requirement's test, not a measurement: Lin 2010b, Table II brakes for 5 s and
  the abnormal-pad case (mu_b = 0.1 < 0.2) must be flagged within that brake application
  (mu_b is only observable while the pads are applied).  Measured on seed 0: 3.4 s into the
  emergency brake while the brake watch carried a model error for the plant's wheelset
  inertia at the demanded deceleration (service brakes then carried too little
  information); with the plant fixed and that term gone, 5.3 s into the first service
  brake at speed (349 s after the onset, before the breakdown).

The monitor's own plumbing (publication thinning, transition counting) is checked on
synthetic data first.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from metro_atc.core.brake.line_monitor import IDLE_PERIOD_S, published
from metro_atc.core.closed_loop import run_closed_loop
from metro_atc.core.line.scenario import Scenario, parse_scenario
from metro_atc.core.linegen import generate_line, scenario_yaml

SEEDS = (0,)
"""Generated lines (3 trains each) with descents of 40 per mille, a TSR and a breakdown.
Seed 0, the line the previous decision rule raised 4 WARNs on, run fault free and with the
pad fault. (Seed 2 passed too and was cut: it takes the same code path, and a line run
with the diagnosis costs ~30 s of a quiet core.)"""
PAD_DETECT_AFTER_EB_S = 5.0
"""Pad flaw announced at most this long after the emergency brake of the breakdown [s]: the
5 s braking test of Lin 2010b, Table II (see module docstring)."""


def _scenario(seed: int, fault: bool = False) -> tuple[dict[str, Any], Scenario]:
    g = generate_line(seed, incidents=True, n_trains=3)
    if fault:
        victim = [x["train"] for x in g["incidents"] if x["kind"] == "breakdown"][0]
        g["faults"] = [{"kind": "pad_mu", "train": victim, "at_s": 60.0, "mu_b": 0.1}]
    return g, parse_scenario(scenario_yaml(g), src=f"<test {g['name']}>")


def test_published_thins_like_the_simulator() -> None:
    """Every braking sample, otherwise one per idle period per train."""
    t = np.arange(1, 101) * 0.05
    clamp = np.zeros((100, 2, 4))
    clamp[40:60, 0, :] = 5000.0
    last = np.full(2, -math.inf)
    pub = published(clamp, t, last, IDLE_PERIOD_S)
    assert pub[40:60, 0].all()
    idle = np.flatnonzero(pub[:, 1])
    assert np.allclose(np.diff(t[idle]), IDLE_PERIOD_S)
    assert last[1] == t[idle[-1]]


@pytest.mark.parametrize("seed", SEEDS)
def test_steep_tsr_lines_fault_free_no_alarm(seed: int) -> None:
    """Fault-free trains braking on -40 per mille descents and in TSRs: no level rise."""
    g, scn = _scenario(seed)
    assert min(x["grade_permille"] for x in g["line"]["gradients"]) <= -35.0
    b = run_closed_loop(scn, brake=True).brake
    assert b["brake_observer_updates"] > 1000  # the diagnosis did run (trains braked)
    assert b["brake_false_alarms"] == 0, b


@pytest.mark.parametrize("seed", SEEDS)
def test_pad_fault_detected_on_steep_line(seed: int) -> None:
    """A pad-friction fault is announced within the stated delay of the emergency brake."""
    g, scn = _scenario(seed, fault=True)
    t_eb = [x["at_s"] for x in g["incidents"] if x["kind"] == "breakdown"][0]
    t_fault = g["faults"][0]["at_s"]
    b = run_closed_loop(scn, brake=True).brake
    assert b["brake_faults"] == 1
    assert b["brake_faults_detected"] == 1, b
    t_detect = t_fault + b["brake_detect_delays_s"][0]
    assert t_fault < t_detect <= t_eb + PAD_DETECT_AFTER_EB_S, b
    assert b["brake_false_alarms"] == 0, b
