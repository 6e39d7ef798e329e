"""``LineSim.run_driven`` (several steps per compiled call) against the per-step loop.

The reference is ``while not done and t < T: step(simple_driver(sim))`` with the samples of
every step read.  ``run_driven`` must leave every state array, the ATP and energy counters,
the events, the KPIs, the trace and the sensor samples (faults included) identical bit for
bit, on real scenarios (slices), fault and incident scenarios and generated lines; the
compiled calls must actually carry the run (and stop for each reason they have), and the
comparison must be able to fail.
"""

from __future__ import annotations

import copy
import json
from operator import attrgetter
from typing import Any
from unittest import mock

import numpy as np
import pytest

import golden
from metro_atc.core.line.scenario import Scenario, load_scenario, parse_scenario
from metro_atc.core.line.service import describe
from metro_atc.core.linegen import generate_line, scenario_yaml
from metro_atc.core.plant import line as plant_line
from metro_atc.core.plant import kernel_run as kr
from metro_atc.core.plant.driver import simple_driver
from metro_atc.core.plant.line import LineSim, SensorBlock


STATE = ("fleet.x", "fleet.v", "fleet.acc", "fleet.a_dem", "fleet.u_last", "atp.eb", "atp.sb",
         "atp.eoa", "atp.atp_limit", "atp.speed_code", "atp.interventions", "atp.violations",
         "energy.e_trac", "energy.e_elec", "energy.e_fric", "energy.e_res", "energy.e_curve",
         "energy.e_grade", "energy.e_stop_corr", "energy.n_in_service", "fleet.status",
         "fleet.load", "fx", "clamp", "slip", "stations.act_arr", "stations.act_dep",
         "stations.boarded", "stations.left_behind")


def _rows(blocks: list[SensorBlock]) -> Any:
    """One row per (instant, train): t, train, car mass, 4 omega, 4 clamp, accel, vref
    (instants in order, the trains of an instant in the block's order)."""
    out = [np.empty((0, 13))]
    for b in blocks:
        ns, nc = b.t.size, b.trains.size
        cols = [np.broadcast_to(b.t[:, None], (ns, nc)), np.broadcast_to(b.trains, (ns, nc)),
                np.broadcast_to(b.car_mass, (ns, nc))]
        out.append(np.concatenate([c[..., None] for c in cols] + [
            b.omega.reshape(ns, nc, -1), b.clamp.reshape(ns, nc, -1), b.accel[..., None],
            b.vref[..., None]], axis=2, dtype=np.float64).reshape(-1, 13))
    return np.concatenate(out)


def _same_stacked(p: list[Any], q: list[Any]) -> bool:
    """True if the two lists of equal-shape arrays stack to equal arrays (NaN equal to NaN,
    as ``assert_array_equal``); False if they differ or do not stack (compare one by one)."""
    try:
        sp, sq = np.asarray(p), np.asarray(q)
        return sp.shape == sq.shape and bool(np.array_equal(sp, sq, equal_nan=True))
    except (TypeError, ValueError):
        return False


def _per_step(sim: LineSim, until_s: float, samples: bool) -> tuple[list[Any], list[Any], int]:
    events: list[Any] = []
    blocks: list[SensorBlock] = []
    n_int = 0
    while not sim.done and sim.t < until_s:
        res = sim.step(simple_driver(sim))
        events += res.events
        n_int += res.atp_interventions
        if samples and res.sensor_arrays is not None:
            blocks.append(res.sensor_arrays)
    return events, blocks, n_int


def _compare(a: LineSim, b: LineSim, ev_a: list[Any], ev_b: list[Any],
             bl_a: list[SensorBlock], bl_b: list[SensorBlock]) -> None:
    assert a.t == b.t and a.step_count == b.step_count
    for name in STATE:
        np.testing.assert_array_equal(attrgetter(name)(a), attrgetter(name)(b), err_msg=name)
    assert a.atp.min_sep == b.atp.min_sep
    assert a.atp.steps_above_civil == b.atp.steps_above_civil
    assert [repr(e) for e in ev_a] == [repr(e) for e in ev_b]
    ra, rb = _rows(bl_a), _rows(bl_b)
    np.testing.assert_array_equal(ra, rb, err_msg="sensor samples")
    assert a.sensors.next_sample_t == b.sensors.next_sample_t
    for key in a.trace:
        assert len(a.trace[key]) == len(b.trace[key]), key
        if _same_stacked(a.trace[key], b.trace[key]):
            continue
        for p, q in zip(a.trace[key], b.trace[key]):  # the first difference, reported
            np.testing.assert_array_equal(p, q, err_msg=f"trace {key}")
    for key, val in a.energy_breakdown().items():
        np.testing.assert_array_equal(val, b.energy_breakdown()[key], err_msg=key)
    assert json.dumps(a.kpis(), sort_keys=True) == json.dumps(b.kpis(), sort_keys=True)
    # the same position in the normals stream (buffers drawn ahead differently)
    np.testing.assert_array_equal(a.sensors.normals(5), b.sensors.normals(5))
    a.sensors.zpos -= 5
    b.sensors.zpos -= 5


def _sims(scn: Scenario, seed: int, n: int = 2) -> list[LineSim]:
    """``n`` simulators of ``scn`` built alike; the static description (a pure function of
    the scenario, the dearest part of the construction on a long line) is computed once and
    each simulator gets its own deep copy of it."""
    d = describe(scn)
    with mock.patch.object(plant_line, "describe", lambda s, p=None: copy.deepcopy(d)):
        return [LineSim(scn, seed=seed) for _ in range(n)]


def _check(scn: Scenario, seed: int, until_s: float, samples: bool = True,
           tamper: Any = None) -> Any:
    """Run both ways on ``scn``; returns the run_driven summary."""
    a, b = _sims(scn, seed)
    if tamper is not None:
        tamper(b)
    ev_a, bl_a, n_int = _per_step(a, until_s, samples)
    run = b.run_driven(until_s, samples=samples)
    assert run.steps == b.step_count
    assert run.atp_interventions == n_int
    assert run.n_samples == sum(x.t.size * x.trains.size for x in bl_a)
    _compare(a, b, ev_a, run.events, bl_a, run.blocks)
    return run


def _gen(seed: int, incidents: bool, wet: bool) -> Scenario:
    d = generate_line(seed, incidents=incidents)
    if wet:
        d["line"]["adhesion"] = "wet"
    return parse_scenario(scenario_yaml(d), src=f"gen_{seed}")


@pytest.mark.parametrize("name,seed,until_s", [
    ("taipei_blue", 3, 1500.0), ("thsr", 5, 1800.0), ("taipei_blue_delay", 1, 1200.0),
    ("mini_pad_fault", 1, 1200.0)])
def test_run_driven_matches_the_step_loop(name: str, seed: int, until_s: float) -> None:
    """Packaged scenarios (slices; a held train; pad fault and breakdowns)."""
    run = _check(load_scenario(name), seed, until_s)
    assert run.kernel_steps > 0.5 * run.steps  # most steps run inside compiled calls
    assert run.calls < run.kernel_steps / 5  # several steps per call
    assert run.stops[kr.STOP_HIT] > 0 and run.stops[kr.STOP_TIME] > 0


@pytest.mark.parametrize("case", ["mini_incidents", "mini_atp_eb"])
def test_run_driven_with_incidents_and_sensor_faults(case: str) -> None:
    """Fixed block, wet rail, TSRs, hold, breakdown, wheel / pad / sensor faults."""
    c = next(c for c in golden.CASES if c.name == case)
    run = _check(golden.scenario_of(c), c.seed, c.t_end_s)
    assert run.kernel_steps > 0.5 * run.steps
    assert np.isnan(_rows(run.blocks)).any()  # a dropout fault reached the samples


@pytest.mark.parametrize("seed,incidents,wet", [
    (1, False, False), (2, True, False), (3, True, True), (4, False, True), (6, True, False)])
def test_run_driven_on_generated_lines(seed: int, incidents: bool, wet: bool) -> None:
    """Generated lines; on a wet rail the slide model interrupts the compiled calls."""
    run = _check(_gen(seed, incidents, wet), seed, 1500.0)
    assert run.kernel_steps > 0.5 * run.steps
    if wet:
        assert run.stops[kr.STOP_SLOW] > 0  # rolled back before a slide-model step


def test_run_driven_without_samples() -> None:
    """Samples not read: same plant, the normals stream untouched (as the step loop)."""
    run = _check(load_scenario("taipei_blue"), 2, 900.0, samples=False)
    assert not run.blocks and run.kernel_steps > 0.5 * run.steps


def test_run_driven_in_pieces_with_commands() -> None:
    """Chunks, ATS departure commands and other commands in between: still identical."""
    a, b = _sims(load_scenario("taipei_blue"), 4)
    rng = np.random.default_rng(0)
    ev_a: list[Any] = []
    ev_b: list[Any] = []
    bl_a: list[SensorBlock] = []
    bl_b: list[SensorBlock] = []
    t = 0.0
    while t < 1200.0:
        t += float(rng.uniform(1.0, 40.0))
        e, bl, _ = _per_step(a, t, True)
        ev_a += e
        bl_a += bl
        run = b.run_driven(t)
        ev_b += run.events
        bl_b += run.blocks
        if rng.random() < 0.5:  # an outside command step (NaN keeps, clipped)
            u = simple_driver(a)
            u[rng.random(a.n) < 0.2] = np.nan
            u[0] = 3.0
            for sim, ev, bl in ((a, ev_a, bl_a), (b, ev_b, bl_b)):
                res = sim.step(u.copy())
                ev += res.events
                if res.sensor_arrays is not None:
                    bl.append(res.sensor_arrays)
        i, j = int(rng.integers(a.n)), int(rng.integers(a.n_st))
        for sim in (a, b):
            sim.set_departure(i, j, a.t + 20.0, 95.0, 40.0)
    _compare(a, b, ev_a, ev_b, bl_a, bl_b)


def test_comparison_detects_a_change() -> None:
    """A 0.01 % change of a constant of the compiled run is caught."""
    from metro_atc.core.plant import kernel as kn

    def tamper(sim: LineSim) -> None:
        assert sim.stepper is not None
        sim.stepper.c.view(kn.CONSTANTS)[0]["davis_a"] *= 1.0001

    with pytest.raises(AssertionError):
        _check(load_scenario("mini_pad_fault"), 1, 400.0, tamper=tamper)
