"""When a train's on-board ATO starts afresh: a new cab (ROS-free, one rule for every caller).

On a line run as a loop (a service day: :mod:`metro_atc.core.service.loop`), one train
runs trip after trip.  Its ATO is a new :class:`metro_atc.core.ato.onboard.OnboardAto`

- when the train comes into service (a pull-out from the depot): the ATO of a train that
  stood in the depot knows nothing of the run it starts;
- when the stop index of its state goes back (the loop closed at the terminus of its
  first station: the driver changed ends, the cab of the other end drives the next lap).

Both are read from the lockstep states alone, so the ROS-free day
(:class:`metro_atc.core.service.dayplant.DayPlant`) and the ``ato_controller`` node decide
the same instants: the train was not in the previous step's states (the plant asks only
trains in service for a command: every step, consecutive step indices) or its
``current_station`` is lower than in its last state.
"""

from __future__ import annotations

from typing import Optional


class CabWatch:
    """Per train: whether a state starts a new cab (see the module docstring)."""

    __slots__ = ("step", "station")

    def __init__(self) -> None:
        """No state seen yet (the first state starts a cab)."""
        self.step: Optional[int] = None
        self.station = -1

    def new_cab(self, step: int, station: int) -> bool:
        """Take the state of lockstep step ``step`` at stop index ``station``.

        True when it starts a new cab: the first state, a state that does not follow the
        last one (step index not the next: the train was out of service in between) or a
        stop index below the last one (a new lap of the loop).
        """
        k, j = int(step), int(station)
        fresh = self.step is None or k != self.step + 1 or j < self.station
        self.step, self.station = k, j
        return fresh


__all__ = ["CabWatch"]
