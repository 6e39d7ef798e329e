"""Tests of the residual evaluation and decision logic (Lin 2010b, Fig. 3)."""
from __future__ import annotations

import numpy as np
import pytest

from metro_atc.core.brake import diagnosis as dg


def test_window_min_matches_naive() -> None:
    """Trailing sliding minimum equals a direct loop; -inf before a full window."""
    rng = np.random.default_rng(0)
    x = rng.standard_normal((2, 30, 3))
    n = 5
    wm = dg.window_min(x, n)
    for k in range(30):
        if k < n - 1:
            assert np.all(wm[:, k] == -np.inf)
        else:
            assert np.allclose(wm[:, k], x[:, k - n + 1:k + 1].min(axis=1))


def test_lowpass_matches_recursion() -> None:
    """Batch low-pass equals y_k = y_{k-1} + a (x_k - y_{k-1}), y_{-1} = 0."""
    rng = np.random.default_rng(1)
    x = rng.standard_normal((40, 2))
    dt, tau = 0.02, 0.1
    a = dt / (tau + dt)
    y = np.zeros(2)
    ref = []
    for k in range(40):
        y = y + a * (x[k] - y)
        ref.append(y.copy())
    assert np.allclose(dg.lowpass(x, dt, tau), np.array(ref))


def _cfg(thr: float, **kw: float) -> dg.DecisionConfig:
    base = {"persistence_s": 0.3, "gate_s": 0.2, "filter_tau_s": 0.0}
    base.update(kw)
    return dg.DecisionConfig(thresholds=np.array([thr, thr]), **base)


def test_persistence_time() -> None:
    """A violation of exactly the persistence time is a flaw, one sample less is not."""
    t = np.arange(0, 3.0, 0.01)
    dt = 0.01
    cfg = _cfg(100.0)
    n = dg.persistence_samples(cfg.persistence_s, dt)     # 31 samples = 0.3 s
    res = np.zeros((2, t.size, 2))
    res[0, 100:100 + n, 1] = 150.0                         # lasts 0.30 s
    res[1, 100:100 + n - 1, 1] = 150.0                     # lasts 0.29 s
    mu = np.full((2, t.size), 0.38)
    d = dg.decide(mu, np.full_like(mu, 0.01), res, t, cfg)
    assert d.flaw.tolist() == [True, False]
    assert d.detect_time[0] == pytest.approx(t[100 + n - 1])
    assert d.force_flaw[0].tolist() == [False, True]


def test_pad_requirement_needs_observability() -> None:
    """mu_b_hat < 0.2 is a flaw only while its std is small (mu_b observable)."""
    t = np.arange(0, 2.0, 0.01)
    mu = np.full((2, t.size), 0.1)
    sd = np.full((2, t.size), 0.01)
    sd[1] = 0.1                                            # never observable
    d = dg.decide(mu, sd, np.zeros((2, t.size, 2)), t, _cfg(100.0))
    assert d.pad_flaw.tolist() == [True, False]
    # gate 0.2 s + persistence 0.3 s
    assert d.pad_time[0] == pytest.approx(0.5)


def test_online_equals_batch() -> None:
    """The streaming logic (node) and the batch logic (bench) decide identically."""
    rng = np.random.default_rng(2)
    t = np.arange(0, 4.0, 0.02)
    nb = 12
    res = np.cumsum(rng.standard_normal((nb, t.size, 2)) * 15.0, axis=1)
    mu = 0.3 + np.cumsum(rng.standard_normal((nb, t.size)) * 0.01, axis=1)
    sd = np.abs(rng.standard_normal((nb, t.size))) * 0.05
    valid = rng.random((nb, t.size, 2)) > 0.05
    cfg = _cfg(120.0, filter_tau_s=0.1)
    d = dg.decide(mu, sd, res, t, cfg, valid)
    for b in range(nb):
        on = dg.OnlineDecision(cfg, dt_first=0.02)
        for k in range(t.size):
            on.update(float(t[k]), float(mu[b, k]), float(sd[b, k]), res[b, k], valid[b, k])
        assert on.pad_flaw == bool(d.pad_flaw[b])
        assert on.force_flaw.tolist() == d.force_flaw[b].tolist()
        if d.flaw[b]:
            assert on.detect_time == pytest.approx(d.detect_time[b])
        else:
            assert on.detect_time is None
    assert 0 < d.flaw.sum() < nb                           # the data exercise both outcomes


def test_online_levels_and_latch() -> None:
    """OK -> WARN while a violation builds up -> ERROR (latched) -> OK after reset."""
    cfg = _cfg(100.0)
    on = dg.OnlineDecision(cfg, dt_first=0.1)
    levels = []
    for k in range(20):
        r = np.array([0.0, 200.0 if 5 <= k < 10 else 0.0])
        levels.append(on.update(0.1 * k, 0.38, 0.01, r))
    assert levels[:5] == [dg.LEVEL_OK] * 5
    assert levels[5:8] == [dg.LEVEL_WARN] * 3             # 0.0, 0.1, 0.2 s into violation
    assert levels[8:] == [dg.LEVEL_ERROR] * 12            # latched
    on.reset()
    assert on.update(2.5, 0.38, 0.01, np.zeros(2)) == dg.LEVEL_OK


def test_calibrated_threshold_is_margin_times_sustained_level() -> None:
    """A residual holding c for longer than the persistence time gives margin * c."""
    t = np.arange(0, 3.0, 0.01)
    res = np.zeros((3, t.size, 1))
    res[0, 50:150, 0] = 80.0                 # sustained 1 s at 80
    res[1, 50:55, 0] = 500.0                 # short spike: not sustained
    res[2, 200:260, 0] = -60.0
    thr = dg.calibrate_thresholds(res, t, persistence_s=0.3, gate_s=0.2, filter_tau_s=0.0,
                                  margin=1.5, floor=10.0)
    assert thr[0] == pytest.approx(120.0)
    thr_f = dg.calibrate_thresholds(res, t, persistence_s=0.3, gate_s=0.2, filter_tau_s=0.05,
                                    margin=1.5, floor=10.0)
    assert 115.0 < thr_f[0] < 120.0          # filtered level approaches 80 from below
    # the thresholds separate the calibration runs from a sustained 130 N violation
    cfg = dg.DecisionConfig(thresholds=thr, persistence_s=0.3, gate_s=0.2, filter_tau_s=0.0)
    bad = np.zeros((1, t.size, 1))
    bad[0, 100:200, 0] = 130.0
    mu = np.full((1, t.size), 0.38)
    assert not dg.decide(np.repeat(mu, 3, 0), np.full((3, t.size), 0.01), res, t,
                         cfg).flaw.any()
    assert dg.decide(mu, np.full_like(mu, 0.01), bad, t, cfg).flaw[0]
