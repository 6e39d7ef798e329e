"""ATS dispatching: timetable or regulated departure commands from train events (ROS-free).

The ``ats_regulator`` node is a thin shell around :class:`AtsDispatcher`: it converts
``/line/events`` messages into :meth:`AtsDispatcher.on_event` calls and publishes the
returned :class:`Dispatch` as ``DepartureCommand`` messages.  The dispatcher keeps only
what the events tell it, so a restarted node rebuilds the same state by replaying the
transient-local event history.

What a command means for the line (the plant, :meth:`LineSim.set_departure`):

- ``departure_s``: the train is held at the platform until then (and until its passenger
  exchange is done, unless the dwell is cut);
- ``running_s``: the ATO's target running time to the next station;
- ``dwell_limit_s``: NaN, or a dwell cut: the doors close that long after the arrival
  (never before the minimum dwell) even if passengers are still boarding.

Regulation (Lin 2010a, eq. 5: u_j(k) is the adjustment of the run into station j plus the
dwell at j, decided on the staggered departure-deviation state x(k) = t(k) - T(k)):

- ``none`` (timetable, Lin 2010a, eq. 10): departure at the timetable, scheduled running
  time, passenger-driven dwell -- trains never leave early and a late train's ATO catches
  up by running faster (it aims at the scheduled arrival).
- ``lqr`` / ``dhp`` / ``aoc``: on the arrival of train m at station j the regulator's u_j
  for the current state estimate (:class:`AtsRegulatorCore`) is applied to what is left
  of it: the run into j is done, so the dwell adjustment is
  ``du_dwell = clip(u_j - (realised run - scheduled run), min_dwell - S_mj, hold_max)``
  with S_mj the scheduled dwell.  ``du_dwell > 0`` holds the train until
  ``arrival + S_mj + du_dwell`` (never before the timetable); ``du_dwell < 0`` cuts the
  dwell to ``S_mj + du_dwell`` (not below the minimum dwell, and the doors never close
  before ``timetable + cut_tolerance_s``): the control that keeps a late train from
  collecting ever more passengers (the t_b p(k) term of Lin 2010a, eq. 4-5 that makes delays
  grow), used for trains beyond the punctuality tolerance only.  The
  running-time target to j+1 is the running part of the regulator's u_{j+1}
  (:func:`metro_atc.core.atr.traffic.split_adjustment`, between the flat-out and the
  maximum running time).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import List, Optional

import numpy as np

from metro_atc.core.atr.cost import CostWeights
from metro_atc.core.atr.fingerprint import line_hash
from metro_atc.core.atr.node_core import KINDS, AtsRegulatorCore
from metro_atc.core.atr.registry import REGULATORS
from metro_atc.core.atr.regulators import make_regulator
from metro_atc.core.bridge import Timetable, atr_line_for, timetable_for
from metro_atc.core.line.scenario import Scenario


@dataclass(frozen=True)
class Dispatch:
    """One departure command: train index, station index, times in s (see module doc)."""

    train: int
    station: int
    departure_s: float
    running_s: float
    dwell_limit_s: float
    adjustment_s: float = 0.0


class AtsDispatcher:
    """Timetable or regulated dispatching of every train of a scenario (module docstring)."""

    def __init__(self, tt: Timetable, core: Optional[AtsRegulatorCore] = None,
                 min_dwell_s: float = 20.0, hold_max_s: float = 60.0,
                 cut_tolerance_s: float = 30.0) -> None:
        """``core`` None: timetable (``none``); else its regulator decides (lqr/dhp/aoc).

        min_dwell_s: shortest dwell a cut may command [s]; hold_max_s: longest hold [s];
        cut_tolerance_s: a cut never closes the doors before ``timetable + cut_tolerance_s``
        -- dwells are cut to bring late trains back within the punctuality tolerance, not
        to leave passengers behind for a few seconds' lateness [s].
        """
        if not (math.isfinite(min_dwell_s) and min_dwell_s >= 0.0):
            raise ValueError(f"min_dwell_s must be finite and >= 0, got {min_dwell_s!r}")
        if not (math.isfinite(hold_max_s) and hold_max_s >= 0.0):
            raise ValueError(f"hold_max_s must be finite and >= 0, got {hold_max_s!r}")
        self.tt = tt
        self.core = core
        self.ids = list(tt.train_ids)
        self.index = {t: i for i, t in enumerate(self.ids)}
        self.n_st = len(tt.station_names)
        n = len(self.ids)
        if not (math.isfinite(cut_tolerance_s) and cut_tolerance_s >= 0.0):
            raise ValueError(f"cut_tolerance_s must be finite and >= 0, got {cut_tolerance_s!r}")
        self.min_dwell_s = float(min_dwell_s)
        self.hold_max_s = float(hold_max_s)
        self.cut_tolerance_s = float(cut_tolerance_s)
        self.arrival_s = np.full((n, self.n_st), math.nan)
        self.departure_s = np.full((n, self.n_st), math.nan)
        self._last: dict[int, tuple[tuple[int, int], float]] = {}

    def train_index(self, train_id: str) -> int:
        """Index of a train id; ValueError naming it when unknown."""
        if train_id not in self.index:
            raise ValueError(f"unknown train id {train_id!r} (known: {self.ids[0]} .. "
                             f"{self.ids[-1]})")
        return self.index[train_id]

    # ------------------------------------------------------------------ commands
    def initial(self) -> List[Dispatch]:
        """First departures of every train from station 0 (published at start-up)."""
        return [self._timetable(i, 0) for i in range(len(self.ids))]

    def first_departure(self, train_id: str, earliest_s: float) -> Dispatch:
        """Station-0 command of a train coming out of a turnback: never before ``earliest_s``.

        ``earliest_s`` [s]: the turnback link's earliest departure (arrival of the train's
        previous trip plus the minimum turnback,
        :func:`metro_atc.core.service.turnback.turnback_link`); whatever the timetable or
        the regulator would command, the departure is max(timetable, earliest_s).
        ValueError for an unknown train or a non-finite instant.
        """
        i = self.train_index(train_id)
        e = float(earliest_s)
        if not math.isfinite(e):
            raise ValueError(f"earliest departure {earliest_s!r} of {train_id} is not finite")
        d = self._timetable(i, 0)
        return replace(d, departure_s=max(d.departure_s, e))

    def on_event(self, train_id: str, station: int, kind: str, t_s: float
                 ) -> Optional[Dispatch]:
        """Record an event; return the command it triggers (arrivals at stations 1..N-2).

        Raises ValueError with a clear message for an unknown train, a station out of range,
        an unknown kind, a non-finite time or an event that does not advance the train
        (out of order or duplicate); the state is then unchanged.
        """
        i = self.train_index(train_id)
        if isinstance(station, bool) or not 0 <= int(station) < self.n_st:
            raise ValueError(f"station index {station} outside 0..{self.n_st - 1}")
        j = int(station)
        if kind not in KINDS:
            raise ValueError(f"event kind must be 'arrival' or 'departure', got {kind!r}")
        t = float(t_s)
        if not math.isfinite(t):
            raise ValueError(f"event time {t_s!r} is not finite")
        key = (j, KINDS.index(kind))
        last = self._last.get(i)
        if last is not None and (key <= last[0] or t < last[1]):
            raise ValueError(f"event {kind} of {train_id} at station {j} (t={t:.3f} s) does "
                             f"not advance on its previous event (out of order/duplicate)")
        if self.core is not None:
            self.core.on_event(train_id, j, kind, t)
        self._last[i] = (key, t)
        if kind == "departure":
            self.departure_s[i, j] = t
            return None
        self.arrival_s[i, j] = t
        if j == 0 or j >= self.n_st - 1:
            # station 0 keeps its start-up command (:meth:`initial`): a second command there
            # would race the first one in the lockstep, and a restarted ATS republishes the
            # same start-up commands; the terminus has no departure
            return None
        return self._regulated(i, j, t) if self.core is not None else self._timetable(i, j)

    def _timetable(self, i: int, j: int) -> Dispatch:
        """The timetable: scheduled departure and running time, no dwell cut."""
        run = float(self.tt.running_s[j])
        if self.core is not None and j + 1 < self.n_st:
            run = self._running_target(i, j)
        return Dispatch(i, j, float(self.tt.departure_s[i, j]), run, math.nan)

    def _running_target(self, i: int, j: int) -> float:
        """Running-time target j -> j+1: the running part of the regulator's u_{j+1}."""
        assert self.core is not None
        return self.core.running_target(self.ids[i], j + 1)

    def _regulated(self, i: int, j: int, arrival_s: float) -> Dispatch:
        """Dwell adjustment from the regulator's u_j (module docstring) and run target."""
        assert self.core is not None
        u = self.core.adjustment(self.ids[i], j)
        done_run = 0.0
        if j >= 1 and math.isfinite(self.departure_s[i, j - 1]):
            done_run = arrival_s - self.departure_s[i, j - 1] - float(self.tt.running_s[j - 1])
        sched_dwell = float(self.tt.dwell_s[i, j])
        du = float(np.clip(u - done_run, self.min_dwell_s - sched_dwell, self.hold_max_s))
        tt_dep = float(self.tt.departure_s[i, j])
        if du >= 0.0:
            dep, limit = max(tt_dep, arrival_s + sched_dwell + du), math.nan
        else:
            dep = tt_dep
            limit = max(sched_dwell + du, self.min_dwell_s,
                        tt_dep + self.cut_tolerance_s - arrival_s)
        return Dispatch(i, j, dep, self._running_target(i, j), limit, du)


def make_dispatcher(scn: Scenario, regulator: str = "none", weights_file: str = "",
                    cost: Optional[CostWeights] = None, energy_weight: float = 1.0,
                    hold_max_s: float = 60.0, cut_tolerance_s: float = 30.0,
                    tt: Optional[Timetable] = None) -> AtsDispatcher:
    """The ATS of a scenario with a regulator by name (what the ``ats_regulator`` node runs).

    ``dhp``/``aoc`` load ``weights_file`` ('' : the shipped or cached weights trained on
    this line, :func:`metro_atc.core.atr.weights_store.find_weights`; none: ValueError);
    weights trained on another line are refused (traffic-model hash);
    ``elqr`` is the energy-aware LQR (:mod:`metro_atc.core.atr.energy`, Sheu 2011) with
    weight ``energy_weight``; its energy table is built from the scenario (a few seconds).
    Raises ValueError / FileNotFoundError with a clear message for a bad choice or file.
    """
    entry = REGULATORS.entry(regulator)
    tt = tt if tt is not None else timetable_for(scn)
    core = None
    if regulator != "none":
        line = atr_line_for(scn, tt)
        w = cost if cost is not None else CostWeights()
        path: Optional[str] = weights_file or None
        if entry.has("trained") and not path:
            # here, not at the top: the weights store imports torch (~2 s of CPU), which
            # the ATS with 'none' or 'lqr' never needs
            from metro_atc.core.atr.weights_store import find_weights
            found = find_weights(regulator, line)
            if found is None:
                raise ValueError(
                    f"no {regulator} weights trained on this line (traffic-model hash "
                    f"{line_hash(line)[:12]}): 'python -m metro_atc run --train-regulator "
                    f"auto' trains them, or give weights_file")
            path = str(found)
        reg = make_regulator(regulator, line, w, path, scenario=scn, energy_weight=energy_weight)
        core = AtsRegulatorCore(line, regulator, weights_path=path, cost=w,
                                train_ids=tt.train_ids,
                                first_dispatch_s=float(tt.departure_s[0, 0]),
                                departure_table_s=tt.departure_s,
                                arrival_table_s=tt.arrival_s, regulator=reg)
    return AtsDispatcher(tt, core, min_dwell_s=float(scn.passengers.min_dwell_s),
                         hold_max_s=hold_max_s, cut_tolerance_s=cut_tolerance_s)
