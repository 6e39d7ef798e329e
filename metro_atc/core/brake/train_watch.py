"""ROS-free brake watch of one train: the Lin 2010b observer inside a consist.

:class:`TrainBrakeWatch` is what the ``brake_diagnostic`` node runs per train (and what the
ROS-free closed loop runs, :mod:`metro_atc.core.brake.line_monitor`): it takes one validated
brake sensor sample (the dict of :func:`metro_atc.nodes.conversions.sensor_from_msg`), adapts
it to the single-car observer :class:`~metro_atc.core.brake.metro_car.MetroBrakeObserver`
and keeps the counters the node reports.

**Consist adaptation (the instrumented car is a trailer inside a 6-car train).**  The
observer's car-body equation ``M dv/dt = sum_j F_j - ...`` (Lin 2010b, eq. 1) holds for a
single vehicle; for a car in a consist the coupler forces are missing from it, and the
accelerometer measures the *train's* acceleration (most of the braking is electric, on
the motor cars).  Fed directly, the observer attributes the train's deceleration to the
trailer's own brakes and flags every train (mu_b drifts to 0.2 within seconds).  The node
therefore feeds the observer:

* as ``a_x`` a virtual car accelerometer ``sum_j F_target,j / M - phi_r(v)``: the
  specific force of the car's own axles from the adhesion model (the line plant's curve
  for the scenario's rail condition) at the creep estimated one sample earlier, i.e. the
  wheel-rail relation the issue asks for in place of tyre forces, used as a
  pseudo-measurement (std ``PSEUDO_ACCEL_STD``), only above ``V_PSEUDO_MPS`` where the creep
  is resolvable with the sensor noise; the real accelerometer is only validated;
* a fast random walk on the observer's gradient state, which then absorbs the coupler
  force per unit mass (``Q_COUPLER`` per step);
* the load-weigh signal ``car_mass_kg`` of each sample as the car mass;
* nothing below ``V_PAUSE_MPS`` (standstill / creeping to a stop: the holding brake is
  static, mu_b is not observable, the creep is not resolvable), nothing while two or more
  axles slide (wheel-slide protection on a slippery rail);
* a restart of the filter from the measurements after a gap of more than ``MAX_GAP_S``
  (pauses, the simulator's 1 Hz heartbeat between brake applications, lost samples):
  mu_b_hat then starts again from the nominal prior; latched flaws are kept and the last
  judged estimate is reported as ``mu_b_last_judged``;
* force-state process noise ``Q_FORCE`` large enough for the axle forces to follow the
  step-wise clamp-force changes of brake applications.

Decision: the core's logic with a pad flaw announced when
``mu_b_hat + MU_B_SIGMAS std < 0.2`` (WARN: ``< 0.25``) for ``PERSISTENCE_S`` (1 s), judged
only while the std is below ``MU_B_STD_JUDGE``, where the std is the filter's bounded below
by :meth:`TrainBrakeWatch.mu_b_std_bound` (the information the creep data carry about mu_b).
Before, mu_b_hat was judged alone once the filter's std fell below 0.012; on the generated
lines fault-free trains braking on 40 per mille descents (often in a TSR) then went OK ->
WARN (mu_b_hat 0.19-0.26, true 0.35, filter std 0.011-0.012): (a) the plant's axle force
used the demanded deceleration for the wheelset inertia term while the wheel speeds follow
the actual one (a bias of mu_b_hat of -0.04 to -0.07 at service-brake clamp forces of
3-8 kN on a descent; fixed in the plant, ``Brakes.follow``: the judged mu_b_hat of
gen_0005_inc's fault-free trains now has its median at 0.351, true 0.35), (b) the virtual
accelerometer feeds the filter's own posterior back as data, so its std is 3-4x too small
at service-brake clamp forces (judged mu_b_hat p1-p99 0.23-0.42 with std 0.011).  Force
residuals are judged above ``2 v_min = 8 m/s`` with a clamp force above 2 kN, and not
during the start-up gate after a gap in the data (``REGATE_GAP_S``).
A pad fault is detected during the first friction-brake application at speed after it
appears (gen_0000_inc, 3 trains, mu_b 0.1 from 60 s: 5.3 s into the first service brake
at speed; with the model-error term this watch carried for the plant's old wheelset-inertia
bias, the blended service brakes carried too little information for a 3-sigma verdict and
only the breakdown's emergency brake, 200 s later, gave one).

The consist adaptation lives here (not in the observer) because the core observer has no
coupler-force state and no adhesion pseudo-measurement.
"""

from __future__ import annotations

import dataclasses
import math
import time
from typing import Any, Optional

import numpy as np

from metro_atc.core import laws
from metro_atc.core.brake import metro_car as mc
from metro_atc.core.line.adhesion import CURVES, AdhesionCurve
from metro_atc.core.line.rolling_stock import train_params_for
from metro_atc.core.line.scenario import Scenario

N_AXLES = mc.N_AX
"""Axles of the instrumented car."""
V_PAUSE_MPS = 5.0
"""Below this reference speed the observer is paused [m/s]."""
V_PSEUDO_MPS = 5.0
"""The virtual car accelerometer is used above this estimated speed [m/s]."""
PSEUDO_ACCEL_STD = 0.1
"""Std of the virtual car accelerometer [m/s^2]."""
PSEUDO_MAX_AGE_S = 0.2
"""The virtual accelerometer uses a posterior at most this old (lost samples) [s]."""
PSEUDO_SPEED_GATE_MPS = 0.15
"""Largest |v_hat - v_ref| at which the virtual accelerometer is used [m/s]."""
MAX_GAP_S = 0.5
"""A gap between used samples longer than this re-initialises the filter [s].  The
simulator publishes at the full rate only while the car brakes and a 1 Hz heartbeat
otherwise; predicting across heartbeats (20 predict-only steps each, for minutes) lets the
unobserved force and gradient random walks run away, and mu_b is only observable during a
brake application anyway (it converges within a second of an emergency brake)."""
SLIDE_AXLES = 2
"""Samples with at least this many axles beyond the adhesion peak (wheel-slide protection
cycling on a slippery rail) are not used: the plant's WSP cycles are not resolved at the
sample rate.  A single sliding axle (a defective wheelset) is still observed."""
Q_COUPLER = 0.005
"""Random-walk std of the gradient state per sample [-] (absorbs coupler force / M g)."""
Q_FORCE = (1000.0, 2000.0, 2.0e4)
"""Process-noise std per sample of each axle force chain (F, dF/dt, d2F/dt2)."""
MU_B_STD_JUDGE = 0.05
"""mu_b_hat is judged against the requirement only below this std [-] (half the prior std:
the data, not the prior, carries the estimate); the std is the filter's, bounded below by
:meth:`TrainBrakeWatch.mu_b_std_bound`.  What decides is the one-sided test ``MU_B_SIGMAS``."""
MU_B_SIGMAS = 3.0
"""Pad flaw (WARN) only when ``mu_b_hat + 3 std`` is below 0.2 (0.25) for ``PERSISTENCE_S``:
the requirement is violated at the 0.13 % one-sided level, with the std bounded below by
:meth:`TrainBrakeWatch.mu_b_std_bound`."""
REGATE_GAP_S = 0.125
"""After a gap of more than this between used samples (two or more sample periods missing at
20 Hz) the decision's start-up gate (``gate_s``) applies again [s].  Between two brake
applications the simulator publishes only its 1 Hz heartbeat, so the filter predicts across
the gap with the old clamp force and its force states meet the re-applied brake stale
(measured on gen_0002_inc: normalised residuals of 0.33-0.43 on the first samples after a
0.3 s gap, above the 0.35 threshold, a WARN on a fault-free train); longer gaps
(``MAX_GAP_S``) restart the filter itself."""
PERSISTENCE_S = 1.0
"""A violation must last this long to become a flaw [s]."""
V_MIN_CREEP = 4.0
"""Creep-definition speed floor; residuals are judged above twice this [m/s]."""
BRAKED_CLAMP_N = 5000.0
"""Mean clamp force above which a sample counts as a friction-brake application [N]."""
LEVEL_NAMES = ("OK", "WARN", "ERROR")
RESYNC_SAMPLES = 10
"""Consecutive in-order samples behind the last accepted stamp after which the stream is
followed again (a sample from the future does not poison it; 0.5 s at 20 Hz)."""


@dataclasses.dataclass(frozen=True)
class ObserverSetup:
    """Everything needed to build one train's observer (from the scenario)."""

    params: mc.MetroCarParams
    dt: float
    curve: AdhesionCurve
    tuning: mc.MetroObserverTuning
    noise: mc.MetroSensorNoise
    decision: Any


def observer_setup(scn: Scenario) -> ObserverSetup:
    """Car data, sample period, adhesion curve and tuning for the scenario's trains.

    The sensor noise model is twice the scenario's sensor noise (margin for the plant's
    quasi-static axle model), with floors so that the covariance stays regular.
    """
    params = dataclasses.replace(mc.from_train_params(train_params_for(scn)),
                                 v_min=V_MIN_CREEP)
    curve = CURVES[scn.line.adhesion]
    sen = scn.sensors
    tuning = dataclasses.replace(mc.MetroObserverTuning(), q_grade=Q_COUPLER, q_f=Q_FORCE)
    noise = mc.MetroSensorNoise(omega=max(2.0 * sen.wheel_omega_noise_radps, 0.01),
                                ax=PSEUDO_ACCEL_STD,
                                v_ref=max(2.0 * sen.ref_speed_noise_mps, 0.01))
    decision = dataclasses.replace(mc.default_metro_decision(params),
                                   mu_b_std_max=MU_B_STD_JUDGE, persistence_s=PERSISTENCE_S,
                                   mu_b_sigmas=MU_B_SIGMAS)
    return ObserverSetup(params, 1.0 / sen.rate_hz, curve, tuning, noise, decision)


class TrainBrakeWatch:
    """ROS-free state of one train: observer, consist adaptation, counters.

    :meth:`feed` takes one validated sample (the dict of
    :func:`metro_atc.nodes.conversions.sensor_from_msg`) and returns what happened to it:
    ``"used"``, ``"degraded"`` (NaN channels left out), ``"paused"`` (slow), ``"sliding"``
    (two or more axles beyond the adhesion peak), ``"waiting"`` (no speed channel for longer
    than the observer's gap) or ``"out_of_order"``.
    """

    def __init__(self, train_id: str, setup: ObserverSetup) -> None:
        """Create the observer (prior: nominal mu_b, no data)."""
        self.train_id = train_id
        self.setup = setup
        p = setup.params
        self.obs = mc.MetroBrakeObserver(p, setup.dt, mu_rail=setup.curve.mu_peak,
                                         decision=setup.decision, tuning=setup.tuning,
                                         noise=setup.noise, adhesion_fn=setup.curve.mu,
                                         max_gap_s=MAX_GAP_S)
        z4 = np.zeros(N_AXLES)
        self.result = mc.DiagnosisResult(
            t=0.0, mu_b=p.mu_b, mu_b_std=setup.tuning.p0_mub, forces=z4.copy(),
            force_std=np.full(N_AXLES, setup.tuning.p0_f), target_forces=z4.copy(),
            residual_forces=z4.copy(), residuals=z4.copy(), creep=z4.copy(), speed=0.0,
            grade=0.0, pad_flaw=False, wheel_flaw=np.zeros(N_AXLES, dtype=bool), level=0,
            message="waiting for brake sensor data", measurement_used=False)
        self.t_last = -math.inf
        self.t_speed = -math.inf
        self.max_gap = (0.0, math.nan)
        """Longest interval between consecutive received samples and where it began [s]."""
        self.state = "waiting"
        self.counts = {"received": 0, "used": 0, "degraded": 0, "paused": 0, "sliding": 0,
                       "waiting": 0, "rejected": 0}
        self.update_s = 0.0
        """CPU time spent in the observer [s] (process time: independent of CPU contention)."""
        self.updates = 0
        self.braked_updates = 0
        """Updates with a mean clamp force above ``BRAKED_CLAMP_N`` (mu_b observable)."""
        self.mu_b_range = (math.inf, -math.inf)
        """Smallest and largest mu_b_hat while judged (std below ``MU_B_STD_JUDGE``)."""
        self.flaw_time: Optional[float] = None
        """Sample time at which the first flaw was announced [s]."""
        self.flaw_text = ""
        self.last_judged = (math.nan, math.nan, math.nan)
        """Last (mu_b_hat, std, t) with std below ``MU_B_STD_JUDGE`` (the latest real
        measurement of the pad friction: between brake applications the filter restarts
        from the prior)."""
        self.judged: list[float] = []
        """Every mu_b_hat with std below ``MU_B_STD_JUDGE`` (for the shutdown summary)."""
        self._t_used = -math.inf
        self._t_fed = -math.inf
        self._ooo_n = 0
        self._ooo_last = -math.inf
        self.resyncs = 0
        """Times the stream was followed again behind a future-stamped sample."""
        self._sample = (np.zeros(N_AXLES), math.nan)
        self._info = (-1, 0.0)
        """(observer restarts seen, information variance of mu_b [-^2])."""
        self.obs.mu_b_std_floor = self.mu_b_std_bound
        cur = setup.curve
        self._c = (cur.c1, cur.c2, cur.c3)
        self._slip_peak = cur.slip_peak
        self._mu_peak = cur.mu_peak

    @property
    def assessed(self) -> bool:
        """Whether the brake was assessed.

        At least one observer update at speed (above ``V_PAUSE_MPS``) with the friction
        brake applied (mean clamp force above ``BRAKED_CLAMP_N``), or mu_b judged at least
        once (its std below ``MU_B_STD_JUDGE``: light blended brake applications can carry
        enough information for the decision to announce a pad flaw).  A train with neither
        (electric braking down to a crawl) is not assessed: its OK says nothing about its
        pads.
        """
        return self.braked_updates > 0 or bool(self.judged)

    def reject(self) -> None:
        """Count a sample rejected before :meth:`feed` (malformed, wrong train id)."""
        self.counts["received"] += 1
        self.counts["rejected"] += 1

    def mu_b_std_bound(self, obs: mc.MetroBrakeObserver, u: np.ndarray) -> float:
        """Lower bound of the mu_b std from the information in the creep data [-].

        The filter's own std is optimistic: the virtual accelerometer is computed from its
        previous posterior and fed back as if it were independent data (an emergency brake
        std of ~0.005 with scatter of that order, service brakes 0.011 with scatter ~0.04).
        What the data can tell: per used sample and axle j on the stable branch above
        ``V_PSEUDO_MPS``, the creep ``s_j`` is measured with std
        ``sigma_s = sqrt((sigma_w r_w)^2 + P_vv) / v`` (wheel-speed noise of the observer's
        model and the posterior speed variance), the axle force ``F_j = N_j mu_a(s_j)``
        with ``N_j mu_a'(s_j) sigma_s``, and ``F_j`` responds to mu_b with
        ``2 R_b F_cj / r_w`` (Lin 2010b, eq. 4), so the Fisher information of the sample is
        ``sum_j (2 R_b F_cj / (r_w N_j mu_a'(s_j) sigma_s))^2``.  It is accumulated like the
        filter's mu_b (random walk ``q_mub`` per sample, restarted with the filter from the
        prior ``p0_mub``).
        """
        p = self.setup.params
        tun = self.setup.tuning
        ukf = obs.ukf
        resets, var = self._info
        if resets != obs.counters.resets or ukf is None:
            var = tun.p0_mub ** 2
        var += tun.q_mub ** 2
        om, vref = self._sample
        if ukf is not None and math.isfinite(vref) and vref > V_PSEUDO_MPS:
            # per axle as plain floats, the array expressions' arithmetic in their order
            c1, c2, c3 = self._c
            fc = np.asarray(u, dtype=float).tolist()[:N_AXLES]
            oml = np.asarray(om, dtype=float).tolist()
            info = None
            sig_s = math.nan
            nload = obs.mass * mc.G / N_AXLES
            for j in range(N_AXLES):
                s = abs(vref - p.r_w * oml[j]) / vref
                if not (s < self._slip_peak and fc[j] > 0.0):
                    continue  # NaN, the falling branch or no clamp force
                if info is None:
                    info = 0.0
                    sig_s = math.sqrt((self.setup.noise.omega * p.r_w) ** 2
                                      + max(float(ukf.p[0, 0]), 0.0)) / vref
                slope = c1 * c2 * math.exp(-c2 * s) - c3
                gain = 2.0 * p.r_b * fc[j] / (p.r_w * nload * slope * sig_s)
                info += gain * gain
            if info is not None:
                var = 1.0 / (1.0 / var + info)
        self._info = (obs.counters.resets, var)
        return math.sqrt(var)

    def _resync(self, t: float) -> bool:
        """True once ``RESYNC_SAMPLES`` out-of-order samples in a row are in order.

        A sample stamped in the future (within the run's horizon) would otherwise make
        every later genuine sample "out of order"; a consistent stream behind it shows the
        earlier stamp was the outlier, and the stream is followed again.
        """
        if t > self._ooo_last:
            self._ooo_n += 1
        else:
            self._ooo_n = 1
        self._ooo_last = t
        if self._ooo_n >= RESYNC_SAMPLES:
            self._ooo_n, self._ooo_last = 0, -math.inf
            self.t_last = -math.inf
            self.resyncs += 1
            # the filter's time base is the outlier's too: restart it from the next sample
            # (latched flaws stay)
            self.obs.ukf = None
            self.obs.t_last = None
            return True
        return False

    def _virtual_accel(self, t: float, vref: float) -> float:
        """Specific force of the car's own axles at the last posterior [m/s^2] (or NaN).

        Used only when that posterior is trustworthy as a linearisation point: recent (at
        most ``PSEUDO_MAX_AGE_S`` old: lost samples), above ``V_PSEUDO_MPS``, its speed
        consistent with the new reference speed (within ``PSEUDO_SPEED_GATE_MPS``; a speed
        error of a few tenths of m/s already puts the creep on the saturated part of the
        curve, and the pseudo-measurement would then feed the error back), and every axle
        on the stable branch of the adhesion curve (no slide: wheel-slide protection).  The
        per-axle targets are limited to what a trailer axle can transmit: braking forces up
        to the peak adhesion, tractive forces only the wheelset's own inertia at 1.5 m/s^2.
        """
        r = self.result
        age = t - self._t_used
        if (not r.measurement_used or r.speed < V_PSEUDO_MPS or age > PSEUDO_MAX_AGE_S
                or not abs(r.speed - vref) < PSEUDO_SPEED_GATE_MPS + 1.5 * age
                or not all(abs(c) < self._slip_peak for c in r.creep.tolist())):
            return math.nan
        p = self.setup.params
        mass = self.obs.mass
        nload = mass * mc.G / N_AXLES
        lo, hi = -nload * self._mu_peak, 1.5 * p.j_w / (p.r_w * p.r_w)
        f = 0.0
        for x in r.target_forces.tolist():  # np.clip (NaN stays), then np.sum (in order)
            f += x if x != x else (hi if x > hi else (x if x > lo else lo))
        v = r.speed
        a, b, c = p.davis
        sign = 1.0 if v > 0.0 else (-1.0 if v < 0.0 else 0.0 * v)
        return f / mass - laws.davis_resistance(v, a, b, c) * sign

    def feed_paused(self, t: float, vref: float, mass: float) -> bool:
        """:meth:`feed` of an in-order sample of a slow or standing train; False otherwise.

        ``t`` the sample's stamp, ``vref`` its reference speed [m/s], ``mass`` its car mass
        [kg] (floats).  When ``t`` is after the last sample and ``vref`` is finite and at
        most ``V_PAUSE_MPS`` (most samples: trains standing with the holding brake on),
        does what :meth:`feed` does with it (counted, stamp, gap and mass kept) without
        building its channels and returns True; otherwise changes nothing and returns
        False (the caller then uses :meth:`feed`).  the per-sample cost of the
        ~84 % paused samples of a line.
        """
        if not (t > self.t_last and vref <= V_PAUSE_MPS and vref > -math.inf):
            return False
        c = self.counts
        c["received"] += 1
        self._ooo_n = 0
        last = self.t_last
        if last > -math.inf and t - last > self.max_gap[0]:
            self.max_gap = (t - last, last)
        self.t_last = t
        if mass == mass:  # MetroBrakeObserver.set_mass: finite and positive only
            self.obs.set_mass(mass)
        self.t_speed = t
        c["paused"] += 1
        self.state = "paused"
        return True

    def feed(self, s: dict[str, Any]) -> str:
        """Process one sample (see class docstring)."""
        c = self.counts
        c["received"] += 1
        t = float(s["t_s"])
        if not t > self.t_last and not self._resync(t):
            c["rejected"] += 1
            return "out_of_order"
        self._ooo_n = 0
        if math.isfinite(self.t_last) and t - self.t_last > self.max_gap[0]:
            self.max_gap = (t - self.t_last, self.t_last)
        self.t_last = t
        mass = s["car_mass"]
        if math.isfinite(mass):
            self.obs.set_mass(mass)
        vref = float(s["ref_speed"])
        if math.isfinite(vref) and vref <= V_PAUSE_MPS:
            # a standing or slow train (most samples: the 1 Hz heartbeat): counted only
            self.t_speed = t
            c["paused"] += 1
            self.state = "paused"
            return "paused"
        oml = np.asarray(s["omega"], dtype=float).tolist()
        ok_om = [x for x in oml if math.isfinite(x)]
        r_w = self.setup.params.r_w
        if math.isfinite(vref):
            v_chk = vref
        elif ok_om:
            v_chk = float(np.median(ok_om)) * r_w
        else:
            v_chk = math.nan
        if math.isfinite(v_chk):
            self.t_speed = t
            if v_chk <= V_PAUSE_MPS:
                c["paused"] += 1
                self.state = "paused"
                return "paused"
            if math.isfinite(vref):
                peak = self._slip_peak
                if sum(1 for x in ok_om if (vref - r_w * x) / vref > peak) >= SLIDE_AXLES:
                    c["sliding"] += 1
                    self.state = "sliding"
                    return "sliding"
        elif t - self.t_speed > self.obs.max_gap_s:
            # no speed channel for a while: let the observer re-initialise on new data
            c["waiting"] += 1
            self.state = "no speed data"
            return "waiting"
        om = np.array(oml)
        clamp = np.asarray(s["clamp"], dtype=float)
        cl = clamp.tolist()
        fin = [x for x in cl if math.isfinite(x)]
        degraded = not (len(ok_om) == N_AXLES and math.isfinite(vref)
                        and len(fin) == N_AXLES and math.isfinite(float(s["accel"])))
        ax = self._virtual_accel(t, vref)
        self._sample = (om, vref)
        if self.obs.ukf is not None and REGATE_GAP_S < t - self._t_fed <= MAX_GAP_S:
            self.obs.decision.restart()
        self._t_fed = t
        t0 = time.process_time()
        r = self.obs.update(t, om, clamp, ax, vref)
        self.update_s += time.process_time() - t0
        self.updates += 1
        self.result = r
        if r.measurement_used:
            self._t_used = t
        if fin:  # np.nanmean: the sum with NaN as 0, over the finite count
            total = 0.0
            for x in cl:
                total += x if math.isfinite(x) else 0.0
            if total / len(fin) > BRAKED_CLAMP_N:
                self.braked_updates += 1
        if r.mu_b_std < MU_B_STD_JUDGE:
            self.mu_b_range = (min(self.mu_b_range[0], r.mu_b), max(self.mu_b_range[1], r.mu_b))
            self.last_judged = (r.mu_b, r.mu_b_std, t)
            if len(self.judged) < 100_000:
                self.judged.append(r.mu_b)
        if r.level == 2 and self.flaw_time is None:
            self.flaw_time = t
            self.flaw_text = f"{r.message} (mu_b_hat {r.mu_b:.3f} +- {r.mu_b_std:.3f})"
        self.state = "running"
        kind = "degraded" if degraded else "used"
        c[kind] += 1
        return kind

    def level(self) -> int:
        """The level of :meth:`level_message` without its text (checked after each sample)."""
        c = self.counts
        if c["received"] == 0:
            return 0
        level = int(self.result.level) if self.updates else 0
        if self.state in ("paused", "sliding") and level < 2:
            level = 0
        bad = c["rejected"] + c["degraded"] + c["waiting"]
        if level < 1 and bad > max(20, c["received"] // 2):
            level = 1
        return level

    def level_message(self) -> tuple[int, str]:
        """The train's level (0/1/2) and a one-line message for /diagnostics."""
        r = self.result
        c = self.counts
        if c["received"] == 0:
            return 0, "waiting for brake sensor data"
        level = int(r.level) if self.updates else 0
        if self.state in ("paused", "sliding") and level < 2:
            level = 0
        mu = f"mu_b {r.mu_b:.3f} +- {r.mu_b_std:.3f}"
        if level == 2:
            text = f"brake flaw since t={self.flaw_time or r.t:.2f} s: " \
                   f"{self.flaw_text or r.message}; now {mu}"
        elif level == 1:
            text = f"violation in progress ({mu})"
        elif self.state == "paused":
            text = f"slow or standing, observer paused ({mu})"
        elif self.state == "sliding":
            text = f"wheel-slide protection active, observer paused ({mu})"
        elif self.updates == 0:
            text = f"no usable sample yet ({self.state})"
        else:
            text = f"ok ({mu})"
        bad = c["rejected"] + c["degraded"] + c["waiting"]
        if level < 1 and bad > max(20, c["received"] // 2):
            level = 1
            text = f"sensor data quality: {bad} of {c['received']} samples rejected or " \
                   f"incomplete; {text}"
        return level, text
