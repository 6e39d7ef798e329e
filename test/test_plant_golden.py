"""Golden traces: the plant reproduces the recorded physics for recorded command sequences.

The data in ``test/data/golden`` were recorded by ``test/golden.py`` from the plant before it
was split into modules (``git log test/data/golden``).  Each case replays its stored commands
(and ATS departure commands) open loop and compares every output: per-step ATP interventions,
events and sensor-channel sums, the full per-train state every ``stride`` steps (positions,
speeds, energy terms, ATP state, modes, stations, loads), raw sensor samples of a window, the
plot trace and the KPIs.  Tolerance: float round-off (relative 1e-9, absolute 1e-9 of the
quantity's largest magnitude); integer outputs and event kinds identical.

The plant runs its compiled step (:mod:`metro_atc.core.plant.fast`; the laws of
:mod:`metro_atc.core.laws`).  It reproduces the traces bit for bit except the stop-correction
energy, whose resistance term at a stopping sub-step is now Davis's ``A + B v + C v^2``
(was ``A + v (B + C v)``): 1e-13 J on ~1e-6 J; the tolerance is round-off.
"""

from __future__ import annotations

import json
from typing import Any

import numpy as np
import pytest

import golden

RTOL = 1e-9


def _close(name: str, got: np.ndarray, exp: np.ndarray) -> None:
    assert got.shape == exp.shape, f"{name}: shape {got.shape} != {exp.shape}"
    if exp.dtype.kind in "iub":
        np.testing.assert_array_equal(got, exp, err_msg=name)
        return
    fin = np.isfinite(exp)
    scale = float(np.max(np.abs(exp[fin]))) if fin.any() else 0.0
    np.testing.assert_allclose(got, exp, rtol=RTOL, atol=RTOL * max(scale, 1e-12),
                               equal_nan=True, err_msg=name)


ADDED_KPIS = {"stops", "stop_error_m", "stops_outside_0p30_m", "missed_stops",
              "atp_interventions_per_100_stops", "time_above_civil_limit_s",
              "withdrawn_trains"}
"""Line KPIs that did not exist when the golden traces were recorded."""


def _kpi_close(path: str, got: Any, exp: Any) -> None:
    if isinstance(exp, dict):
        assert isinstance(got, dict) and set(got) == set(exp), path
        for k in exp:
            _kpi_close(f"{path}.{k}", got[k], exp[k])
    elif isinstance(exp, list):
        assert isinstance(got, list) and len(got) == len(exp), path
        for i, (g, e) in enumerate(zip(got, exp)):
            _kpi_close(f"{path}[{i}]", g, e)
    elif isinstance(exp, float) and isinstance(got, (int, float)):
        assert got == pytest.approx(exp, rel=RTOL, abs=1e-9), path
    else:
        assert got == exp, path


@pytest.mark.parametrize("case", golden.CASES, ids=[c.name for c in golden.CASES])
def test_golden_trace(case: golden.Case) -> None:
    """Open-loop replay of the recorded commands reproduces every recorded output."""
    exp = dict(np.load(golden.path_of(case)))
    got = golden.replay(case, exp.pop("u"), exp.pop("ats"))
    kp_exp = json.loads(bytes(exp.pop("kpis")))
    kp_got = json.loads(bytes(got.pop("kpis")))
    assert set(got) == set(exp)
    ev_g, ev_e = got.pop("events"), exp.pop("events")
    assert ev_g.shape == ev_e.shape, "number of events"
    np.testing.assert_array_equal(ev_g[:, :4], ev_e[:, :4])  # step, train, station, kind
    np.testing.assert_array_equal(ev_g[:, 5:7], ev_e[:, 5:7])  # boarded, alighted
    _close("events", ev_g[:, 4:], ev_e[:, 4:])
    for key in sorted(exp):
        _close(key, got[key], exp[key])
    # KPIs added after the recording (berthing, time above the civil limit) are new keys;
    # every recorded KPI must be reproduced
    added = set(kp_got) - set(kp_exp)
    assert added <= ADDED_KPIS, added
    _kpi_close("kpis", {k: kp_got[k] for k in kp_exp if k in kp_got}, kp_exp)


def test_golden_detects_a_change() -> None:
    """The comparison fails when the commands differ (the test can fail)."""
    case = golden.CASES[2]
    exp = dict(np.load(golden.path_of(case)))
    u = exp["u"].copy()
    moving = np.flatnonzero(exp["state_s_v_mps"][:, 0] > 10.0)  # train 0 at speed
    k = int(moving[len(moving) // 2]) * case.stride
    u[k:k + 4, 0] = np.where(u[k:k + 4, 0] > 0, 0, -5000)  # 1 s of coasting / more brake
    got = golden.replay(case, u, exp["ats"])
    with pytest.raises(AssertionError):
        _close("state_s_x_m", got["state_s_x_m"], exp["state_s_x_m"])
