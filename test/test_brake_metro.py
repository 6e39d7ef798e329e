"""Tests of the metro brake-by-wire observer (the node's core)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from metro_atc.core.brake import diagnosis as dg
from metro_atc.core.brake import metro_car as mc

P = mc.MetroCarParams()


def test_adhesion_curve_shape() -> None:
    """Odd, slope mu_max (2/pi) k_s at zero creep, bounded by mu_max."""
    s = np.linspace(-0.3, 0.3, 601)
    mu = mc.adhesion(s, 0.3, P)
    assert np.allclose(mu, -mc.adhesion(-s, 0.3, P))
    h = 1e-7
    slope = (mc.adhesion(np.array(h), 0.3, P) - mc.adhesion(np.array(-h), 0.3, P)) / (2 * h)
    assert slope == pytest.approx(0.3 * 2 / np.pi * P.adh_k, rel=1e-6)
    assert np.abs(mu).max() < 0.3
    assert np.abs(mu).max() > 0.25


def test_clamp_force_from_eq4() -> None:
    """4 axles x 2 mu_b R_b F_c / r_w equals M a (Lin 2010b, eq. 4 brake torque)."""
    fc = float(P.clamp_for_decel(np.array(1.0)))
    assert 4 * 2 * P.mu_b * P.r_b * fc / P.r_w == pytest.approx(P.mass * 1.0)
    assert 15e3 < fc < 30e3


def test_from_train_params_duck_typed() -> None:
    """Parameters can be taken from a TrainParams-like object."""
    class TP:
        mass_kg = 240_000.0
        cars = 6
        wheel_radius_m = 0.42
        pad_mu_nominal = 0.4

    p = mc.from_train_params(TP())
    assert p.mass == pytest.approx(40_000.0)
    assert (p.r_w, p.mu_b, p.r_b) == (0.42, 0.4, P.r_b)


def _run(scen: mc.MetroScenario, seed: int = 0, t_end: float = 5.0,
         corrupt: bool = False) -> tuple[list[mc.DiagnosisResult], mc.MetroLog]:
    log = mc.simulate_metro(P, [scen], t_end=t_end)
    meas = mc.measure_metro(log, mc.MetroSensorNoise(), np.random.default_rng(seed))
    y, fc = meas["y"][0], meas["fc"][0]
    obs = mc.MetroBrakeObserver(P, 0.02, mu_rail=scen.mu_rail, mass=float(log.mass[0]))
    out = []
    for k in range(y.shape[0]):
        yk, fck = y[k].copy(), fc[k].copy()
        mask = None
        if corrupt and k % 7 == 3:
            yk[[1, 4]] = np.nan                     # NaN wheel speed and acceleration
        if corrupt and k % 11 == 5:
            fck[2] = np.inf                         # bad clamp force: held
        if corrupt and k % 13 == 0:
            mask = [True, True, False, True, True, False]
        if corrupt and 150 <= k < 175:              # 0.5 s total dropout
            yk[:] = np.nan
        out.append(obs.update(0.02 * k, yk[:4], fck, yk[4], yk[5], mask))
        if corrupt and k % 17 == 9:                 # stale / duplicate stamps
            out.append(obs.update(0.02 * k - 0.01, yk[:4], fck, yk[4], yk[5]))
            out.append(obs.update(0.02 * k, yk[:4], fck, yk[4], yk[5]))
    return out, log


def _finite(r: mc.DiagnosisResult) -> bool:
    vals = [r.mu_b, r.mu_b_std, r.speed, r.grade, r.t]
    arrays = [r.forces, r.force_std, r.target_forces, r.residual_forces, r.residuals, r.creep]
    return all(math.isfinite(v) for v in vals) and all(np.isfinite(a).all() for a in arrays)


def test_normal_run_ok_and_mu_b_converges() -> None:
    """Healthy car on a 2 % down-gradient: mu_b converges, forces tracked, level OK."""
    out, log = _run(mc.MetroScenario(0, 0.3, mu_b=0.33, grade=-0.02, mass_scale=1.1))
    last = out[-1]
    assert last.level == dg.LEVEL_OK
    assert not last.pad_flaw and not last.wheel_flaw.any()
    assert last.mu_b == pytest.approx(0.33, abs=0.015)
    assert last.grade == pytest.approx(-0.02, abs=0.004)
    err = np.array([r.forces for r in out[100:]]) - log.force[0, 100:]
    assert np.sqrt((err ** 2).mean()) < 600.0                  # forces ~ -9 kN
    assert max(r.level for r in out) == dg.LEVEL_OK


def test_pad_fault_detected() -> None:
    """mu_b = 0.1 on every axle: ERROR with the pad flaw soon after braking starts."""
    out, _ = _run(mc.MetroScenario(0, 0.3, "pad"))
    last = out[-1]
    assert last.level == dg.LEVEL_ERROR and last.pad_flaw
    assert last.mu_b == pytest.approx(0.1, abs=0.01)
    t_err = next(r.t for r in out if r.level == dg.LEVEL_ERROR)
    assert t_err < mc.METRO_BRAKE_ONSET_S + 1.5
    assert not last.wheel_flaw.any()


def test_wheel_fault_flags_axle_2_only() -> None:
    """Defective wheelset on axle 2 (wet rail): force-residual flaw on axle 2 only."""
    out, _ = _run(mc.MetroScenario(0, 0.15, "wheel"), seed=1)
    last = out[-1]
    assert last.level == dg.LEVEL_ERROR
    assert last.wheel_flaw.tolist() == [False, True, False, False]
    assert not last.pad_flaw


def test_fault_injected_in_service_is_detected() -> None:
    """Pads degrade at t = 3 s during braking: flagged within 2 s, not before."""
    out, _ = _run(mc.MetroScenario(1, 0.3, "pad", fault_time=3.0), t_end=5.5)
    t_err = [r.t for r in out if r.level == dg.LEVEL_ERROR]
    assert t_err and 3.0 < t_err[0] < 5.0


def test_bad_input_never_nan_and_still_works() -> None:
    """NaN/inf/masked channels, dropouts and stale stamps: predict-only, never NaN."""
    out, _ = _run(mc.MetroScenario(0, 0.3, "pad"), corrupt=True)
    assert all(_finite(r) for r in out)
    reasons = {r.skipped_reason for r in out}
    assert "out-of-order time stamp" in reasons
    assert "no valid measurement (predict only)" in reasons
    assert "partial measurement" in reasons or "clamp force invalid (held)" in reasons
    assert not all(r.measurement_used for r in out)
    assert out[-1].pad_flaw and out[-1].mu_b == pytest.approx(0.1, abs=0.02)


def test_garbage_before_init_and_long_gap() -> None:
    """No valid speed yet -> WARN placeholder; a long gap re-initialises the filter."""
    obs = mc.MetroBrakeObserver(P, 0.02)
    r0 = obs.update(0.0, [np.nan] * 4, [0.0] * 4, np.nan, np.nan)
    assert r0.level == dg.LEVEL_WARN and _finite(r0) and not r0.measurement_used
    r1 = obs.update(0.02, [20 / P.r_w] * 4, [0.0] * 4, 0.0, 20.0)
    assert _finite(r1) and r1.speed == pytest.approx(20.0, abs=0.1)
    r2 = obs.update(float("nan"), [20 / P.r_w] * 4, [0.0] * 4, 0.0, 20.0)
    assert r2.skipped_reason == "non-finite time" and _finite(r2)
    r3 = obs.update(100.0, [10 / P.r_w] * 4, [0.0] * 4, 0.0, 10.0)     # 100 s gap
    assert r3.speed == pytest.approx(10.0, abs=0.1)
    assert obs.counters.resets == 2
    r4 = obs.update(100.02, [1.0, 2.0], [0.0] * 4, 0.0, 10.0)        # malformed
    assert r4.skipped_reason == "malformed sample" and _finite(r4)


def test_online_observer_equals_batch() -> None:
    """MetroBrakeObserver and the batched bench path give the same estimates."""
    scen = mc.MetroScenario(1, 0.3, mu_b=0.36)
    log = mc.simulate_metro(P, [scen], t_end=3.0)
    meas = mc.measure_metro(log, mc.MetroSensorNoise(), np.random.default_rng(4))
    batch = mc.run_metro_batch(P, meas, log.mass, np.array([0.3]), v0=0.0)
    obs = mc.MetroBrakeObserver(P, 0.02, mu_rail=0.3, mass=float(log.mass[0]))
    y, fc = meas["y"][0], meas["fc"][0]
    for k in range(y.shape[0]):
        r = obs.update(0.02 * k, y[k, :4], fc[k], y[k, 4], y[k, 5])
    assert obs.ukf is not None
    # equal up to the round-off of the online time differences t_k - t_k-1
    assert np.allclose(obs.ukf.x, batch["x"][0, -1], rtol=1e-8, atol=1e-6)
    assert np.allclose(r.target_forces, batch["target"][0, -1], rtol=1e-6, atol=1e-3)


def test_custom_adhesion_curve_as_target() -> None:
    """A plant-supplied curve mu(|s|) is used with the creep's sign as the target."""
    def curve(s: np.ndarray) -> np.ndarray:
        return 0.32 * (1.0 - np.exp(-150.0 * s)) - 0.08 * s     # Burckhardt, dry rail

    obs = mc.MetroBrakeObserver(P, 0.02, mu_rail=0.31, adhesion_fn=curve)
    v = 20.0
    w = np.full(4, v * (1 - 0.004) / P.r_w)                     # 0.4 % braking creep
    r = obs.update(0.0, w, [0.0] * 4, 0.0, v)
    s = (P.r_w * obs.ukf.x[1:5] - obs.ukf.x[0]) / obs.ukf.x[0] if obs.ukf else None
    assert s is not None and np.all(s < 0)
    expect = -P.mass * mc.G / 4 * curve(np.abs(s))
    assert np.allclose(r.target_forces, expect)
