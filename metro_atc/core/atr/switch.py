"""A dispatcher's regulator switch in the ATS: deterministic, from a stated time (ROS-free).

The dispatcher's desk (:mod:`metro_atc.core.dispatcher_commands`) validates a switch,
applies it at a lockstep step and records it with the time it takes effect, ``from_s`` =
the step's time + ``LEAD_S``.  :class:`RegulatorSwitch` wraps the ATS's
:class:`~metro_atc.core.atr.dispatch.AtsDispatcher`: every event at or after a switch's
``from_s`` is decided by the new regulator, which is built then and given the events
before (so its state is the one it would have had from the start).  A run and its replay
with the same recorded switches make the same decisions.  A switch that reaches the ATS
after an event at or past its ``from_s`` was decided is counted in ``late`` (it then
takes effect at once: the only case a replay could decide differently).
"""

from __future__ import annotations

import bisect
from typing import Any, Callable, Optional

from metro_atc.core.atr.dispatch import AtsDispatcher, Dispatch


class RegulatorSwitch:
    """The ATS's dispatcher with the dispatcher's switches of regulator (module docstring).

    ``dispatcher``: the ATS's dispatcher at the start; ``regulator`` its name; ``build``:
    (regulator, weights_file) -> a new dispatcher (raises ValueError / FileNotFoundError
    when it cannot be built).
    """

    def __init__(self, dispatcher: AtsDispatcher, regulator: str,
                 build: Callable[[str, str], AtsDispatcher]) -> None:
        """No switch yet."""
        self.dispatcher = dispatcher
        self.regulator = regulator
        self.build = build
        self.history: list[tuple[str, int, str, float]] = []
        """Every event the dispatcher took: (train, station, kind, time [s])."""
        self.pending: list[tuple[float, int, str, str]] = []
        """Switches to come: (from_s [s], sequence, regulator, weights_file), in time order."""
        self.seen: set[int] = set()
        self.last_t = -float("inf")
        self.switched: list[tuple[float, str]] = []
        """(time [s], regulator) of every switch made."""
        self.late = 0
        self.failed: list[str] = []
        """Why switches could not be made (the old regulator kept)."""

    def announce(self, sequence: int, from_s: float, regulator: str,
                 weights_file: str = "") -> bool:
        """Take an applied switch once (by its sequence); True when new."""
        if sequence in self.seen:
            return False
        self.seen.add(sequence)
        if from_s <= self.last_t:
            self.late += 1
        bisect.insort(self.pending, (float(from_s), int(sequence), regulator, weights_file))
        return True

    def on_event(self, train_id: str, station: int, kind: str, t_s: float
                 ) -> Optional[Dispatch]:
        """:meth:`AtsDispatcher.on_event` by the regulator in force at ``t_s``."""
        self.due(float(t_s))
        d = self.dispatcher.on_event(train_id, station, kind, t_s)
        self.history.append((train_id, int(station), kind, float(t_s)))
        self.last_t = max(self.last_t, float(t_s))
        return d

    def due(self, t_s: float) -> None:
        """Make the switches whose time has come (before the events of ``t_s``)."""
        while self.pending and self.pending[0][0] <= t_s:
            from_s, _, name, weights = self.pending.pop(0)
            try:
                new = self.build(name, weights)
                for ev in self.history:
                    new.on_event(*ev)
            except (ValueError, FileNotFoundError, OSError, RuntimeError) as exc:
                self.failed.append(f"regulator '{name}' at {from_s:.2f} s: "
                                   + " ".join(str(exc).split()))
                continue
            self.dispatcher = new
            self.regulator = name
            self.switched.append((from_s, name))

    def __getattr__(self, name: str) -> Any:
        """The wrapped dispatcher's other attributes (``tt``, ``initial``, ...)."""
        if name == "dispatcher":
            raise AttributeError(name)
        return getattr(self.dispatcher, name)
