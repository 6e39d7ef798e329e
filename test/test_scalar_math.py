"""The plain-float fast paths of the per-train ATO give the numpy results bit for bit.

Graph speed: the ATO's per-step tracking evaluates its tables at one point a few
dozen times per step; ``metro_atc.core.scalar_math`` and the ``*_at`` twins in
``vehicle``, ``track``, ``envelope``, ``reference_curve`` and ``fuzzy`` replace 0-d numpy
calls by plain floats.  Each is compared with the numpy function it names on many random
inputs (exact equality, not a tolerance), and a closed-loop run's ATO inputs are replayed
through the on-board ATO once with the fast paths and once with the numpy ones: every
command must be identical.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from metro_atc.core.ato import controller as ctl_mod
from metro_atc.core.ato import fuzzy
from metro_atc.core.ato import onboard as onb_mod
from metro_atc.core.ato.envelope import RunModel
from metro_atc.core.ato.onboard import OnboardAto, atp_model_for, envelope_limits, tsr_zones
from metro_atc.core.ato.reference_curve import ProfileReference
from metro_atc.core.bridge import timetable_for, track_for, train_for
from metro_atc.core.line import track as track_mod
from metro_atc.core.line import vehicle as veh
from metro_atc.core.line.scenario import load_scenario
from metro_atc.core.scalar_math import clip1, interp1, maximum1, minimum1, sqrt_or_nan

RNG = np.random.default_rng(13)


def _same(a: float, b: Any) -> bool:
    """Bitwise-equal floats (NaN equal to NaN)."""
    b = float(b)
    return (math.isnan(a) and math.isnan(b)) or a == b


def test_interp1_matches_numpy() -> None:
    """Random knots and points: inside, on knots, at and beyond both ends, NaN."""
    for _ in range(300):
        n = int(RNG.integers(2, 40))
        xp = np.sort(RNG.uniform(-1e3, 1e3, n))
        if RNG.random() < 0.3:
            xp[int(RNG.integers(0, n - 1))] = xp[int(RNG.integers(0, n))]  # duplicates
            xp = np.sort(xp)
        fp = RNG.normal(0.0, 50.0, n)
        xs = np.concatenate((RNG.uniform(xp[0] - 10.0, xp[-1] + 10.0, 40), xp,
                             [xp[0], xp[-1], -np.inf, np.inf, np.nan]))
        xl, fl = xp.tolist(), fp.tolist()
        for x in xs.tolist():
            assert _same(interp1(x, xl, fl), np.interp(x, xp, fp)), (x, xl, fl)


def test_small_helpers_match_numpy() -> None:
    """clip1 / maximum1 / minimum1 / sqrt_or_nan against np.clip / maximum / minimum / sqrt."""
    vals = [0.0, -0.0, 1.5, -2.0, math.inf, -math.inf, math.nan, 1e-300]
    with np.errstate(invalid="ignore"):
        for a in vals:
            assert _same(sqrt_or_nan(a), np.sqrt(a))
            assert _same(clip1(a, -1.0, 1.0), np.clip(a, -1.0, 1.0))
            for b in vals:
                assert _same(maximum1(a, b), np.maximum(a, b))
                assert _same(minimum1(a, b), np.minimum(a, b))


def test_vehicle_and_ebi_match_numpy() -> None:
    """Traction, resistance and the ATP braking curve at one point: the numpy values."""
    p = veh.TAIPEI_MRT_6CAR
    for v in np.concatenate((RNG.uniform(-5.0, 40.0, 2000), [p.v1_mps, p.v2_mps, 0.0])):
        v = float(v)
        assert veh.max_traction_accel_at(p, v) == float(veh.max_traction_accel(p, v))
        assert veh.max_traction_force_at(p, v) == float(veh.max_traction_force(p, v))
        assert veh.resistance_force_at(p, v) == float(veh.resistance_force(p, v))
    for _ in range(3000):
        d, tgt = float(RNG.uniform(-200.0, 3000.0)), float(RNG.choice([0.0, RNG.uniform(0, 25)]))
        a_w, t_r, b_g = (float(x) for x in RNG.uniform([0.0, 0.5, 0.3], [1.5, 3.0, 1.2]))
        assert _same(track_mod.ebi_speed_at(d, tgt, a_w, t_r, b_g),
                     track_mod.ebi_speed(d, tgt, a_w, t_r, b_g))


def test_fuzzy_scalar_matches_numpy() -> None:
    """flc_output_at on random and on membership break points; a whole tracker sequence."""
    pts = np.concatenate((RNG.uniform(-3.0, 3.0, 4000), np.arange(-2.0, 2.01, 0.25)))
    ds = np.concatenate((RNG.uniform(-3.0, 3.0, 4000), np.arange(-2.0, 2.01, 0.5)))
    for e, d in zip(pts.tolist(), RNG.permutation(ds).tolist()):
        assert fuzzy.flc_output_at(e, d) == float(fuzzy.flc_output(e, d)), (e, d)
    fast, ref = fuzzy.FuzzyController(), fuzzy.FuzzyController()
    v = 0.0
    for k in range(3000):
        r, ff = float(12.0 + 3.0 * math.sin(k / 40.0)), float(RNG.uniform(-0.3, 0.3))
        u_fast = float(fast.step(r, v, 0.25, ff))
        u_ref = float(ref.step(np.asarray(r), np.asarray(v), 0.25, np.asarray(ff)))  # numpy
        assert u_fast == u_ref, k
        if k % 7 == 0:  # an outer guard lowered the command
            fast.set_output(u_fast - 0.1, ff)
            ref.set_output(u_ref - 0.1, ff)
        v = max(v + 0.4 * u_fast + float(RNG.normal(0.0, 0.05)), 0.0)


@pytest.fixture(autouse=True)
def python_ato_path(monkeypatch: pytest.MonkeyPatch) -> None:
    """These tests prove the Python path against numpy: the compiled ATO step declines every
    state (it is proven against the Python path in ``test/test_ato_control_kernel.py``)."""
    monkeypatch.setattr(OnboardAto, "_kernel_control", lambda self, s: None)


@pytest.fixture(scope="module")
def blue() -> Any:
    """The Blue line scenario with its train, track, limits and ATP model."""
    scn = load_scenario("taipei_blue")
    train = train_for(scn)
    return scn, train, track_for(scn), envelope_limits(scn, train), atp_model_for(scn, train)


def test_run_model_and_reference_match_numpy(blue: Any) -> None:
    """RunModel.*_at and ProfileReference.speed_at on both directions' runs."""
    scn, train, track, limits, _ = blue
    st = timetable_for(scn).station_positions_m
    for i0, i1 in ((0, 1), (5, 6), (7, 6), (len(st) - 1, len(st) - 2)):
        run = RunModel(train, track, float(st[i0]), float(st[i1]), limits)
        xs = RNG.uniform(min(st[i0], st[i1]) - 300.0, max(st[i0], st[i1]) + 300.0, 400)
        for x in xs.tolist():
            s = run.run_coordinate_at(x)
            assert s == float(run.run_coordinate(x))
            assert run.grade_at(s) == float(run.grade(s))
            assert run.ceiling_e_at(s) == float(run.ceiling_e(s))
            assert run.mean_grade_force_at(s - train.length_m, s) \
                == float(run.mean_grade_force(s - train.length_m, s))
        sg = np.linspace(0.0, run.length_m, 300)
        vp = np.minimum(np.sqrt(2.0 * 0.8 * sg), np.sqrt(2.0 * 0.7 * (run.length_m - sg)))
        ref = ProfileReference(sg, np.minimum(vp, 22.0), run.length_m, tail_decel=0.6,
                               creep_speed=0.5, tail_brake=0.3)
        for s in np.concatenate((RNG.uniform(-5.0, run.length_m + 5.0, 500), sg)).tolist():
            assert ref.speed_at(s) == float(ref.speed(np.asarray(s))), s


def _brake_capability_numpy(self: OnboardAto, x_from: float, x_to: float) -> float:
    """The 64-sample numpy construction of OnboardAto._brake_capability (reference)."""
    a, b = (x_from, x_to) if x_from <= x_to else (x_to, x_from)
    xs = np.linspace(a - self.train.length_m, max(b, a) + 1.0, 64)
    g = float(np.min(self.track.grade_at(xs)))
    return max(self.train.max_service_brake_mps2 + veh.G_MPS2 * min(g, 0.0), 0.05)


def _speed_cap_reference(self: OnboardAto, s: dict[str, Any], x_at: Any = None,
                         authority: bool = True) -> float:
    """OnboardAto.speed_cap as written before its per-state context (the reference)."""
    x, v, t = float(s["x_m"]), float(s["v_mps"]), float(s["t_s"])
    if x_at is not None:
        x = float(x_at)
    cap = math.inf
    atp = self.atp
    sup = float(s["supervision_speed_mps"])
    if math.isfinite(sup):
        cap = sup - atp.sbi_offset_mps - onb_mod.SPEED_MARGIN_MPS
    tab = atp.sbi_static_mps
    assert tab is not None
    k0 = int((x - atp.grid_x0_m) / atp.grid_dx_m)
    k1 = int((x + v * onb_mod.CAP_LOOKAHEAD_S + 1.0 - atp.grid_x0_m) / atp.grid_dx_m) + 1
    k0 = min(max(k0, 0), tab.size - 1)
    k1 = min(max(k1, k0 + 1), tab.size)
    cap = min(cap, float(tab[k0:k1].min()) - atp.sbi_offset_mps - onb_mod.SPEED_MARGIN_MPS)
    b = self._plan_decel(x)
    ma = float(s["movement_authority_m"])
    if authority and math.isfinite(ma):
        d = ma - x - onb_mod.AUTHORITY_MARGIN_M
        cap = min(cap, math.sqrt(2.0 * b * max(d, 0.0)),
                  atp.sbi_speed(d, v) - onb_mod.SPEED_MARGIN_MPS)
    lead = self.core.limits.restriction_lead_m
    margin = self.core.limits.speed_margin_mps
    for z in self.tsrs:
        if not (z.known_s <= t < z.to_s) or x - self.train.length_m >= z.end_m:
            continue
        lim = max(z.limit_mps - margin, 0.5 * z.limit_mps)
        d = z.start_m - lead - x
        cap = min(cap, math.sqrt(lim * lim + 2.0 * b * max(d, 0.0)),
                  atp.sbi_speed_to(z.start_m - x - v * onb_mod.CAP_LOOKAHEAD_S, z.limit_mps)
                  - onb_mod.SPEED_MARGIN_MPS)
    return max(cap, 0.0)


def test_speed_caps_equal_the_former_formula(blue: Any) -> None:
    """speed_cap (one context per state, the SBI table minimum over a list) and the guard
    give the former per-call construction's floats exactly, with TSRs known, active and
    cleared, authorities finite and infinite, supervision speeds known and not, planned
    and unplanned."""
    scn, train, track, limits, atp = blue
    st = timetable_for(scn).station_positions_m
    lo, hi = float(min(st)), float(max(st))
    zones = []
    for _ in range(6):
        a = float(RNG.uniform(lo, hi - 500.0))
        t0 = float(RNG.uniform(0.0, 400.0))
        zones.append(onb_mod.TsrZone(a, a + float(RNG.uniform(50.0, 600.0)),
                                     float(RNG.uniform(4.0, 18.0)), t0, t0 + 60.0,
                                     t0 + float(RNG.uniform(100.0, 300.0))))
    ato = OnboardAto(train, track, st, limits=limits, atp=atp, tsrs=zones)
    n = 0
    for planned in (False, True):
        if planned:
            ato.plan(2, 110.0, 0.0)
        for _ in range(1500):
            x = float(RNG.uniform(lo - 100.0, hi + 100.0))
            s = {"x_m": x, "v_mps": float(RNG.choice([0.0, RNG.uniform(0.0, 25.0)])),
                 "t_s": float(RNG.uniform(0.0, 700.0)), "next_station": 3,
                 "supervision_speed_mps": float(RNG.choice([math.inf, RNG.uniform(0, 30)])),
                 "movement_authority_m": float(RNG.choice(
                     [math.inf, x + float(RNG.uniform(-20.0, 2000.0))]))}
            for x_at, auth in ((None, True), (x + 7.5, True), (x + 7.5, False),
                               (x - 3.0, True)):
                assert ato.speed_cap(s, x_at, auth) == _speed_cap_reference(ato, s, x_at, auth)
            with pytest.MonkeyPatch.context() as mp:
                ref_guard = ato.guard(s)
                mp.setattr(OnboardAto, "speed_cap", _speed_cap_reference)
                mp.setattr(OnboardAto, "_cap_at",
                           lambda self, ctx, x_at, auth, s=s: _speed_cap_reference(
                               self, s, x_at, auth))
                assert ato.guard(s) == ref_guard
            n += 1
    assert n == 3000 and any(z.known_s < 700.0 for z in zones)


def test_brake_capability_matches_samples(blue: Any) -> None:
    """The two-piece shortcut equals the minimum over the 64 samples."""
    scn, train, track, limits, atp = blue
    st = timetable_for(scn).station_positions_m
    ato = OnboardAto(train, track, st, limits=limits, atp=atp)
    for x in RNG.uniform(float(st[0]) - 200.0, float(st[-1]) + 200.0, 3000).tolist():
        x2 = x + float(RNG.choice([0.0, RNG.uniform(-500.0, 500.0)]))
        assert ato._brake_capability(x, x2) == _brake_capability_numpy(ato, x, x2)


def _cap_at_per_call(self: OnboardAto, ctx: tuple[Any, ...], x_at: Any,
                     authority: bool) -> float:
    """OnboardAto._cap_at as written before its calls were inlined (the reference).

    One call each to AtpModel.static_sbi, OnboardAto._plan_decel and AtpModel.sbi_speed.
    """
    x, v, cap, ma, zones, a_w = ctx[:6]
    if x_at is not None:
        x = float(x_at)
    atp = self.atp
    c = atp.static_sbi(x, x + v * onb_mod.CAP_LOOKAHEAD_S + 1.0) - onb_mod.SPEED_MARGIN_MPS
    if c < cap:
        cap = c
    b = self._plan_decel(x)
    if authority and math.isfinite(ma):
        d = ma - x - onb_mod.AUTHORITY_MARGIN_M
        c = math.sqrt(2.0 * b * (0.0 if 0.0 > d else d))
        if c < cap:
            cap = c
        c = atp.sbi_speed(d, v, a_w) - onb_mod.SPEED_MARGIN_MPS
        if c < cap:
            cap = c
    if zones:
        lead = self.core.limits.restriction_lead_m
        rear = x - self.train.length_m
        for z, lim in zones:
            if rear >= z.end_m:
                continue
            d = z.start_m - lead - x
            cap = min(cap, math.sqrt(lim * lim + 2.0 * b * max(d, 0.0)),
                      atp.sbi_speed_to(z.start_m - x - v * onb_mod.CAP_LOOKAHEAD_S,
                                       z.limit_mps) - onb_mod.SPEED_MARGIN_MPS)
    return 0.0 if 0.0 > cap else cap


def test_inlined_cap_equals_the_per_call_one(blue: Any) -> None:
    """OnboardAto._cap_at (static SBI, planned deceleration and authority SBI speed written
    out) gives the per-call construction's float on generated states: both directions'
    runs planned and none, positions beyond the line's ends, speeds 0 to 25 m/s, finite and
    infinite authorities (some behind the train), TSRs known and not."""
    scn, train, track, limits, atp = blue
    st = timetable_for(scn).station_positions_m
    lo, hi = float(min(st)), float(max(st))
    zones = [onb_mod.TsrZone(lo + 900.0, lo + 1300.0, 8.0, 0.0, 50.0, 500.0)]
    n = 0
    for plan in (None, (2, 110.0), (9, 95.0), (len(st) - 1, 100.0)):
        ato = OnboardAto(train, track, st, limits=limits, atp=atp, tsrs=zones)
        if plan is not None and plan[0] + 1 < len(st):
            ato.plan(plan[0], plan[1], 0.0)
        for _ in range(2500):
            x = float(RNG.uniform(lo - 200.0, hi + 200.0))
            s = {"x_m": x, "v_mps": float(RNG.choice([0.0, RNG.uniform(0.0, 25.0)])),
                 "t_s": float(RNG.uniform(0.0, 700.0)),
                 "supervision_speed_mps": float(RNG.choice([math.inf, RNG.uniform(0, 30)])),
                 "movement_authority_m": float(RNG.choice(
                     [math.inf, x + float(RNG.uniform(-60.0, 3000.0))]))}
            ctx = ato._cap_context(s)
            for x_at in (None, x + float(RNG.uniform(-10.0, 60.0)), x - 3.0):
                for auth in (True, False):
                    got = ato._cap_at(ctx, x_at, auth)
                    want = _cap_at_per_call(ato, ctx, x_at, auth)
                    assert got == want and math.copysign(1.0, got) == math.copysign(1.0, want)
                    n += 1
    assert n == 4 * 2500 * 6


def _numpy_paths(mp: pytest.MonkeyPatch) -> None:
    """Route every fast path of the tracking back to the numpy function it replaces."""
    mp.setattr(ctl_mod, "resistance_force_at",
               lambda p, v: float(veh.resistance_force(p, v)))
    mp.setattr(ctl_mod, "max_traction_force_at",
               lambda p, v: float(veh.max_traction_force(p, v)))
    mp.setattr(ctl_mod, "sqrt_or_nan", lambda x: float(np.sqrt(x)))
    mp.setattr(onb_mod, "max_traction_accel_at",
               lambda p, v: float(veh.max_traction_accel(p, v)))
    mp.setattr(onb_mod, "ebi_speed_at",
               lambda *a: float(track_mod.ebi_speed(*a)))
    mp.setattr(RunModel, "run_coordinate_at", lambda self, x: float(self.run_coordinate(x)))
    mp.setattr(RunModel, "mean_grade_force_at",
               lambda self, a, b: float(self.mean_grade_force(a, b)))
    mp.setattr(RunModel, "ceiling_e_at", lambda self, s: float(self.ceiling_e(s)))
    mp.setattr(ProfileReference, "speed_at",
               lambda self, s: float(self.speed(np.asarray(s))))
    mp.setattr(fuzzy, "flc_output_at", lambda e, d: float(fuzzy.flc_output(e, d)))
    mp.setattr(OnboardAto, "_brake_capability", _brake_capability_numpy)
    mp.setattr(OnboardAto, "_cap_at", _cap_at_per_call)


def test_tracking_commands_identical_over_a_run(blue: Any) -> None:
    """A closed-loop run's ATO inputs, replayed with the numpy paths: the same commands.

    The run (600 s of the Blue line peak, trains departing, cruising, braking behind
    others and berthing) records every input of every on-board ATO and its command; the
    replay through fresh ATOs with every fast path routed back to numpy gives each command
    (effort, mode) exactly.
    """
    from metro_atc.core.closed_loop import run_closed_loop

    scn, train, track, limits, atp = blue
    logs: dict[int, list[tuple[str, Any, Any]]] = {}
    orig_c, orig_d = OnboardAto.control, OnboardAto.on_departure

    def control(self: OnboardAto, s: dict[str, Any]) -> Any:
        out = orig_c(self, s)
        logs.setdefault(id(self), []).append(("s", dict(s), (out[0], out[1])))
        return out

    def on_departure(self: OnboardAto, *a: Any) -> Any:
        logs.setdefault(id(self), []).append(("d", a, None))
        return orig_d(self, *a)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(OnboardAto, "control", control)
        mp.setattr(OnboardAto, "on_departure", on_departure)
        res = run_closed_loop(scn, duration_s=600.0)
    moving = sum(1 for lg in logs.values() for k, s, _ in lg if k == "s" and s["v_mps"] > 1.0)
    assert res.stops > 5 and moving > 2000  # a run with real tracking in it
    tt = timetable_for(scn)
    shared: dict[str, Any] = {}
    with pytest.MonkeyPatch.context() as mp:
        _numpy_paths(mp)
        n = 0
        for lg in logs.values():
            ato = OnboardAto(train, track, tt.station_positions_m,
                             control_period_s=float(scn.sim.control_period_s), limits=limits,
                             shared=shared, tsrs=tsr_zones(scn), atp=atp)
            for kind, a, out in lg:
                if kind == "d":
                    ato.on_departure(*a)
                    continue
                u, mode, _ = ato.control(a)
                assert (u, mode) == out, (a, u, mode, out)
                n += 1
    assert n == sum(len([x for x in lg if x[0] == "s"]) for lg in logs.values())
