"""ATP: braking-curve mathematics (Ke 2010, Fig. 1) and the fuzzed safety property."""

from __future__ import annotations

import os

import numpy as np
import pytest

from metro_atc.core.plant.driver import adversarial_driver, random_driver, simple_driver
from metro_atc.core.plant.line import LineSim
from metro_atc.core.line.scenario import parse_scenario
from metro_atc.core.line.track import (braking_envelope, ebi_speed, stopping_distance,
                                       window_min_ahead, window_min_behind)

FUZZ = """
name: fuzz
sources: [test]
sim: {control_period_s: 0.25, duration_s: 330}
trains: {count: 4, preset: taipei_mrt_6car, initial_load_pax: 300}
line:
  stations:
    - {name: A, position_m: 0}
    - {name: B, position_m: 700}
    - {name: C, position_m: 1500}
    - {name: D, position_m: 2300}
  line_speed_kmh: 80
  speed_limits:
    - {start_m: -1000, limit_kmh: 80}
    - {start_m: 1000, limit_kmh: 45}
    - {start_m: 1200, limit_kmh: 80}
  gradients:
    - {start_m: -1000, grade_permille: 0}
    - {start_m: 200, grade_permille: -25}
    - {start_m: 600, grade_permille: 0}
  tail_track_m: 300
  turnback_s: 30
  turnback_sidings: 1
  adhesion: ADHESION
signalling: {mode: MODE, safety_margin_m: 40, response_time_s: 1.0}
timetable:
  first_departure_s: 20
  periods: [{start_s: 0, headway_s: 45, boarding_pph: [600, 600, 600, 0]}]
passengers: {alight_fraction: [0, 0.3, 0.3, 1], min_dwell_s: 10, door_overhead_s: 5}
disturbances: {departure_delay_prob: 0.5, departure_delay_mean_s: 8}
incidents:
  - {kind: tsr, start_m: 1700, end_m: 1900, limit_kmh: 25, at_s: TSR_AT, duration_s: 150}
  - {kind: breakdown, train: train_02, at_s: BD_AT, duration_s: 40}
"""

N_RUNS = int(os.environ.get("METRO_ATC_FUZZ_RUNS", "12"))
"""Fuzz runs of the property test (raise it for a longer offline campaign)."""


def fuzz_sim(seed: int, mode: str, wet: bool, duration_s: float = 330.0) -> LineSim:
    """The fuzz line with seed-dependent TSR/breakdown times."""
    rng = np.random.default_rng(1000 + seed)
    text = (FUZZ.replace("MODE", mode).replace("ADHESION", "wet" if wet else "dry")
            .replace("duration_s: 330", f"duration_s: {duration_s}")
            .replace("TSR_AT", f"{rng.uniform(0, 150):.1f}")
            .replace("BD_AT", f"{rng.uniform(30, 200):.1f}"))
    return LineSim(parse_scenario(text, "fuzz.yaml"), seed=seed, trace_period_s=0.0)


def test_ebi_closed_form_is_the_worst_case_stop() -> None:
    """The EBI speed is exactly the speed whose worst-case stop (t_r at a_w, then b_g) is D."""
    rng = np.random.default_rng(0)
    d = rng.uniform(1.0, 1500.0, 200)
    for a_w, t_r, b_g in [(1.0, 1.0, 1.2), (0.3, 2.5, 0.7), (0.0, 0.5, 1.0)]:
        v = ebi_speed(d, 0.0, a_w, t_r, b_g)
        assert np.allclose(stopping_distance(v, a_w, t_r, b_g), d, rtol=1e-10)
        # time stepping of the worst case (exact per step, vectorised) lands on D
        h = 0.01  # divides every t_r below, so the switch time is hit exactly
        s = v[:10].copy()
        x = np.zeros_like(s)
        t = 0.0
        while np.any(s > 0.0):
            acc = a_w if t < t_r - 1e-12 else -b_g
            hh = np.where(s + acc * h < 0.0, s / b_g, h)  # last partial step to rest
            x += np.where(s > 0.0, s * hh + 0.5 * acc * hh * hh, 0.0)
            s = np.where(s > 0.0, s + acc * hh, 0.0)
            t += h
        assert np.allclose(x, d[:10], atol=1e-6, rtol=1e-9)
    # with a target speed, the braking part ends at v_t
    v = ebi_speed(500.0, 10.0, 1.0, 1.0, 1.0)
    w = v + 1.0
    assert v * 1.0 + 0.5 + (w * w - 100.0) / 2.0 == pytest.approx(500.0)


def test_braking_envelope_and_windows_against_brute_force() -> None:
    """Reverse cumulative-min envelope and sliding minima equal their O(N^2) definitions."""
    rng = np.random.default_rng(1)
    c = rng.uniform(5.0, 25.0, 300)
    dx, b = 2.0, 0.9
    env = braking_envelope(c, dx, b)
    brute = np.array([min(np.sqrt(c[j] ** 2 + 2 * b * (j - k) * dx) for j in range(k, c.size))
                      for k in range(c.size)])
    assert np.allclose(env, brute)
    for n in (0, 1, 7, 40):
        assert np.allclose(window_min_ahead(c, n), [c[k:k + n + 1].min() for k in range(300)])
        assert np.allclose(window_min_behind(c, n),
                           [c[max(k - n, 0):k + 1].min() for k in range(300)])


def _drive(sim: LineSim, kind: int, rng: np.random.Generator) -> int:
    """Run to the end with fuzzed commands; returns the interventions."""
    while not sim.done:
        if kind == 0:
            u = random_driver(sim, rng)
        elif kind == 1:
            u = adversarial_driver(sim, rng)
        else:  # chase: odd trains brake at random, even trains full traction
            u = np.where(np.arange(sim.n) % 2 == 1,
                         np.where(rng.random(sim.n) < 0.3, -1.0, simple_driver(sim)), 1.0)
        sim.step(u)
    return int(sim.kpis()["atp_interventions"])


@pytest.mark.parametrize("run", range(N_RUNS))
def test_property_no_violation_under_fuzzed_commands(run: int) -> None:
    """Random / adversarial / chasing commands never cause a separation or overspeed
    violation (moving and fixed block, dry and wet rail, TSR and breakdown incidents)."""
    mode = "fixed_block" if run % 4 >= 2 else "moving_block"
    wet = run % 2 == 1
    sim = fuzz_sim(run, mode, wet)
    rng = np.random.default_rng(run)
    interventions = _drive(sim, run % 3, rng)
    k = sim.kpis()
    assert k["atp_violations"] == 0
    assert k["min_separation_m"] is None or k["min_separation_m"] >= sim.atp.margin - 1e-6
    if run % 3 != 0:  # full traction cannot go unchecked
        assert interventions > 0


def test_monitor_detects_violations_without_atp() -> None:
    """Negative control: with the ATP curves disabled the same fuzzing violates."""
    sim = fuzz_sim(1, "moving_block", False)
    sim.atp.ebi_static = np.full_like(sim.atp.ebi_static, 1e9)
    sim.atp.sbi_static = np.full_like(sim.atp.sbi_static, 1e9)
    sim.atp.curve.c1 = 1e12  # unlimited movement authority
    _drive(sim, 1, np.random.default_rng(1))
    assert sim.kpis()["atp_violations"] > 0


def test_tsr_is_respected_and_eb_latches() -> None:
    """Full traction into a 25 km/h TSR: ATP keeps the speed under the ceiling, counts the
    intervention once per onset and holds the emergency brake to standstill."""
    sim = fuzz_sim(3, "moving_block", False)
    rng = np.random.default_rng(3)
    tsr = [t for t in sim.incidents.tsrs]
    assert tsr
    saw_eb = False
    while not sim.done:
        eb_before = sim.atp.eb.copy()
        sim.step(adversarial_driver(sim, rng))
        # once applied, the EB stays until standstill
        assert not np.any(eb_before & ~sim.atp.eb & (sim.fleet.v > 0.0) & sim.fleet.run)
        saw_eb = saw_eb or bool(sim.atp.eb.any())
    assert saw_eb
    assert sim.kpis()["atp_violations"] == 0


def test_fixed_block_speed_codes() -> None:
    """Fixed-block speed codes are 5 km/h multiples below the limit; EoA at block entries."""
    sim = fuzz_sim(0, "fixed_block", False, duration_s=1200.0)
    codes = []
    while not sim.done:
        sim.step(simple_driver(sim))
        st = sim.states()
        run = st["in_service"]
        codes.extend((st["speed_code_mps"][run] * 3.6).tolist())
        eoa = st["movement_authority_m"][run]
        atp, geo = sim.atp, sim.geometry
        on_block = np.isclose(((eoa + atp.margin - geo.x0) / atp.block_len) % 1.0, 0.0) | \
            np.isclose(((eoa + atp.margin - geo.x0) / atp.block_len) % 1.0, 1.0) | \
            (eoa >= geo.eoa_end - 1e-9) | (eoa + atp.margin > geo.x_switch)
        assert np.all(on_block)
    c = np.array(codes)
    assert np.allclose(c / 5.0, np.round(c / 5.0), atol=1e-6)
    assert c.max() <= 80.0 + 1e-9
    assert sim.kpis()["completed_trains"] == sim.n
