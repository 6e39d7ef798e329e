"""Residual generator and decision logic of the active safety diagnosis.

Seed 000, second paper, Fig. 3: "The residual generator compares the estimated tire
forces with the target values to find faults.  The decision logic checks the flaws
against the safety requirements."  The paper states one requirement explicitly,
``mu_b >= 0.2`` (Case 2), and announces a flaw in Case 3 because the estimated forces
"significantly deviate from the corresponding target values".  We make "significantly"
precise:

* pad flaw: ``mu_b_hat < mu_b_min`` (0.2) continuously for ``persistence_s`` while the
  estimate is trustworthy (posterior std below ``mu_b_std_max``, i.e. mu_b observable:
  the brakes are applied);
* force flaw on channel c: ``|r_c| = |F_hat_c - F_target_c| > theta_c`` continuously for
  ``persistence_s``;
* both are ignored before ``gate_s`` (observer start-up transient).

Thresholds ``theta_c`` come from the statistics of normal (fault-free) runs: for every
normal run, the largest residual level that was sustained for a whole persistence
window (the sliding-window minimum of ``|r_c|``) is computed; ``theta_c`` is the
maximum of that statistic over the calibration runs times a safety ``margin``, never
below ``floor``.  Calibration and evaluation use disjoint noise seeds.

Functions are vectorised over leading batch axes; time is the last-but-one axis of
residual arrays (B, n_t, n_c).  Units: forces [N], time [s].
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Optional, Sequence

import numpy as np

FloatArray = np.ndarray

LEVEL_OK, LEVEL_WARN, LEVEL_ERROR = 0, 1, 2
"""Diagnosis levels; numerically equal to diagnostic_msgs/DiagnosticStatus OK/WARN/ERROR."""


@dataclass(frozen=True)
class DecisionConfig:
    """Decision-logic parameters.

    Attributes:
        thresholds: residual thresholds per channel [N].
        mu_b_min: safety requirement on the disk-pad friction [-] (paper: 0.2).
        mu_b_warn: WARN level for mu_b_hat [-] (our choice).
        mu_b_std_max: mu_b_hat only judged when its std is below this [-].
        persistence_s: time a violation must last to become a flaw [s].
        gate_s: decisions ignored before this time [s].
        filter_tau_s: time constant of the first-order low-pass applied to the force
            residuals before thresholding [s] (smooths ABS / WSP cycling).
        mu_b_sigmas: a pad violation (and a WARN) needs ``mu_b_hat + mu_b_sigmas * std``
            below the limit: a one-sided test that the requirement is violated, not only
            the estimate (0: the estimate alone, the paper's rule).
    """

    thresholds: FloatArray
    mu_b_min: float = 0.2
    mu_b_warn: float = 0.25
    mu_b_std_max: float = 0.05
    persistence_s: float = 0.3
    gate_s: float = 0.3
    filter_tau_s: float = 0.1
    mu_b_sigmas: float = 0.0


def residuals(estimate: FloatArray, target: FloatArray) -> FloatArray:
    """Residual generator: estimated minus target forces [N] (same shapes)."""
    return np.asarray(estimate) - np.asarray(target)


def lowpass(res: FloatArray, dt: float, tau: float) -> FloatArray:
    """First-order low-pass along axis -2 (time), zero initial state.

    ``y[k] = y[k-1] + a (x[k] - y[k-1])`` with ``a = dt / (tau + dt)``, ``y[-1] = 0``;
    the same recursion as :class:`OnlineDecision`.
    """
    if tau <= 0.0:
        return np.asarray(res, dtype=float)
    # imported here: scipy.signal pulls in scipy.stats (~1 s of CPU), and the online
    # path (OnlineDecision, what the brake node runs) never calls this batch filter
    from scipy.signal import lfilter

    a = dt / (tau + dt)
    return np.asarray(lfilter([a], [1.0, -(1.0 - a)], res, axis=-2))


def window_min(x: FloatArray, n_win: int) -> FloatArray:
    """Trailing sliding-window minimum along axis -2 (time), window ``n_win`` samples.

    Element k is ``min(x[k - n_win + 1 .. k])``; for k < n_win - 1 it is ``-inf``
    (a violation cannot have lasted a full window yet).

    Args:
        x: array (..., n_t, n_c).
        n_win: window length in samples (>= 1).
    """
    n_win = max(int(n_win), 1)
    nt = x.shape[-2]
    out = np.full(x.shape, -np.inf)
    if n_win > nt:
        return out
    v = np.lib.stride_tricks.sliding_window_view(x, n_win, axis=-2)
    out[..., n_win - 1:, :] = v.min(axis=-1)
    return out


def persistence_samples(persistence_s: float, dt: float) -> int:
    """Number of consecutive samples making up ``persistence_s`` at period ``dt``."""
    return max(int(round(persistence_s / dt)) + 1, 1)


def sustained_level(res: FloatArray, t: FloatArray, persistence_s: float, gate_s: float,
                    filter_tau_s: float, valid: Optional[FloatArray] = None) -> FloatArray:
    """Largest filtered residual level held for a whole persistence window, per run.

    Args:
        res: raw residuals (B, n_t, n_c) [N].
        t: uniform sample times (n_t,) [s].
        persistence_s, gate_s, filter_tau_s: as in :class:`DecisionConfig`.
        valid: optional mask (B, n_t, n_c) of samples where the residual is meaningful.

    Returns:
        (B, n_c) [N].
    """
    dt = float(t[1] - t[0])
    a = np.abs(lowpass(res, dt, filter_tau_s))
    ok = (t >= gate_s)[:, None]
    if valid is not None:
        ok = ok & valid
    a = np.where(ok, a, 0.0)
    return window_min(a, persistence_samples(persistence_s, dt)).max(axis=-2)


def calibrate_thresholds(res: FloatArray, t: FloatArray, persistence_s: float,
                         gate_s: float, filter_tau_s: float, margin: float = 1.5,
                         floor: float | FloatArray = 50.0,
                         valid: Optional[FloatArray] = None) -> FloatArray:
    """Thresholds from normal runs' residual statistics (see module docstring).

    Args:
        res: raw residuals of normal runs (B, n_t, n_c) [N].
        t: sample times (n_t,) [s], uniform.
        persistence_s, gate_s, filter_tau_s: as in :class:`DecisionConfig`.
        margin: multiplicative safety margin (>= 1).
        floor: lower bound per channel [N].
        valid: optional validity mask (B, n_t, n_c).

    Returns:
        theta (n_c,) [N].
    """
    lv = sustained_level(res, t, persistence_s, gate_s, filter_tau_s, valid)
    return np.maximum(margin * lv.max(axis=0), floor)


@dataclass
class Decision:
    """Batch decision result.

    Attributes:
        flaw: flaw announced (B,).
        detect_time: first time the flaw was announced [s] (NaN if none) (B,).
        pad_flaw: mu_b requirement violated (B,).
        force_flaw: per-channel force flaw (B, n_c).
        pad_time, force_time: first announcement times [s] (NaN if none).
    """

    flaw: FloatArray
    detect_time: FloatArray
    pad_flaw: FloatArray
    force_flaw: FloatArray
    pad_time: FloatArray
    force_time: FloatArray


def _first_time(flags: FloatArray, t: FloatArray) -> FloatArray:
    """First time along the last axis where ``flags`` is True (NaN if never)."""
    anyf = flags.any(axis=-1)
    idx = np.argmax(flags, axis=-1)
    return np.where(anyf, t[idx], np.nan)


def decide(mu_b: FloatArray, mu_b_std: FloatArray, res: FloatArray, t: FloatArray,
           cfg: DecisionConfig, valid: Optional[FloatArray] = None) -> Decision:
    """Decision logic over whole runs (vectorised; same rules as :class:`OnlineDecision`).

    Args:
        mu_b: estimated disk-pad friction (B, n_t).
        mu_b_std: its posterior std (B, n_t).
        res: raw force residuals (B, n_t, n_c) [N] (low-passed here).
        t: sample times (n_t,) [s], uniform, starting at the first sample.
        cfg: decision parameters.
        valid: optional mask (B, n_t, n_c) of meaningful residual samples.
    """
    dt = float(t[1] - t[0])
    n_win = persistence_samples(cfg.persistence_s, dt)
    gate = (t - t[0]) >= cfg.gate_s - 1e-9
    mu_up = mu_b + cfg.mu_b_sigmas * mu_b_std
    pad_viol = ((mu_up < cfg.mu_b_min) & (mu_b_std < cfg.mu_b_std_max) & gate).astype(float)
    pad_ok = window_min(pad_viol[..., None], n_win)[..., 0] > 0.5
    rf = lowpass(res, dt, cfg.filter_tau_s)
    ok = gate[:, None] if valid is None else (gate[:, None] & valid)
    exceed = ((np.abs(rf) > cfg.thresholds) & ok).astype(float)
    force_ok = window_min(exceed, n_win) > 0.5
    pad_time = _first_time(pad_ok, t)
    force_time = _first_time(np.swapaxes(force_ok, -1, -2), t)
    detect = np.fmin(pad_time, np.nanmin(np.where(np.isnan(force_time), np.inf, force_time),
                                         axis=-1))
    detect = np.where(np.isinf(detect), np.nan, detect)
    return Decision(flaw=~np.isnan(detect), detect_time=detect, pad_flaw=~np.isnan(pad_time),
                    force_flaw=~np.isnan(force_time), pad_time=pad_time, force_time=force_time)


@dataclass
class OnlineDecision:
    """Streaming decision logic for one vehicle (used by the ROS node).

    Each channel keeps the start time of its current uninterrupted violation; a flaw
    is announced when a violation has lasted ``persistence_s``.  Flaws latch (a brake
    defect does not heal by itself) until :meth:`reset`.

    Args:
        cfg: decision parameters.
        latch: keep flaws once announced.
        dt_first: sample period assumed for the residual filter at the first sample [s]
            (use the nominal period to match :func:`decide` exactly).
    """

    cfg: DecisionConfig
    latch: bool = True
    dt_first: float = 0.01
    t0: Optional[float] = None
    t_prev: Optional[float] = None
    res_f: FloatArray = field(default_factory=lambda: np.zeros(0))
    _pad_since: Optional[float] = None
    _force_since: FloatArray = field(default_factory=lambda: np.zeros(0))
    pad_flaw: bool = False
    force_flaw: FloatArray = field(default_factory=lambda: np.zeros(0, dtype=bool))
    detect_time: Optional[float] = None

    def reset(self) -> None:
        """Clear latched flaws, violation timers and the residual filter."""
        self.restart()
        n = np.size(self.cfg.thresholds)
        self.pad_flaw = False
        self.force_flaw = np.zeros(n, dtype=bool)
        self.detect_time = None

    def restart(self) -> None:
        """Restart the start-up gate, timers and filter; latched flaws are kept.

        Called when the observer is re-initialised (e.g. after a long data gap).
        """
        n = np.size(self.cfg.thresholds)
        self.t0 = None
        self.t_prev = None
        self.res_f = np.zeros(n)
        self._pad_since = None
        self._force_since = np.full(n, np.inf)

    def __post_init__(self) -> None:
        """Initialise the timers."""
        self.reset()

    def update(self, t: float, mu_b: float, mu_b_std: float, res: FloatArray | Sequence[float],
               res_valid: FloatArray | Sequence[bool] | None = None) -> int:
        """Process one sample and return the level (OK / WARN / ERROR).

        Args:
            t: time [s]; mu_b, mu_b_std: estimate and its std [-].
            res: raw force residuals (n_c,) [N] (low-passed here, see ``res_f``).
            res_valid: channels whose residual is meaningful now (default all); an
                invalid channel interrupts its violation timer.

        Returns:
            LEVEL_ERROR if a flaw is (or was, when latching) announced, LEVEL_WARN if a
            violation is in progress or mu_b_hat is below ``mu_b_warn``, else LEVEL_OK.
        """
        cfg = self.cfg
        if self.t0 is None:
            self.t0 = t
        dt = 0.0 if self.t_prev is None else t - self.t_prev
        self.t_prev = t
        gated = (t - self.t0) >= cfg.gate_s - 1e-9
        # per channel as plain floats (a handful of channels: numpy's per-call cost was
        # most of this method's time); the same arithmetic element by element
        raw = [x if math.isfinite(x) else 0.0 for x in np.asarray(res, dtype=float).tolist()]
        if cfg.filter_tau_s <= 0.0:
            rf = raw
        else:
            h = dt if dt > 0 else self.dt_first
            a = h / (cfg.filter_tau_s + h)
            rf = [f + a * (x - f) for f, x in zip(self.res_f.tolist(), raw)]
        self.res_f = np.array(rf)
        n = len(rf)
        valid = ([True] * n if res_valid is None
                 else np.asarray(res_valid, dtype=bool).reshape(n).tolist())
        eps = 1e-9
        mu_up = mu_b + cfg.mu_b_sigmas * mu_b_std
        pad_v = gated and (mu_up < cfg.mu_b_min) and (mu_b_std < cfg.mu_b_std_max)
        if pad_v:
            if self._pad_since is None:
                self._pad_since = t
            if t - self._pad_since >= cfg.persistence_s - eps:
                if not self.pad_flaw and self.detect_time is None:
                    self.detect_time = t
                self.pad_flaw = True
        else:
            self._pad_since = None
            if not self.latch:
                self.pad_flaw = False
        thr = np.asarray(cfg.thresholds, dtype=float).reshape(-1).tolist()
        if len(thr) == 1:  # one threshold for every channel (broadcast)
            thr = thr * n
        since = self._force_since.tolist()
        exc = [gated and valid[j] and abs(rf[j]) > thr[j] for j in range(n)]
        since = [min(since[j], t) if exc[j] else math.inf for j in range(n)]
        self._force_since = np.array(since)
        lasting = [t - s >= cfg.persistence_s - eps for s in since]
        if any(lasting) and self.detect_time is None:
            self.detect_time = t
        lasting_a = np.array(lasting, dtype=bool)
        self.force_flaw = (self.force_flaw | lasting_a) if self.latch else lasting_a
        if self.pad_flaw or any(self.force_flaw.tolist()):
            return LEVEL_ERROR
        if pad_v or any(exc) or (gated and mu_up < cfg.mu_b_warn
                                 and mu_b_std < cfg.mu_b_std_max):
            return LEVEL_WARN
        return LEVEL_OK
