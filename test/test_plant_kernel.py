"""The compiled plant kernel (numba) against the numpy reference path.

Both paths run side by side on generated lines (:mod:`metro_atc.core.linegen`; some with
incidents, some on a wet rail with traction pulses that make axles slide and ATP
intervene) with the same command sequence: the reference driver's command (compared
between the paths every step), NaN and out-of-range entries and traction pulses mixed in.
Every step the whole fleet state, the ATP state, the energy counters, the events and the
sensor samples must agree bit for bit -- the kernel repeats the numpy operations in the
same order (no fused multiply-add, no reassociation), so no tolerance is needed.
"""

from __future__ import annotations

import json
from operator import attrgetter
from typing import Any

import numpy as np
import pytest

from metro_atc.core.line.scenario import parse_scenario
from metro_atc.core.linegen import generate_line, scenario_yaml
from metro_atc.core.plant.driver import simple_driver
from metro_atc.core.plant.fast import KERNEL_ENV, numba_available, resolve_kernel
from metro_atc.core.plant.line import LineSim

needs_numba = pytest.mark.skipif(not numba_available(), reason="numba not installed")

STATE = ("fleet.x", "fleet.v", "fleet.acc", "fleet.a_dem", "fleet.u_last", "atp.eb", "atp.sb",
         "atp.eoa", "atp.atp_limit", "atp.speed_code", "atp.interventions", "atp.violations",
         "energy.e_trac", "energy.e_elec", "energy.e_fric", "energy.e_res", "energy.e_curve",
         "energy.e_grade", "energy.e_stop_corr", "energy.n_in_service", "fleet.status",
         "fleet.load", "fx", "clamp", "slip")


def _line(seed: int, incidents: bool, wet: bool) -> Any:
    d = generate_line(seed, incidents=incidents)
    if wet:
        d["line"]["adhesion"] = "wet"
    return parse_scenario(scenario_yaml(d), src=f"gen_{seed}")


def _compare(a: LineSim, b: LineSim, ra: Any, rb: Any, where: str) -> None:
    for name in STATE:
        np.testing.assert_array_equal(attrgetter(name)(a), attrgetter(name)(b),
                                      err_msg=f"{where}: {name}")
    assert a.atp.min_sep == b.atp.min_sep, where
    assert a.atp.steps_above_civil == b.atp.steps_above_civil, where
    assert ra.atp_interventions == rb.atp_interventions, where
    assert [repr(e) for e in ra.events] == [repr(e) for e in rb.events], where
    sa, sb = ra.sensor_arrays, rb.sensor_arrays
    assert (sa is None) == (sb is None), where
    if sa is not None:
        for ch in ("t", "trains", "omega", "clamp", "accel", "vref", "car_mass"):
            np.testing.assert_array_equal(getattr(sa, ch), getattr(sb, ch),
                                          err_msg=f"{where}: sensor {ch}")


def _run_pair(scn: Any, seed: int, t_end: float, pulses: bool,
              tamper: Any = None) -> int:
    """Run both kernels in lockstep; returns the number of steps compared."""
    a = LineSim(scn, seed=seed, kernel="numpy")
    b = LineSim(scn, seed=seed, kernel="numba")
    if tamper is not None:
        tamper(b)
    rng = np.random.default_rng(seed)
    k = 0
    while not a.done and a.t < t_end:
        ua, ub = simple_driver(a), simple_driver(b)
        np.testing.assert_array_equal(ua, ub, err_msg=f"driver, step {k}")
        u = ua.copy()
        r = rng.random(a.n)
        u[r < 0.03] = np.nan
        u[(r >= 0.03) & (r < 0.04)] = 7.0
        if pulses and (k // 200) % 3 == 0:  # bursts of full traction (ATP, wheel slides)
            u[: max(a.n // 3, 1)] = 1.0
        ra, rb = a.step(u), b.step(u.copy())
        _compare(a, b, ra, rb, f"step {k}, t = {a.t:.2f} s")
        if k % 40 == 0 and a.t > 60.0:  # ATS departure commands on the way
            i = int(rng.integers(a.n))
            j = int(rng.integers(a.n_st))
            cut = float(rng.uniform(20, 60))
            for s in (a, b):
                s.set_departure(i, j, a.t + 30.0, 95.0, cut)
        k += 1
    assert json.dumps(a.kpis(), sort_keys=True) == json.dumps(b.kpis(), sort_keys=True)
    return k


@needs_numba
@pytest.mark.parametrize("seed,incidents,wet,pulses", [
    (1, False, False, False), (2, True, False, False), (3, True, True, True),
    (4, False, True, True), (5, True, False, True), (6, False, False, True)])
def test_kernels_agree_on_generated_lines(seed: int, incidents: bool, wet: bool,
                                          pulses: bool) -> None:
    """Compiled and numpy steps give identical states, events and samples on any line."""
    n = _run_pair(_line(seed, incidents, wet), seed, 900.0, pulses)
    assert n > 1000


@needs_numba
def test_wet_pulses_exercise_the_slide_path() -> None:
    """The wet-rail case above reaches the numpy slide model from the compiled step."""
    scn = _line(3, True, True)
    sim = LineSim(scn, seed=3, kernel="numba")
    slid = 0
    while sim.t < 900.0:
        u = simple_driver(sim)
        if (sim.step_count // 200) % 3 == 0:
            u[: max(sim.n // 3, 1)] = 1.0
        sim.step(u)
        slid += int(sim.brakes.any_slide)
    assert slid > 0


@needs_numba
def test_comparison_detects_a_kernel_change() -> None:
    """A 0.01 % change of one kernel constant is caught (the comparison can fail)."""
    from metro_atc.core.plant import kernel as kn

    def tamper(sim: LineSim) -> None:
        sim.stepper.c[kn.C_DAVIS_A] *= 1.0001

    with pytest.raises(AssertionError):
        _run_pair(_line(1, False, False), 1, 300.0, False, tamper)


@needs_numba
def test_interp_matches_numpy() -> None:
    """The kernel's interp reproduces np.interp bit for bit, edge cases included."""
    from metro_atc.core.plant.kernel import interp1
    rng = np.random.default_rng(0)
    for _ in range(20):
        xp = np.sort(rng.uniform(-5.0, 5.0, int(rng.integers(2, 60))))
        xp[rng.random(xp.size) < 0.1] = xp[0]  # repeated abscissae
        xp = np.maximum.accumulate(xp)
        fp = rng.normal(size=xp.size)
        x = np.concatenate([rng.uniform(-6.0, 6.0, 200), xp, [np.nan, np.inf, -np.inf]])
        got = np.array([interp1(float(v), xp, fp) for v in x])
        np.testing.assert_array_equal(got, np.interp(x, xp, fp))


def test_kernel_selection(monkeypatch: pytest.MonkeyPatch) -> None:
    """Argument, environment and fallback rules of the kernel choice."""
    monkeypatch.setenv(KERNEL_ENV, "numpy")
    assert resolve_kernel() == "numpy"
    assert resolve_kernel("numpy") == "numpy"
    with pytest.raises(ValueError):
        resolve_kernel("fortran")
    monkeypatch.setenv(KERNEL_ENV, "auto")
    assert resolve_kernel() == ("numba" if numba_available() else "numpy")
    monkeypatch.setattr("metro_atc.core.kernel_choice.numba_available", lambda: False)
    assert resolve_kernel("auto") == "numpy"
    with pytest.raises(RuntimeError):
        resolve_kernel("numba")


@needs_numba
def test_samples_read_out_of_order_or_skipped() -> None:
    """Samples the compiled step computed ahead are used only while they are the next ones.

    Reading patterns: every step, every other step, none, and held results read later in
    reverse order.  The numba path (samples computed with the step once read, normals drawn
    ahead in blocks) must give exactly the numpy path's samples (drawn at access).
    """
    scn = _line(2, True, False)
    a = LineSim(scn, seed=2, kernel="numpy")
    b = LineSim(scn, seed=2, kernel="numba")
    held: list[tuple[Any, Any]] = []
    n_cmp = 0
    for k in range(1600):
        ua, ub = simple_driver(a), simple_driver(b)
        ra, rb = a.step(ua), b.step(ub)
        mode = (k // 200) % 4
        pairs = []
        if mode == 0 or (mode == 1 and k % 2):
            pairs = [(ra, rb)]
        elif mode == 3:
            held.append((ra, rb))
            if len(held) == 3:
                pairs, held = held[::-1], []
        for pa, pb in pairs:
            sa, sb = pa.sensor_arrays, pb.sensor_arrays
            assert (sa is None) == (sb is None), k
            if sa is not None:
                n_cmp += 1
                for ch in ("t", "trains", "omega", "clamp", "accel", "vref", "car_mass"):
                    np.testing.assert_array_equal(getattr(sa, ch), getattr(sb, ch),
                                                  err_msg=f"step {k}: sensor {ch}")
    assert b.sensors.want and n_cmp > 300
    # both at the same place of the sensor stream (buffers may be refilled at other steps)
    np.testing.assert_array_equal(a.sensors.normals(5000), b.sensors.normals(5000))
