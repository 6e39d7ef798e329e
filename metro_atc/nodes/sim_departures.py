"""The line_simulator's departure bookkeeping (ROS-free): which dwelling trains wait for the ATS.

The lockstep waits, besides the ATOs' commands, for the ATS's departure command of every
train dwelling in service at a station before its terminus (:meth:`DepartureBook.pending`);
on a lockstep timeout those departures are given up (the timetable is used, counted as ATS
timeouts: :meth:`DepartureBook.give_up_pending`).  Steps are lockstep step indices; trains
and stations are indices into the scenario's lists.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from metro_atc.core.plant.views import dwelling_in_service


class DepartureBook:
    """Departure commands received or given up, per (train, station).

    ``n_trains``, ``n_stations``: the scenario's sizes.  :attr:`received`,
    :attr:`given_up`, :attr:`ats_misses` and :attr:`regulators` are part of a checkpoint
    (the node saves and restores them).
    """

    def __init__(self, n_trains: int, n_stations: int) -> None:
        """Nothing received, nothing given up."""
        self.received = np.zeros((n_trains, n_stations), dtype=bool)
        """A departure command of (train, station) was applied."""
        self.given_up = np.zeros((n_trains, n_stations), dtype=bool)
        """The lockstep stopped waiting for (train, station)'s command (timetable used)."""
        self.ats_misses = 0
        """Departure commands given up (lockstep timeouts on the ATS)."""
        self.regulators: dict[str, int] = {}
        """Regulator name -> departures it decided first (what ran, for the KPIs)."""
        self._last_station = n_stations - 1
        self._version = 0
        """Bumped whenever a departure is received or given up."""
        self._dwelling: tuple[int, list[tuple[int, int]]] = (-1, [])
        """(k, (train, station) of the trains dwelling in service at step k)."""
        self._pending: tuple[tuple[int, int], list[tuple[int, int]]] = ((-1, -1), [])
        """((k, _version), pending()) of the last look."""

    def receive(self, i: int, st: int, regulator: str) -> None:
        """Note the departure command of train ``i`` at station ``st`` (by ``regulator``)."""
        if not self.received[i, st]:
            self.regulators[regulator] = self.regulators.get(regulator, 0) + 1
        self.received[i, st] = True
        self._version += 1

    def pending(self, k: int, line: Any) -> list[tuple[int, int]]:
        """(train, station) pairs dwelling at step ``k`` without a departure command yet.

        ``line``: the plant at step ``k`` (:func:`dwelling_in_service`); computed once per
        step and change of the book (cached: the lockstep asks at every wake).
        """
        key = (k, self._version)
        if self._pending[0] == key:
            return self._pending[1]
        ck, dwell = self._dwelling
        if ck != k:  # mode, service and station change only in a step
            dwell = dwelling_in_service(line)
            self._dwelling = (k, dwell)
        last = self._last_station
        received, given_up = self.received, self.given_up
        out = []
        for i, j in dwell:
            if 0 <= j < last and not received[i, j] and not given_up[i, j]:
                out.append((int(i), j))
        self._pending = (key, out)
        return out

    def give_up_pending(self, k: int, line: Any) -> list[tuple[int, int]]:
        """Give up the departures :meth:`pending` at step ``k``; return them (ATS timeouts)."""
        out = self.pending(k, line)
        for i, j in out:
            self.given_up[i, j] = True
            self._version += 1
            self.ats_misses += 1
        return out
