"""A lost ATO is a CBTC fault: the decision, ROS-free.

The line simulator asks this watchdog, at every step, which effort to apply to each train
in service.  A train whose ATO missed ``max_missed`` consecutive lockstep steps (no valid
command for the step) is declared lost: instead of the last command (which may be full
traction), it gets a full service brake to a stop (the ATP-commanded stop of a CBTC
train that lost its onboard ATO; the plant's ATP still supervises on top).  When a valid
command arrives again the ATO gets the train back.  Losses and hand-backs are returned as
events for the node to log, and counted.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from numpy.typing import NDArray

__all__ = ["AtoWatchdog", "WatchdogEvent", "STOP_EFFORT"]

STOP_EFFORT = -1.0
"""Effort applied to a train whose ATO is lost: full service brake [-]."""


@dataclasses.dataclass(frozen=True)
class WatchdogEvent:
    """A train's ATO declared lost (``lost``) or back (``back``) at a step."""

    train: int
    kind: str
    step: int
    missed: int
    """Consecutive missed steps at the event."""


class AtoWatchdog:
    """Missed-step counter per train and the effort override (see module docstring)."""

    def __init__(self, n_trains: int, max_missed: int) -> None:
        """``max_missed`` >= 1: consecutive missed steps after which the ATO is lost."""
        if max_missed < 1:
            raise ValueError(f"max_missed must be >= 1, got {max_missed}")
        self.max_missed = int(max_missed)
        self.missed = np.zeros(n_trains, dtype=np.int64)
        self.lost = np.zeros(n_trains, dtype=bool)
        self.losses = 0
        """Times a train's ATO was declared lost."""
        self.stop_steps = 0
        """Train-steps driven by the watchdog's stop command."""

    def apply(self, step: int, active: NDArray[np.bool_], received: NDArray[np.bool_],
              effort: NDArray[np.float64]) -> tuple[NDArray[np.float64], list[WatchdogEvent]]:
        """Efforts to apply at ``step`` and the events of this step.

        ``active``: trains that must send a command; ``received``: trains whose ATO sent a
        valid command for this step; ``effort``: the node's efforts (last command where
        none was received).  Inactive trains keep their effort and counters.
        """
        act = np.asarray(active, dtype=bool)
        got = np.asarray(received, dtype=bool) & act
        miss = act & ~got
        if not miss.any() and not self.lost.any():
            # every active ATO answered, none lost (nearly every step): their counters reset
            self.missed[got] = 0
            return np.array(effort, dtype=float, copy=True), []
        events: list[WatchdogEvent] = []
        for i in np.flatnonzero(got & self.lost):
            events.append(WatchdogEvent(int(i), "back", int(step), int(self.missed[i])))
        self.lost[got] = False
        self.missed[got] = 0
        self.missed[miss] += 1
        new = miss & ~self.lost & (self.missed >= self.max_missed)
        for i in np.flatnonzero(new):
            events.append(WatchdogEvent(int(i), "lost", int(step), int(self.missed[i])))
        self.losses += int(np.count_nonzero(new))
        self.lost |= new
        out = np.array(effort, dtype=float, copy=True)
        stop = self.lost & act
        out[stop] = STOP_EFFORT
        self.stop_steps += int(np.count_nonzero(stop))
        return out, events
