"""ATO core: planner interface and the stateful AtoCore used by the ato_controller node."""

from __future__ import annotations

import math

import numpy as np
import pytest

from metro_atc.core.ato.controller import HOLD_BRAKE, SAFE_BRAKE, AtoCore
from metro_atc.core.ato.envelope import MODE_ACCEL, MODE_COAST, RunModel
from metro_atc.core.ato.planner import plan_profile
from metro_atc.core.line.vehicle import TAIPEI_MRT_6CAR, Track, effort_force, rk4_step

P = TAIPEI_MRT_6CAR
TRACK = Track(np.array([-1e12, 500.0]), np.array([0.0, 0.004]),
              np.array([-1e12]), np.array([80.0 / 3.6]))


def _drive(core: AtoCore, x0: float, dt: float = 0.1, t_max: float = 200.0
           ) -> tuple[float, float, list[float]]:
    """Close the loop with RK4 until the core reports the platform stop."""
    x, v, t = x0, 0.0, 0.0
    us = []
    d = 1.0 if core.run is not None and core.run.direction > 0 else -1.0
    while t < t_max:
        u = core.command(t, x, v)
        us.append(u)
        if core.last_reason == "stopped at platform":
            break
        grade = float(core.run.grade(core.run.run_coordinate(x))) if core.run else 0.0
        f = float(effort_force(P, v, u))
        s1, v1 = rk4_step(P, 0.0, v, f, grade, dt)
        x, v, t = x + d * float(s1), float(v1), t + dt
    return t, x, us


@pytest.mark.parametrize("planner,tracker", [("ectp", "fuzzy"), ("fotp", "pi")])
def test_core_plans_and_stops_at_platform(planner: str, tracker: str) -> None:
    """Plan a Blue-line run, drive it closed-loop; the train stops at the platform point."""
    core = AtoCore(P, TRACK, planner, tracker, 0.1)
    prof = core.plan(100.0, 1400.0, 90.0)
    assert prof.feasible, prof.message
    assert prof.section_bounds_m[0] == pytest.approx(100.0)
    assert prof.section_bounds_m[-1] == pytest.approx(1400.0)
    assert prof.modes[0] == MODE_ACCEL
    t, x, us = _drive(core, 100.0)
    assert core.last_reason == "stopped at platform"
    assert abs(x - 1400.0) < (0.1 if tracker == "fuzzy" else 0.5)
    assert t < prof.running_time_s + 10.0
    # jerk limit: |du/dt| <= j / a_ref
    assert np.max(np.abs(np.diff(us[:-1]))) <= 0.1 * 1.0 / 1.0 + 1e-9


def test_core_runs_in_the_down_direction() -> None:
    """A run with decreasing chainage is planned in the run coordinate and stops too."""
    core = AtoCore(P, TRACK, "ectp", "fuzzy", 0.1)
    prof = core.plan(1400.0, 100.0, 92.0)
    assert prof.feasible
    _, x, _ = _drive(core, 1400.0)
    assert abs(x - 100.0) < 0.1


def test_bad_inputs_give_safe_brake() -> None:
    """NaN, stale or out-of-order states brake with a reason; no plan holds the train."""
    core = AtoCore(P, TRACK, "fotp", "fuzzy", 0.1)
    c = core.command_ex(0.0, 100.0, 0.0)
    assert not c.ok and c.u == HOLD_BRAKE
    core.plan(100.0, 1400.0, 95.0)
    assert core.command(0.0, 100.0, 0.0) >= 0.0
    c = core.command_ex(0.1, math.nan, 1.0)
    assert (c.u, c.ok) == (SAFE_BRAKE, False) and "non-finite" in c.reason
    c = core.command_ex(0.2, 100.1, 1.0, now_s=5.0)
    assert (c.u, c.ok) == (SAFE_BRAKE, False) and "stale" in c.reason
    core.command(0.3, 100.2, 1.0)
    c = core.command_ex(0.1, 100.2, 1.0)
    assert c.u == SAFE_BRAKE and "backwards" in c.reason


def test_infeasible_targets_return_fastest_profile() -> None:
    """A target below the minimum or NaN gives the flat-out profile, flagged, with a message."""
    core = AtoCore(P, TRACK, "ectp", "fuzzy", 0.1)
    fast = core.plan(100.0, 1400.0, 30.0)
    assert not fast.feasible and "minimum running time" in fast.message
    assert fast.running_time_s > 30.0
    nan = core.plan(100.0, 1400.0, math.nan)
    assert not nan.feasible and "invalid" in nan.message
    assert nan.running_time_s == pytest.approx(fast.running_time_s)
    ok = core.plan(100.0, 1400.0, fast.running_time_s + 5.0)
    assert ok.feasible and ok.energy_j < fast.energy_j
    assert abs(ok.running_time_s - (fast.running_time_s + 5.0)) < 0.5
    with pytest.raises(ValueError):
        AtoCore(P, TRACK, "nope", "fuzzy")


def test_mmas_profile_sections() -> None:
    """The MMAS profile carries its sections, modes and speed commands.

    The continuous local search moves commands off the 5 km/h lattice and boundaries off the
    equal partition (``core/ato/mmas_polish.py``): commands stay within the code range, the
    bounds increase from the departure to the stop.
    """
    run = RunModel(P, TRACK, 0.0, 1000.0)
    prof = plan_profile(run, 80.0, "mmas", None, n_sections=20, n_ants=20, n_iterations=20)
    assert prof.feasible
    assert prof.section_bounds_m.size == 21 and prof.modes.size == 20
    assert np.all((prof.codes_mps > 0.0) & (prof.codes_mps <= 80.0 / 3.6 + 1e-9))
    assert np.all(np.diff(prof.section_bounds_m) > 0.0)
    assert prof.section_bounds_m[0] == pytest.approx(0.0)
    assert prof.section_bounds_m[-1] == pytest.approx(1000.0)
    assert prof.running_time_s <= 80.0 + 1e-6
    assert np.any(prof.modes == MODE_COAST) and math.isfinite(prof.coast_point_m)
