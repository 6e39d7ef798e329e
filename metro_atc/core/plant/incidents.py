"""Incidents and faults of a scenario: timed events, temporary speed restrictions, holds.

* ``breakdown``: the train brakes to a stop and stays there (or at the platform) for the
  duration; ``hold``: extra dwell of a train at a station; ``tsr``: a temporary speed
  restriction known to ATP ``tsr_notice_s`` before it applies.
* Faults: ``pad_mu``/``wheel`` change the instrumented car's brake physics
  (:meth:`metro_atc.core.plant.braking.Brakes.set_fault`); ``sensor_dropout``/``sensor_stuck``
  act on the sensor samples only (:mod:`.sensors`).
"""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from metro_atc.core.line.geometry import LineGeometry
from metro_atc.core.line.rolling_stock import KMH
from metro_atc.core.line.scenario import Scenario

from .braking import N_AXLES_SENSED, Brakes
from .fleet import Fleet

FloatArray = NDArray[np.float64]


@dataclass
class TimedEvent:
    """A queued discrete event (breakdown, fault on/off) at time ``t`` [s]."""

    t: float
    kind: str
    data: dict[str, Any] = field(default_factory=dict)


class Incidents:
    """Timed-event queue, TSR zones and the sensor faults of a scenario."""

    def __init__(self, scn: Scenario, n_st: int) -> None:
        """Queue the scenario's incidents and faults (train ids -> indices)."""
        self.queue: list[tuple[float, int, TimedEvent]] = []
        self._qseq = 0
        tid = {t: i for i, t in enumerate(scn.train_ids)}
        self.extra_hold = np.zeros((scn.trains.count, n_st))
        self.tsrs: list[tuple[float, float, float, float, float]] = []
        for t in scn.line.temporary_speed_limits:
            self.tsrs.append((t.start_m, t.end_m, t.limit_kmh * KMH, t.from_s, t.to_s))
        for inc in scn.incidents:
            if inc.kind == "tsr":
                self.tsrs.append((inc.start_m, inc.end_m, inc.limit_kmh * KMH, inc.at_s,
                                  inc.at_s + inc.duration_s))
            elif inc.kind == "hold":
                j = scn.station_index(inc.station)
                self.extra_hold[tid[inc.train], j] += inc.duration_s
            elif inc.kind == "breakdown":
                self.push(inc.at_s, "breakdown", train=tid[inc.train], dur=inc.duration_s)
        self.notice_s = scn.signalling.tsr_notice_s
        self.reschedule_tsrs()
        self.sensor_faults: list[dict[str, Any]] = []
        for fl in scn.faults:
            i = tid[fl.train]
            axes = list(range(N_AXLES_SENSED)) if fl.axle == 0 else [fl.axle - 1]
            if fl.kind in ("pad_mu", "wheel"):
                self.push(fl.at_s, "fault_on", train=i, axles=axes, spec=fl)
                if math.isfinite(fl.duration_s):
                    self.push(fl.at_s + fl.duration_s, "fault_off", train=i, axles=axes,
                              spec=fl)
            else:
                self.sensor_faults.append({"train": i, "axles": axes, "kind": fl.kind,
                                           "channel": fl.channel, "t0": fl.at_s,
                                           "t1": fl.at_s + fl.duration_s, "stuck": None})

    def reschedule_tsrs(self) -> None:
        """The TSR calendar of :attr:`tsrs` (after a change): known, in force, lifted [s].

        The next :meth:`tsr_changed` (forced) walks it up to the current time.
        """
        notice = self.notice_s
        self.tsr_times = sorted({max(f - notice, 0.0) for (_, _, _, f, _) in self.tsrs}
                                | {f for (_, _, _, f, _) in self.tsrs}
                                | {e for (_, _, _, _, e) in self.tsrs if math.isfinite(e)})
        self._tsr_ptr = 0
        self.next_tsr_t = 0.0

    def push(self, t: float, kind: str, **data: Any) -> None:
        """Queue an event at time ``t`` [s] (ties keep the insertion order)."""
        self._qseq += 1
        heapq.heappush(self.queue, (t, self._qseq, TimedEvent(t, kind, data)))

    def next_t(self) -> float:
        """Time of the next queued event or TSR change [s] (inf if none)."""
        nxt = self.next_tsr_t
        if self.queue:
            nxt = min(nxt, self.queue[0][0])
        return nxt

    def process_queue(self, t: float, fl: Fleet, brakes: Brakes) -> None:
        """Apply the queued events due at ``t``: breakdowns and brake faults."""
        while self.queue and self.queue[0][0] <= t:
            _, _, ev = heapq.heappop(self.queue)
            d = ev.data
            if ev.kind == "breakdown":
                i = d["train"]
                fl.broken_until[i] = ev.t + d["dur"]
                if fl.dwelling[i]:
                    fl.release_t[i] = max(fl.release_t[i], ev.t + d["dur"])
            elif ev.kind in ("fault_on", "fault_off"):
                f = d["spec"]
                brakes.set_fault(d["train"], d["axles"], f.kind, ev.kind == "fault_on", f.mu_b,
                                 f.adhesion_factor, f.radius_factor)

    def tsr_changed(self, t: float, force: bool = False) -> bool:
        """Advance the TSR calendar to ``t``; True when the grids must be recomputed."""
        changed = force
        while self._tsr_ptr < len(self.tsr_times) and self.tsr_times[self._tsr_ptr] <= t:
            self._tsr_ptr += 1
            changed = True
        if changed:
            self.next_tsr_t = (self.tsr_times[self._tsr_ptr]
                               if self._tsr_ptr < len(self.tsr_times) else math.inf)
        return changed

    def ceiling(self, geom: LineGeometry, t: float, notice: float) -> FloatArray:
        """Per-cell limit incl. TSRs in force at ``t`` (known ``notice`` s ahead) [m/s]."""
        lim = geom.static_limit.copy()
        for (a, b, v, f, e) in self.tsrs:
            if f - notice <= t < e:
                k0 = int(math.floor((a - geom.x0) / geom.dx))
                k1 = int(math.ceil((b - geom.x0) / geom.dx))
                k0, k1 = max(k0, 0), min(k1, geom.n_cells)
                lim[k0:k1] = np.minimum(lim[k0:k1], v)
        return lim
