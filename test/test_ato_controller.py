"""The on-board ATO's one control path: plans, tracking to the stop, and every edge case.

:class:`OnboardAto` runs every control step through the compiled step
(:mod:`metro_atc.core.ato.control_kernel_step`); there is no second copy to compare with,
so these tests check behaviour against known answers: closed loops stop at the platform
within the door tolerance under the jerk limit; a rejected state (NaN, out of range, time
backwards, a duplicate) raises, is counted and changes nothing (the next commands equal
those of an ATO that never saw it); no plan holds the train; past the stopping point, on a
tracker input that is not a number, the full service brake; the steepest of any number of
grade pieces under the train sets the guard's deceleration; an ATP model without a static
SBI table is a table of +inf; a static SBI limit is never reached; a dispatcher's TSR set
mid-run is obeyed; the fuzzy controller's absolute form and Li n.d. Table 1's rules.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import subprocess
import sys
from pathlib import Path
from typing import Any, Optional

import numpy as np
import pytest

from metro_atc.core import laws
from metro_atc.core.ato import control_kernel as ck
from metro_atc.core.ato import control_kernel_pack as pack
from metro_atc.core.ato import control_kernel_step as cks
from metro_atc.core.ato import tracker_laws
from metro_atc.core.ato.controller import AtoCore
from metro_atc.core.ato.envelope import MODE_ACCEL, MODE_COAST, RunModel
from metro_atc.core.ato.fuzzy import RULE_MATRIX, FuzzyController, FuzzyParams
from metro_atc.core.ato.onboard import (MODE_BRAKE, MODE_DWELL, AtpModel, OnboardAto,
                                        StateRejected, TsrZone)
from metro_atc.core.ato.planner import plan_profile
from metro_atc.core.line.atp_constants import SBI_OFFSET_MPS
from metro_atc.core.line.vehicle import TAIPEI_MRT_6CAR, Track, effort_force, rk4_step

P = TAIPEI_MRT_6CAR
TRACK = Track(np.array([-1e12, 500.0]), np.array([0.0, 0.004]),
              np.array([-1e12]), np.array([80.0 / 3.6]))
DT = 0.1
MODE_RUN = 2
"""TrainState.MODE_ACCELERATE: a state of a train in motion (not dwelling)."""


def _ato(tracker: str = "fuzzy", planner: str = "ectp", stations: Any = (100.0, 1400.0),
         track: Track = TRACK, **kw: Any) -> OnboardAto:
    return OnboardAto(P, track, np.asarray(stations, dtype=float), planner=planner,
                      tracker=tracker, control_period_s=DT, **kw)


def _state(t: float, x: float, v: float, mode: int = MODE_RUN, cur: int = 0, nxt: int = 1,
           target: float = 90.0, dep: float = 0.0) -> dict[str, Any]:
    """A validated state dict (``conversions.state_from_msg``'s keys), SI units."""
    return {"step": int(round(t / DT)), "t_s": float(t), "x_m": float(x), "v_mps": float(v),
            "a_mps2": 0.0, "current_station": cur, "next_station": nxt, "mode": mode,
            "departure_time_s": dep, "target_running_time_s": target,
            "supervision_speed_mps": math.inf, "movement_authority_m": math.inf,
            "mass_kg": math.nan, "again": False}


def _depart(ato: OnboardAto, x0: float, target: float = 90.0, cur: int = 0,
            nxt: int = 1) -> None:
    """A dwell state at the station, then the run is planned at departure (t = 0.1 s)."""
    ato.control(_state(0.0, x0, 0.0, MODE_DWELL, cur, nxt, target))


def _drive(ato: OnboardAto, x0: float, target: float = 90.0, cur: int = 0, nxt: int = 1,
           t_max: float = 200.0, xs: Optional[list[float]] = None,
           grade_of: Any = None) -> tuple[float, float, list[float]]:
    """Close the loop with RK4 from a dwell at x0 until the ATO reports the platform stop.

    (time [s], position [m], efforts); ``xs`` gets the position of each effort [m].
    """
    _depart(ato, x0, target, cur, nxt)
    x, v, t = x0, 0.0, DT
    d = 1.0 if ato.stations[nxt] > x0 else -1.0
    us = []
    while t < t_max:
        u, _, _ = ato.control(_state(t, x, v, MODE_RUN, cur, nxt, target))
        us.append(u)
        if xs is not None:
            xs.append(x)
        if ato.core.last_reason == "stopped at platform":
            break
        grade = d * float(TRACK.grade_at(x)) if grade_of is None else grade_of(x)
        s1, v1 = rk4_step(P, 0.0, v, float(effort_force(P, v, u)), grade, DT)
        x, v, t = x + d * float(s1), float(v1), t + DT
    return t, x, us


@pytest.mark.parametrize("planner,tracker", [("ectp", "fuzzy"), ("fotp", "pi")])
def test_plans_and_stops_at_platform(planner: str, tracker: str) -> None:
    """Plan a run at departure, drive it closed-loop: the train stops at the stop point,
    in time, and the effort never changes faster than the jerk limit allows but where the
    stopping guard brakes in the last metre."""
    ato = _ato(tracker, planner)
    xs: list[float] = []
    t, x, us = _drive(ato, 100.0, xs=xs)
    prof = ato.core.profile
    assert prof is not None and prof.feasible, prof
    assert prof.section_bounds_m[0] == pytest.approx(100.0)
    assert prof.section_bounds_m[-1] == pytest.approx(1400.0)
    assert prof.modes[0] == MODE_ACCEL
    assert ato.core.last_reason == "stopped at platform"
    assert abs(x - 1400.0) < 0.3  # the platform-screen-door tolerance
    assert t < prof.running_time_s + 10.0
    # jerk limit: |du/dt| <= j / a_ref (1 m/s^3 over a1 = 1 m/s^2: 0.1 per 0.1 s step); the
    # stopping guard is a hard bound (a brake, within 1 m of the stop); the arrival's
    # holding brake is the last effort
    du = np.diff(us[:-1])
    fast = np.flatnonzero(np.abs(du) > 0.1 + 1e-9)
    assert all(du[i] < 0.0 and 1400.0 - xs[i + 1] < 1.0 for i in fast), \
        [(xs[i + 1], du[i]) for i in fast]
    assert len(fast) <= 2


def test_runs_in_the_down_direction() -> None:
    """A run with decreasing chainage (stations 1400 -> 100) is tracked and stops too."""
    ato = _ato(stations=(100.0, 1400.0)[::-1])
    _, x, _ = _drive(ato, 1400.0, target=92.0)
    assert ato.core.last_reason == "stopped at platform"
    assert abs(x - 100.0) < 0.3


def test_fuzzy_absolute_form_stops_at_platform() -> None:
    """The fuzzy controller's absolute form (Li n.d., Sec. 2.3) runs in the compiled step:
    its commands differ from the incremental form's and the train still stops."""
    inc = _ato()
    _, _, u_inc = _drive(inc, 100.0)
    ato = _ato()
    ato.core.tracker = FuzzyController(FuzzyParams(gain=1.0, incremental=False))
    _, x, us = _drive(ato, 100.0)
    assert us[:len(u_inc)] != u_inc[:len(us)]
    assert ato.core.last_reason == "stopped at platform"
    assert abs(x - 1400.0) < 0.3


def test_fuzzy_rules_at_their_centres() -> None:
    """At the centre of each (d, e) set pair only one rule fires fully: the compiled
    controller's output is that rule's singleton (Li n.d., Table 1)."""
    for i, d_n in enumerate((1.0, 0.0, -1.0)):
        for j, e_n in enumerate((1.0, 0.5, 0.0, -0.5, -1.0)):
            assert tracker_laws.flc(e_n, d_n) == RULE_MATRIX[i, j], (e_n, d_n)
    # between P and Z of e (e = 0.25, d zero): half of each, 0.25
    assert tracker_laws.flc(0.25, 0.0) == 0.25


def _hostile(s: dict[str, Any], kind: str, last_t: float) -> dict[str, Any]:
    bad = dict(s)
    if kind == "nan_x":
        bad["x_m"] = math.nan
    elif kind == "inf_v":
        bad["v_mps"] = math.inf
    elif kind == "huge_x":
        bad["x_m"] = 2e12
    elif kind == "nan_t":
        bad["t_s"] = math.nan
    elif kind == "backwards":
        bad["t_s"] = last_t - 5.0
    elif kind == "duplicate":
        bad["t_s"] = last_t
    return bad


def test_rejected_states_change_nothing() -> None:
    """NaN, infinite, out-of-range and backwards or repeated times raise StateRejected,
    are counted, leave the state vector untouched, and the commands after them are those
    of an ATO that never saw them."""
    clean, ato = _ato(), _ato()
    _depart(clean, 100.0)
    _depart(ato, 100.0)
    kinds = ("nan_x", "inf_v", "huge_x", "nan_t", "backwards", "duplicate")
    x, v, t, k = 100.0, 0.0, DT, 0
    while t < 40.0:
        s = _state(t, x, v)
        u_ref = clean.control(s)
        u_got = ato.control(s)
        assert u_got[:2] == u_ref[:2]
        if int(round(t / DT)) % 17 == 0:
            before = ato.core.state.copy()
            mode, n = ato.last_mode, ato.rejected
            with pytest.raises(StateRejected):
                ato.control(_hostile(s, kinds[k % len(kinds)], t))
            assert ato.rejected == n + 1
            assert kinds[k % len(kinds)] in ("nan_x", "inf_v", "huge_x", "nan_t") \
                or "time" in ato.last_rejection
            assert np.array_equal(ato.core.state, before) and ato.last_mode == mode
            k += 1
        s1, v1 = rk4_step(P, 0.0, v, float(effort_force(P, v, u_ref[0])), 0.0, DT)
        x, v, t = x + float(s1), float(v1), t + DT
    assert k >= len(kinds) and v > 5.0


def test_no_plan_holds_the_train() -> None:
    """No run planned (a train outside the timetable's stops): holding brake at rest,
    full service brake moving; the per-train state is not touched."""
    ato = _ato()
    u, mode, planned = ato.control(_state(0.0, 50.0, 0.0, cur=-1, nxt=0))
    assert (u, mode, planned) == (ck.HOLD_BRAKE, MODE_BRAKE, None)
    assert ato.core.last_reason.startswith("no plan")
    u, mode, _ = ato.control(_state(0.1, 50.0, 4.0, cur=-1, nxt=0))
    assert (u, mode) == (ck.SAFE_BRAKE, MODE_BRAKE)
    assert not ato.core.state.any()


def test_overshoot_brakes() -> None:
    """More than 2 m past the stopping point: the full service brake, with the reason;
    within 2 m the stop tail still tracks (no overshoot reason)."""
    ato = _ato()
    _depart(ato, 100.0)
    ato.control(_state(0.1, 100.0, 0.0))
    u, mode, _ = ato.control(_state(0.2, 1401.5, 1.0))
    assert "overshot" not in ato.core.last_reason
    u, mode, _ = ato.control(_state(0.3, 1402.5, 1.0))
    assert (u, mode) == (ck.SAFE_BRAKE, MODE_BRAKE)
    assert ato.core.last_reason.startswith("overshot the stopping point")
    assert ato.core.last_effort == ck.SAFE_BRAKE


def test_tracker_input_not_a_number_brakes() -> None:
    """A tracker that divides by a zero scale (e/0): full service brake, the tracker's
    state kept (no NaN enters it)."""
    ato = _ato()
    ato.core.tracker = FuzzyController(FuzzyParams(e_scale_mps=0.0))
    _depart(ato, 100.0)
    u, mode, _ = ato.control(_state(0.1, 100.0, 0.0))
    assert (u, mode) == (ck.SAFE_BRAKE, MODE_BRAKE)
    assert ato.core.last_reason.startswith("tracker input not finite")
    st = ato.core.state
    i = ck.STATE_INDEX
    assert (st[i["has_e"]], st[i["e"]], st[i["tu"]]) == (0.0, 0.0, 0.0)
    assert np.isfinite(st).all() or not np.isnan(st).any()


def test_steepest_of_many_grade_pieces_sets_the_brake() -> None:
    """A 0.5 m piece of -4 % among level pieces under a 141 m train (64 samples over the
    train would miss it): the achievable deceleration is the service brake on -4 %."""
    starts = np.array([-1e12, 1000.0, 1030.0, 1030.5, 1060.0, 1090.0])
    grades = np.array([0.0, 0.001, -0.04, 0.0, 0.002, 0.0])
    track = Track(starts, grades, np.array([-1e12]), np.array([80.0 / 3.6]))
    ato = _ato(track=track)
    ato._pack(ato.core)
    c = np.asarray(ato._kconst).view(ck.CONSTANTS)[0]
    want = max(laws.guaranteed_decel_on_grade(P.max_service_brake_mps2, 0.04), 0.05)
    for x in (1040.0, 1100.0, 1170.0):  # the piece under the front, mid-train, the rear
        assert cks.brake_capability(c, ato._kline, x) == want
    level = max(laws.guaranteed_decel_on_grade(P.max_service_brake_mps2, 0.0), 0.05)
    assert cks.brake_capability(c, ato._kline, 1200.0) == level  # the rear is past it


def _run_max_speed(atp: Optional[AtpModel]) -> tuple[float, list[float]]:
    ato = _ato(atp=atp)
    _, x, us = _drive(ato, 100.0, target=70.0)
    vs = []
    # replay the efforts on the plant for the speeds (the same closed loop)
    xx, v = 100.0, 0.0
    for u in us:
        s1, v1 = rk4_step(P, 0.0, v, float(effort_force(P, v, u)), float(TRACK.grade_at(xx)),
                          DT)
        xx, v = xx + float(s1), float(v1)
        vs.append(v)
    return max(vs), us


def test_atp_without_static_table_is_no_limit() -> None:
    """An ATP model without a static SBI table gives the commands of a table of +inf; a
    table with NaN is refused; a 12 m/s table is never reached."""
    atp = AtpModel(b_g=0.5 * P.emergency_brake_mps2, t_r=1.0, t_sbi=2.0, g_down=0.0,
                   sbi_offset_mps=SBI_OFFSET_MPS, train=P)
    inf_tab = dataclasses.replace(atp, grid_x0_m=0.0, grid_dx_m=1.0,
                                  sbi_static_mps=np.full(2000, np.inf))
    v_none, u_none = _run_max_speed(atp)
    v_inf, u_inf = _run_max_speed(inf_tab)
    assert u_none == u_inf and v_none > 15.0
    with pytest.raises(ValueError):
        dataclasses.replace(atp, sbi_static_mps=np.array([10.0, math.nan]))
    low = dataclasses.replace(inf_tab, sbi_static_mps=np.full(2000, 12.0))
    v_low, _ = _run_max_speed(low)
    assert v_low < 12.0 - SBI_OFFSET_MPS


def test_dispatcher_tsr_set_mid_run_is_obeyed() -> None:
    """TSRs set on a running ATO (a dispatcher's) reach the compiled step: approaching a
    5 m/s zone at speed, the command brakes where it motored without the zone."""
    ato = _ato()
    _depart(ato, 100.0)
    v, x, t = 0.0, 100.0, DT
    while v < 15.0:
        u, _, _ = ato.control(_state(t, x, v))
        s1, v1 = rk4_step(P, 0.0, v, float(effort_force(P, v, u)), 0.0, DT)
        x, v, t = x + float(s1), float(v1), t + DT
    free = _ato()
    free.core, free._kconst = ato.core, None  # the same plan and state, no TSR
    before = ato.core.state.copy()
    u_free = free.control(_state(t, x, v))[0]
    ato.core.state[:] = before
    ato.tsrs = (TsrZone(x + 150.0, x + 300.0, 5.0, 0.0, 0.0, math.inf),)
    u_tsr = ato.control(_state(t, x, v))[0]
    assert u_free > -0.1 and u_tsr < u_free


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


_MINI_LOOP = """
import json
from metro_atc.core.ato.onboard import OnboardAto
from metro_atc.core.closed_loop import run_closed_loop
from metro_atc.core.line.scenario import load_scenario
out = []
orig = OnboardAto.control
def control(self, s):
    r = orig(self, s)
    out.append((r[0].hex(), r[1], self.core.last_reason))
    return r
OnboardAto.control = control
run_closed_loop(load_scenario("mini"), duration_s=120.0)
print(json.dumps(out))
"""


def test_the_same_source_runs_as_python() -> None:
    """``NUMBA_DISABLE_JIT=1`` (debugging) runs the planners and the control step as Python:
    a ``mini`` closed loop (120 s) gives the compiled run's efforts (bit for bit), modes and
    reasons."""
    root = Path(__file__).resolve().parents[1]
    got = {}
    for jit_off in ("0", "1"):
        env = dict(os.environ, NUMBA_DISABLE_JIT=jit_off,
                   PYTHONPATH=os.pathsep.join([str(root), os.environ.get("PYTHONPATH", "")]))
        r = subprocess.run([sys.executable, "-c", _MINI_LOOP], env=env, capture_output=True,
                           text=True, timeout=600, cwd=root)
        assert r.returncode == 0, r.stderr[-2000:]
        got[jit_off] = json.loads(r.stdout.strip().splitlines()[-1])
    assert got["0"] == got["1"]
    moving = [o for o in got["0"] if o[1] != MODE_DWELL]
    assert len(moving) > 100 and {o[2] for o in moving} >= {"tracking"}
    assert pack.control_step_fn() is cks.control_step


def test_grade_force_of_a_train_too_short_to_resolve() -> None:
    """A train whose length vanishes at its position: the grade force of the piece under
    its front (the mean over any interval inside that piece), not 0/0."""
    short = dataclasses.replace(P, length_m=1e-13)
    ato = OnboardAto(short, TRACK, np.array([100.0, 1400.0]), control_period_s=DT)
    _depart(ato, 100.0)
    ato.control(_state(0.1, 100.0, 0.0))
    c = np.asarray(ato._kconst).view(ck.CONSTANTS)[0]
    p = ato._kplan[2]
    ph = p[:ck.N_PH].view(ck.PLAN)[0]
    run = ato.core.run
    for s in (200.0, 700.0):  # level, then the 0.4 % piece from x = 500 m
        want = float(run.mean_grade_force(s - 10.0, s))
        assert ck.grade_force(c, ph, p, s) == pytest.approx(want, rel=1e-9, abs=1e-6)
    assert ck.grade_force(c, ph, p, 700.0) > 0.0
