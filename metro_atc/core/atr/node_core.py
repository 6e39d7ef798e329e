"""Stateful ATR core for the ``ats_regulator`` node (ROS-free).

The node feeds train events (arrival / departure at a station, simulated time [s]) into
:class:`AtsRegulatorCore` and asks for departure commands.  The core keeps only the event
log, so a restarted node rebuilds its full state by replaying the events it receives
(:meth:`AtsRegulatorCore.from_history`).

Timetable: train ``train_ids[m]`` is service m, dispatched at z0 + m H (steady peak
timetable of Lin 2010a, eq. 10 with one duration) unless an explicit departure table is
given.  A command for (train m, station j) is the Lin 2010a, eq. 5 decision u_j(k) with
k = m + j: the adjustment of the run j-1 -> j plus the dwell at j, computed from the
staggered state t(k) whose entry i is train m + j - 1 - i at station i.  Entries without a
recorded departure use the train's latest known delay (0 if it has no event yet): the
line state is estimated from the latest information, and the decision is receding-horizon
(stage 0 of the K adjustable services).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, Iterable, List, Optional, Sequence, Tuple, Union

import numpy as np

from metro_atc.core.atr.blue_line import LineData
from metro_atc.core.atr.cost import CostWeights
from metro_atc.core.atr.regulators import Regulator, make_regulator
from metro_atc.core.atr.traffic import schedule_offsets, split_adjustment

KINDS = ("arrival", "departure")


@dataclass(frozen=True)
class TrainEvent:
    """An arrival or departure of a train at a station at simulated time t_s [s]."""

    train_id: str
    station_idx: int
    kind: str
    t_s: float


@dataclass(frozen=True)
class DepartureCommand:
    """Regulated departure of a train at a station (times in s, durations in s).

    target_running_time_s is the run station_idx-1 -> station_idx (0 at the first station);
    target_dwell_s the dwell at station_idx; adjustment_s the applied (saturated) u.
    """

    train_id: str
    station_idx: int
    departure_time_s: float
    target_running_time_s: float
    target_dwell_s: float
    scheduled_departure_s: float
    adjustment_s: float


class AtsRegulatorCore:
    """Event-driven ATR: validates events, estimates the line state, issues commands."""

    def __init__(self, line: LineData, regulator_name: str = "none",
                 weights_path: Optional[Union[str, Path]] = None,
                 cost: Optional[CostWeights] = None, train_ids: Sequence[str] = (),
                 first_dispatch_s: float = 0.0,
                 departure_table_s: Optional[np.ndarray] = None,
                 arrival_table_s: Optional[np.ndarray] = None,
                 regulator: Optional[Regulator] = None) -> None:
        """Create the core; ``train_ids`` in dispatch order (service m = index m).

        departure_table_s / arrival_table_s: optional (n_trains, N) scheduled departures /
        arrivals [s] replacing the steady peak timetable (arrivals default to departure
        minus the model's steady dwell).  regulator: a ready regulator (e.g. the
        energy-aware LQR) used instead of ``regulator_name``.
        """
        if len(set(train_ids)) != len(train_ids):
            raise ValueError("train ids must be unique")
        if not math.isfinite(first_dispatch_s):
            raise ValueError("first_dispatch_s must be finite")
        self.line = line
        self.cost = cost if cost is not None else CostWeights()
        self.regulator: Regulator = (regulator if regulator is not None else make_regulator(
            regulator_name, line, self.cost, weights_path))
        self.train_ids: Tuple[str, ...] = tuple(train_ids)
        self._index = {tid: m for m, tid in enumerate(self.train_ids)}
        n = line.n_stations
        h = line.headway_s
        self._sched_dwell = line.dwell_fixed_s + line.c() * h
        if departure_table_s is not None:
            table = np.asarray(departure_table_s, dtype=float)
            if table.shape != (len(self.train_ids), n) or not np.all(np.isfinite(table)):
                raise ValueError(f"departure table must be finite with shape "
                                 f"({len(self.train_ids)}, {n})")
            self._table = table
        else:
            off = schedule_offsets(line)
            m = np.arange(len(self.train_ids))[:, None]
            self._table = first_dispatch_s + m * h + off[None, :]
        self._arr_table: Optional[np.ndarray] = None
        if arrival_table_s is not None:
            arr = np.asarray(arrival_table_s, dtype=float)
            if arr.shape != self._table.shape or not np.all(np.isfinite(arr)):
                raise ValueError(f"arrival table must be finite with shape {self._table.shape}")
            self._arr_table = arr
        self._h = h
        self._dep: Dict[Tuple[int, int], float] = {}
        self._arr: Dict[Tuple[int, int], float] = {}
        self._last: Dict[int, Tuple[Tuple[int, int], float, float]] = {}  # key, t, delay
        self._history: List[TrainEvent] = []

    # --- events ----------------------------------------------------------------------
    @classmethod
    def from_history(cls, events: Iterable[TrainEvent], line: LineData, **kwargs: object
                     ) -> "AtsRegulatorCore":
        """Rebuild a core (e.g. after a node restart) by replaying accepted events."""
        core = cls(line, **kwargs)  # type: ignore[arg-type]
        for ev in events:
            core.on_event(ev.train_id, ev.station_idx, ev.kind, ev.t_s)
        return core

    @property
    def history(self) -> List[TrainEvent]:
        """Accepted events in arrival order (enough to rebuild the state)."""
        return list(self._history)

    def _train(self, train_id: str) -> int:
        if train_id not in self._index:
            raise ValueError(f"unknown train id {train_id!r} (known: {len(self._index)} trains)")
        return self._index[train_id]

    def _station(self, station_idx: int) -> int:
        if isinstance(station_idx, bool) or not isinstance(station_idx, (int, np.integer)):
            raise ValueError(f"station index must be an integer, got {station_idx!r}")
        if not 0 <= int(station_idx) < self.line.n_stations:
            raise ValueError(f"station index {station_idx} outside 0..{self.line.n_stations - 1}")
        return int(station_idx)

    def scheduled(self, m: int, station: int, kind: str) -> float:
        """Scheduled arrival/departure instant [s] of service m at a station."""
        dep = float(self._table[m, station])
        if kind == "departure":
            return dep
        if self._arr_table is not None:
            return float(self._arr_table[m, station])
        return dep - float(self._sched_dwell[station])

    def on_event(self, train_id: str, station_idx: int, kind: str, t_s: float) -> None:
        """Record an event; raises ValueError (clear message) for invalid or out-of-order input.

        Per train, events must advance: (station, arrival) < (station, departure) <
        (station + 1, arrival) ..., skipping is allowed (missed messages), going back or
        repeating is not; time may not decrease.
        """
        m = self._train(train_id)
        j = self._station(station_idx)
        if kind not in KINDS:
            raise ValueError(f"event kind must be 'arrival' or 'departure', got {kind!r}")
        try:
            t = float(t_s)
        except (TypeError, ValueError):
            raise ValueError(f"event time must be a number, got {t_s!r}") from None
        if not math.isfinite(t):
            raise ValueError(f"event time must be finite, got {t_s!r}")
        key = (j, KINDS.index(kind))
        last = self._last.get(m)
        if last is not None:
            if key <= last[0]:
                raise ValueError(
                    f"out-of-order event for {train_id!r}: {kind} at station {j} after "
                    f"{KINDS[last[0][1]]} at station {last[0][0]}")
            if t < last[1]:
                raise ValueError(f"out-of-order event for {train_id!r}: time {t:.3f} s is "
                                 f"before its previous event at {last[1]:.3f} s")
        (self._dep if kind == "departure" else self._arr)[(m, j)] = t
        self._last[m] = (key, t, t - self.scheduled(m, j, kind))
        self._history.append(TrainEvent(train_id, j, kind, t))

    # --- state and commands ------------------------------------------------------------
    def delay_estimate(self, m: int, station: int) -> float:
        """Departure deviation [s] of service m at a station: recorded, else latest known."""
        if (m, station) in self._dep:
            return self._dep[(m, station)] - self.scheduled(m, station, "departure")
        last = self._last.get(m)
        return 0.0 if last is None else last[2]

    def state_for(self, m: int, station: int) -> np.ndarray:
        """Staggered deviation state t(k) - T(k) [s] for the decision (service m, station j)."""
        n = self.line.n_stations
        x = np.zeros(n)
        n_trains = len(self.train_ids)
        for i in range(n):
            other = m + station - 1 - i
            if 0 <= other < n_trains:
                x[i] = self.delay_estimate(other, i)
        return x

    def _decide(self, train_id: str, station_idx: int) -> Tuple[int, int, np.ndarray]:
        """(m, j, u): the regulator's adjustments for the decision (train, station j)."""
        m = self._train(train_id)
        j = self._station(station_idx)
        return m, j, self.regulator.decide(self.state_for(m, j), 0)

    def adjustment(self, train_id: str, station_idx: int) -> float:
        """The regulator's u_j [s] for (train, station j) on the current state estimate.

        u_j is the adjustment of the run into j plus the dwell at j (Lin 2010a, eq. 5),
        unsaturated: the caller applies what is left of it.
        """
        _, j, u = self._decide(train_id, station_idx)
        return float(u[j])

    def running_target(self, train_id: str, station_idx: int) -> float:
        """Running-time target [s] of the run into station j >= 1: scheduled + saturated part.

        The running part of u_j (:func:`split_adjustment`), i.e. the
        ``target_running_time_s`` of :meth:`departure_command` without its dwell forecast.
        """
        _, j, u = self._decide(train_id, station_idx)
        if j < 1:
            raise ValueError("station 0 has no run into it")
        return float(self.line.run_s[j - 1]) + float(split_adjustment(self.line, u)[0][j])

    def departure_command(self, train_id: str, station_idx: int) -> DepartureCommand:
        """Regulated departure time, running-time and dwell targets for a train at a station."""
        m = self._train(train_id)
        j = self._station(station_idx)
        if (m, j) in self._dep:
            raise ValueError(f"train {train_id!r} already departed station {j}")
        last = self._last.get(m)
        if last is not None and last[0] > (j, 0):
            raise ValueError(f"train {train_id!r} is already past station {j}")
        line = self.line
        _, _, u = self._decide(train_id, j)
        du_run, du_dwell = split_adjustment(line, u)
        dr, dd = float(du_run[j]), float(du_dwell[j])
        run = float(line.run_s[j - 1]) + dr if j >= 1 else 0.0
        if (m, j) in self._arr:
            arrival = self._arr[(m, j)]
        elif j >= 1 and (m, j - 1) in self._dep:
            arrival = self._dep[(m, j - 1)] + run
        else:
            arrival = self.scheduled(m, j, "arrival") + self.delay_estimate(m, j)
        leader = m - 1
        if leader >= 0 and (leader, j) in self._dep:
            lead_dep = self._dep[(leader, j)]
            arrival = max(arrival, lead_dep + line.separation_min_s)
        elif leader >= 0:
            lead_dep = self.scheduled(leader, j, "departure") + self.delay_estimate(leader, j)
        else:
            lead_dep = self.scheduled(m, j, "departure") - self._h
        c = float(line.c()[j])
        gap = arrival - lead_dep + float(line.dwell_fixed_s[j]) + dd
        dwell = float(line.dwell_fixed_s[j]) + dd + max(c * gap / (1.0 - c), 0.0)
        dwell = max(dwell, float(line.dwell_fixed_min_s[j]))
        return DepartureCommand(train_id, j, arrival + dwell, run, dwell,
                                self.scheduled(m, j, "departure"), dr + dd)
