"""Brake diagnosis of every instrumented train of a ROS-free line run.

:class:`LineBrakeMonitor` does, without ROS, what the graph does between the line simulator
and the ``brake_diagnostic`` node: each step's brake sensor samples
(:attr:`metro_atc.core.plant.sensors.StepResult.sensor_arrays`) are thinned like the
simulator node publishes them (every sample while a car brakes, a heartbeat every
``idle_period_s`` otherwise: :func:`published`) and fed to one
:class:`~metro_atc.core.brake.train_watch.TrainBrakeWatch` per train, whose level
(OK / WARN / ERROR, :meth:`TrainBrakeWatch.level_message`) is followed sample by sample.

Figures (:meth:`LineBrakeMonitor.summary`):

* ``brake_assessed``: per train, whether its brake was assessed at all (at least one observer
  update at speed with the friction brake applied, or mu_b judged once:
  :attr:`TrainBrakeWatch.assessed`; mu_b is observable only while the pads act);
  ``brake_trains_assessed`` how many were, ``brake_trains_not_assessed`` the others (on
  stock whose friction brake never acts at speed: every train, and its OK says nothing);
* ``brake_false_alarms``: level rises (OK -> WARN, OK/WARN -> ERROR) of assessed trains with
  no pad or wheel fault in force at that time; ``brake_false_errors`` the ERROR ones among
  them; both None (not assessed, not "0 false alarms") when no train was assessed;
  ``brake_alarms_not_assessed`` the level rises of fault-free trains that were not assessed
  (sensor-data quality), counted apart;
* ``brake_faults`` / ``brake_faults_detected``: injected pad-friction and wheel faults and
  those announced (ERROR) while in force, with the delay from the fault onset
  (``brake_detect_delays_s``) and from the first friction-brake application at speed after
  the onset (``brake_detect_after_brake_s``: what the observer can do at best, since
  mu_b is only observable while the pads are applied);
* ``brake_mu_b_judged_min``: smallest judged pad-friction estimate of fault-free trains.

Sensor-data-quality WARNs (more than half of the samples rejected) cannot occur here: the
samples come straight from the plant.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Optional

import numpy as np

from metro_atc.core.brake.train_watch import (BRAKED_CLAMP_N, V_PAUSE_MPS, TrainBrakeWatch,
                                              observer_setup)
from metro_atc.core.line.scenario import Scenario

BRAKING_CLAMP_N = 1000.0
"""A sample with some axle clamp force above this counts as braking (published at the full
rate), as in ``sim_sensors.SensorOutbox.take`` [N]."""
IDLE_PERIOD_S = 1.0
"""Heartbeat period between brake applications (``sensor_idle_period_s`` default) [s]."""
BRAKE_FAULT_KINDS = ("pad_mu", "wheel")
"""Fault kinds the diagnosis must announce (sensor faults are not brake flaws)."""


def published(clamp: np.ndarray, t: np.ndarray, last_t: np.ndarray,
              idle_period_s: float = IDLE_PERIOD_S) -> np.ndarray:
    """Which samples the line simulator node publishes, and update ``last_t`` in place.

    Args:
        clamp: clamp forces [n_samples, n_trains, 4] [N].
        t: sample times [n_samples] [s].
        last_t: time of each train's last published sample [n_trains] [s] (updated).
        idle_period_s: heartbeat period while not braking [s] (<= 0: publish all).

    Returns:
        Boolean mask [n_samples, n_trains].
    """
    braking = np.nanmax(np.asarray(clamp, dtype=float), axis=2, initial=0.0) > BRAKING_CLAMP_N
    out = np.zeros(braking.shape, dtype=bool)
    for a, ts in enumerate(t):
        ok = braking[a] | (idle_period_s <= 0.0) | (ts - last_t >= idle_period_s - 1e-9)
        last_t[ok] = ts
        out[a] = ok
    return out


@dataclass
class _Fault:
    """One injected brake fault and what the monitor saw of it."""

    train: int
    kind: str
    t0: float
    t1: float
    braked_t: float = math.nan
    detect_t: float = math.nan


@dataclass
class _TrainState:
    """Level history of one train."""

    level: int = 0
    rises: list[tuple[float, int, int, str]] = field(default_factory=list)


class LineBrakeMonitor:
    """One brake watch per instrumented train of a line run (see module docstring).

    Args:
        scn: the scenario the plant runs (sensors, rail condition, rolling stock, faults).
        idle_period_s: heartbeat period of the sensor publication between brakes [s].
    """

    def __init__(self, scn: Scenario, idle_period_s: float = IDLE_PERIOD_S) -> None:
        """Build the watches and the list of injected brake faults."""
        setup = observer_setup(scn)
        ids = list(scn.train_ids)
        self.ids = ids
        self.watch = {i: TrainBrakeWatch(ids[i], setup) for i in range(len(ids))}
        self.state = {i: _TrainState() for i in self.watch}
        self.idle_period_s = float(idle_period_s)
        self.last_pub = np.full(len(ids), -math.inf)
        pos = {t: i for i, t in enumerate(ids)}
        self.faults = [_Fault(pos[f.train], f.kind, float(f.at_s),
                              float(f.at_s) + (math.inf if f.duration_s is None
                                               else float(f.duration_s)))
                       for f in scn.faults if f.kind in BRAKE_FAULT_KINDS and f.train in pos]

    def _faulty(self, i: int, t: float) -> Optional[_Fault]:
        for f in self.faults:
            if f.train == i and f.t0 <= t < f.t1:
                return f
        return None

    def on_step(self, res: Any) -> None:
        """Feed the samples of one plant step (a ``StepResult``) to the watches."""
        b = res.sensor_arrays
        if b is None or b.t.size == 0:
            return
        trains = np.asarray(b.trains)
        last = self.last_pub[trains]
        pub = published(b.clamp, b.t, last, self.idle_period_s)
        self.last_pub[trains] = last
        for a in range(b.t.size):
            t = float(b.t[a])
            for c, i in enumerate(trains):
                if not pub[a, c]:
                    continue
                self._feed(int(i), t, b, a, c)

    def _feed(self, i: int, t: float, b: Any, a: int, c: int) -> None:
        self.feed_sample(i, {"t_s": t, "omega": b.omega[a, c], "clamp": b.clamp[a, c],
                             "accel": float(b.accel[a, c]), "ref_speed": float(b.vref[a, c]),
                             "car_mass": float(b.car_mass[c])})

    def feed_sample(self, i: int, s: dict[str, Any]) -> None:
        """Feed one published sample of train ``i`` and follow its level.

        ``s``: the sample dict of :meth:`TrainBrakeWatch.feed`.
        """
        w = self.watch.get(i)
        if w is None:
            return
        t = float(s["t_s"])
        clamp = np.asarray(s["clamp"], dtype=float)
        w.feed(s)
        f = self._faulty(i, t)
        if (f is not None and math.isnan(f.braked_t) and np.isfinite(clamp).any()
                and float(np.nanmean(clamp)) > BRAKED_CLAMP_N
                and float(s["ref_speed"]) > 2.0 * V_PAUSE_MPS):
            f.braked_t = t
        level, text = w.level_message()
        st = self.state[i]
        if level > st.level:
            st.rises.append((t, st.level, level, text))
            if level == 2 and f is not None and math.isnan(f.detect_t):
                f.detect_t = t
        st.level = level

    def false_alarms(self) -> list[tuple[str, float, int, int, str]]:
        """Level rises of trains without a brake fault in force: (train, t, from, to, text)."""
        out = []
        for i, st in self.state.items():
            for t, a, b, text in st.rises:
                if self._faulty(i, t) is None:
                    out.append((self.ids[i], t, a, b, text))
        return out

    def summary(self) -> dict[str, Any]:
        """Figures of the run (module docstring)."""
        assessed = {self.ids[i]: w.assessed for i, w in self.watch.items()}
        fa = self.false_alarms()
        judged_fa = [x for x in fa if assessed[x[0]]]
        any_assessed = any(assessed.values())
        faulty = {f.train for f in self.faults}
        judged = [min(w.judged) for i, w in self.watch.items() if w.judged and i not in faulty]
        det = [f for f in self.faults if not math.isnan(f.detect_t)]
        return {
            "brake_assessed": assessed,
            "brake_trains_assessed": sum(assessed.values()),
            "brake_trains_not_assessed": sorted(t for t, a in assessed.items() if not a),
            "brake_false_alarms": len(judged_fa) if any_assessed else None,
            "brake_false_errors": (sum(1 for x in judged_fa if x[3] == 2) if any_assessed
                                   else None),
            "brake_alarms_not_assessed": len(fa) - len(judged_fa),
            "brake_faults": len(self.faults),
            "brake_faults_detected": len(det),
            "brake_detect_delays_s": [f.detect_t - f.t0 for f in det],
            "brake_detect_after_brake_s": [f.detect_t - f.braked_t for f in det
                                           if not math.isnan(f.braked_t)],
            "brake_faults_never_braked": sum(1 for f in self.faults if math.isnan(f.braked_t)),
            "brake_mu_b_judged_min": min(judged) if judged else math.nan,
            "brake_observer_updates": int(sum(w.updates for w in self.watch.values())),
        }
