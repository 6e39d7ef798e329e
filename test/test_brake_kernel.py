"""The brake diagnosis's fast paths equal the reference paths.

* :mod:`metro_atc.core.brake.metro_kernel` (compiled UKF step) against the numpy UKF of
  :mod:`metro_atc.core.brake.ukf`: single steps on random states and covariances (full and
  partial measurements, inputs of every sign), the fallback to the numpy path on a
  covariance that is not positive definite, and whole sample streams through
  :class:`~metro_atc.core.brake.train_watch.TrainBrakeWatch` (what the node runs): the
  closed-loop stream of ``mini_pad_fault`` (a pad fault announced) and single-car runs
  of the paper bench with a wheel fault and corrupted samples.  Every returned kind, level
  and message is the same; every estimate agrees to round-off (the kernel sums in another
  order than BLAS).
* Journal entries built directly equal their JSON round trip (what a restarted node reads).
"""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np
import pytest

from metro_atc.core.brake import metro_car as mc
from metro_atc.core.brake import line_monitor as lm
from metro_atc.core.brake.metro_kernel import MetroUKF
from metro_atc.core.brake.train_watch import TrainBrakeWatch, observer_setup
from metro_atc.core.closed_loop import run_closed_loop
from metro_atc.core.line.scenario import load_scenario

P = mc.MetroCarParams()
REL = 1e-9
"""Largest difference between the paths, relative to the quantity's scale over the stream."""


def _random_spd(rng: np.random.Generator, n: int) -> np.ndarray:
    a = rng.standard_normal((n, n)) * rng.uniform(0.01, 100.0, n)
    return a @ a.T + np.diag(rng.uniform(1e-4, 1.0, n))


def _pair(rng: np.random.Generator) -> tuple[Any, Any]:
    ref = mc.make_metro_ukf(P, 0.05, 15.0)
    ker = mc.make_metro_ukf_compiled(P, 0.05, 15.0)
    assert isinstance(ker, MetroUKF) and not isinstance(ref, MetroUKF)
    x = ref.x + rng.standard_normal(mc.M_NX) * 0.1
    x[mc.M_IF] = rng.uniform(-2e4, 2e4, 4)
    p = _random_spd(rng, mc.M_NX)
    for f in (ref, ker):
        f.x, f.p = x.copy(), p.copy()
    return ref, ker


def _close(a: np.ndarray, b: np.ndarray) -> bool:
    scale = max(float(np.max(np.abs(a))), 1e-300)
    return float(np.max(np.abs(a - b))) <= REL * scale


def test_kernel_steps_equal_numpy_steps() -> None:
    """Predict (nominal and jittered steps, capped variances) and updates (all / some rows)."""
    rng = np.random.default_rng(3)
    for trial in range(40):
        ref, ker = _pair(rng)
        u = np.r_[rng.uniform(0.0, 2e4, 4), rng.uniform(-3e3, 3e3, 4), 35_000.0]
        dt = (0.05, 0.05 + 1e-12, 0.1, 0.0371)[trial % 4]
        if trial % 5 == 0:
            for f in (ref, ker):
                f.p = f.p * 1e6  # above the variance caps: scaled down (P <- D P D)
        ref.predict(u, dt)
        ker.predict(u, dt)
        assert _close(ref.x, ker.x) and _close(ref.p, ker.p), trial
        z = np.r_[ref.x[mc.M_IW] + rng.standard_normal(4) * 0.1, -0.4, ref.x[mc.M_IV]]
        rows = None if trial % 3 else np.sort(rng.choice(6, size=int(rng.integers(1, 6)),
                                                         replace=False))
        zz = z if rows is None else z[rows]
        assert ref.update(zz, u, rows) and ker.update(zz, u, rows)
        assert _close(ref.x, ker.x) and _close(ref.p, ker.p), trial
    assert ker.kernel_steps > 0


def test_kernel_hands_indefinite_covariance_to_numpy_path() -> None:
    """P not positive definite: the kernel declines and the numpy path's fallbacks run."""
    rng = np.random.default_rng(5)
    ref, ker = _pair(rng)
    bad = ref.p.copy()
    bad[3, 3] = -1.0
    for f in (ref, ker):
        f.p = bad.copy()
    u = np.r_[np.full(4, 5e3), np.zeros(4), 35_000.0]
    ref.predict(u, 0.05)
    ker.predict(u, 0.05)
    assert ker.kernel_steps == 0
    assert np.array_equal(ref.x, ker.x) and np.array_equal(ref.p, ker.p)


@pytest.fixture(scope="module")
def pad_fault_stream() -> list[tuple[str, dict[str, Any]]]:
    """The samples the brake node gets on a ROS-free closed-loop run of mini_pad_fault."""
    rec: list[tuple[str, dict[str, Any]]] = []
    orig = lm.LineBrakeMonitor._feed

    def feed(self: lm.LineBrakeMonitor, i: int, t: float, b: Any, a: int, c: int) -> None:
        rec.append((self.ids[i], {
            "t_s": t, "omega": np.array(b.omega[a, c], dtype=float),
            "clamp": np.array(b.clamp[a, c], dtype=float), "accel": float(b.accel[a, c]),
            "ref_speed": float(b.vref[a, c]), "car_mass": float(b.car_mass[c])}))
        orig(self, i, t, b, a, c)

    mp = pytest.MonkeyPatch()
    mp.setattr(lm.LineBrakeMonitor, "_feed", feed)
    try:
        res = run_closed_loop(load_scenario("mini_pad_fault"), brake=True)
    finally:
        mp.undo()
    assert res.brake["brake_faults_detected"] == 1  # the stream has a fault announced
    return rec


def _numpy_filter(monkeypatch: pytest.MonkeyPatch, numpy_path: bool) -> None:
    """The observer's filter: the compiled one, or (reference) the numpy UKF alone.

    The numpy UKF is the path the kernels hand declined steps to, so the two must agree.
    """
    if numpy_path:
        monkeypatch.setattr(mc, "make_metro_ukf_compiled", mc.make_metro_ukf)
    else:
        monkeypatch.undo()


def _watch_outputs(stream: list[tuple[str, dict[str, Any]]], compiled: bool,
                   monkeypatch: pytest.MonkeyPatch) -> tuple[list[Any], int]:
    _numpy_filter(monkeypatch, not compiled)
    setup = observer_setup(load_scenario("mini_pad_fault"))
    ws: dict[str, TrainBrakeWatch] = {}
    out = []
    for train, s in stream:
        w = ws.get(train) or ws.setdefault(train, TrainBrakeWatch(train, setup))
        kind = w.feed(s)
        assert w.obs.ukf is None or isinstance(w.obs.ukf, MetroUKF) == compiled
        r = w.result
        out.append((kind, w.level_message(), r.level, np.r_[
            r.mu_b, r.mu_b_std, r.forces, r.residuals, r.residual_forces, r.speed, r.grade]))
    steps = sum(getattr(w.obs.ukf, "kernel_steps", 0) for w in ws.values())
    return out, steps


def test_kernel_stream_equals_numpy_stream(pad_fault_stream: list[Any],
                                           monkeypatch: pytest.MonkeyPatch) -> None:
    """mini_pad_fault's samples: same kinds, levels and messages; estimates to round-off."""
    ref, _ = _watch_outputs(pad_fault_stream, False, monkeypatch)
    ker, steps = _watch_outputs(pad_fault_stream, True, monkeypatch)
    assert steps > 0
    assert [r[:3] for r in ref] == [k[:3] for k in ker]
    assert max(r[2] for r in ref) == 2  # the ERROR (pad flaw) is among them
    a = np.array([r[3] for r in ref])
    b = np.array([k[3] for k in ker])
    scale = np.maximum(np.max(np.abs(a), axis=0), 1e-12)
    assert (np.max(np.abs(a - b), axis=0) <= REL * scale).all()


@pytest.mark.parametrize("fault", ["wheel", "pad", "none"])
def test_kernel_observer_equals_numpy_on_corrupted_runs(fault: str,
                                                        monkeypatch: pytest.MonkeyPatch
                                                        ) -> None:
    """Single-car runs with NaN channels, a held clamp force and a gap: same outputs."""
    log = mc.simulate_metro(P, [mc.MetroScenario(1, 0.15 if fault == "none" else 0.3,
                                                 fault, fault_time=1.0)], t_end=4.0)
    meas = mc.measure_metro(log, mc.MetroSensorNoise(), np.random.default_rng(11))
    y, fc = meas["y"][0], meas["fc"][0]
    res = {}
    for compiled in (False, True):
        _numpy_filter(monkeypatch, not compiled)
        obs = mc.MetroBrakeObserver(P, 0.02, mu_rail=0.3, mass=float(log.mass[0]))
        out = []
        for k in range(y.shape[0]):
            if 100 <= k < 130:
                continue  # a 0.6 s gap: the filter restarts
            yk, fck = y[k].copy(), fc[k].copy()
            if k % 7 == 3:
                yk[[1, 4]] = np.nan
            if k % 11 == 5:
                fck[2] = np.inf
            r = obs.update(0.02 * k, yk[:4], fck, yk[4], yk[5])
            out.append((r.level, r.message, r.skipped_reason,
                        np.r_[r.mu_b, r.mu_b_std, r.forces, r.residuals, r.speed]))
        res[compiled] = out
    assert [o[:3] for o in res[False]] == [o[:3] for o in res[True]]
    a = np.array([o[3] for o in res[False]])
    b = np.array([o[3] for o in res[True]])
    scale = np.maximum(np.max(np.abs(a), axis=0), 1e-12)
    assert (np.max(np.abs(a - b), axis=0) <= REL * scale).all()


def test_journal_entries_equal_their_json_round_trip(
        pad_fault_stream: list[Any]) -> None:
    """What the node journals equals what a restarted node reads back (NaN included)."""
    from metro_atc.nodes.brake_diagnostic import _sample_entry

    samples = [s for _, s in pad_fault_stream[:300]]
    samples[5] = dict(samples[5], omega=np.array([math.nan, 1.0, -0.0, 2.5]),
                      car_mass=math.nan)
    for s in samples:
        e = _sample_entry(s)
        back = json.loads(json.dumps(e))
        assert json.dumps(e, sort_keys=True) == json.dumps(back, sort_keys=True)
        assert repr(e) == repr(back)


def test_precompile_covers_every_call_of_the_observer(
        pad_fault_stream: list[Any], monkeypatch: pytest.MonkeyPatch) -> None:
    """``precompile_metro_kernels`` (run by scripts/install.sh) compiles the kernels for the
    argument types a node passes: with compiling then disabled, the mini_pad_fault stream
    and a corrupted single-car run (partial updates, restarts) still go through the kernels.
    """
    from metro_atc.core.brake.metro_kernel import predict_kernel, update_kernel

    assert mc.precompile_metro_kernels() == 3
    kernels = (predict_kernel, update_kernel)
    for k in kernels:
        assert len(k.signatures) == 1, k.signatures  # one type signature: one cache entry
        k.disable_compile()
    try:
        _, steps = _watch_outputs(pad_fault_stream[:4000], True, monkeypatch)
        assert steps > 0
        test_kernel_observer_equals_numpy_on_corrupted_runs("pad", monkeypatch)
    finally:
        for k in kernels:
            k.disable_compile(False)
    assert [len(k.signatures) for k in kernels] == [1, 1]
