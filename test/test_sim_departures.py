"""The simulator's departure bookkeeping alone (no ROS): which dwelling trains the lockstep
waits for, and what a lockstep timeout gives up.

The plant is a stand-in with the fleet arrays :func:`dwelling_in_service` reads (``run``,
``dwelling``, ``cur_station``).
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from metro_atc.nodes.sim_departures import DepartureBook


def _line(run: list[bool], dwelling: list[bool], station: list[int]) -> SimpleNamespace:
    return SimpleNamespace(fleet=SimpleNamespace(
        run=np.array(run), dwelling=np.array(dwelling), cur_station=np.array(station)))


def test_pending_are_the_dwelling_trains_in_service_before_the_terminus() -> None:
    """Not running, not dwelling or at the terminus (station 3 of 4): not waited for."""
    book = DepartureBook(5, 4)
    line = _line([True, True, False, True, True], [True, False, True, True, True],
                 [1, 1, 1, 3, 0])
    assert book.pending(7, line) == [(0, 1), (4, 0)]


def test_a_received_departure_is_no_longer_pending_within_the_same_step() -> None:
    """The look is cached per step, but a departure received at that step ends the wait."""
    book = DepartureBook(2, 3)
    line = _line([True, True], [True, True], [0, 1])
    assert book.pending(3, line) == [(0, 0), (1, 1)]
    book.receive(1, 1, "atr")
    assert book.pending(3, line) == [(0, 0)]
    book.receive(1, 1, "dp")  # a repeat counts no second regulator decision
    assert book.regulators == {"atr": 1}
    assert book.received[1, 1] and not book.received[0, 0]


def test_the_dwelling_trains_are_looked_up_again_at_the_next_step() -> None:
    """Within a step the dwelling set is the step's; the next step sees the plant anew."""
    book = DepartureBook(2, 3)
    line = _line([True, True], [True, False], [0, 0])
    assert book.pending(1, line) == [(0, 0)]
    line.fleet.dwelling[1] = True
    assert book.pending(1, line) == [(0, 0)]  # the plant changes only in a step
    assert book.pending(2, line) == [(0, 0), (1, 0)]


def test_a_timeout_gives_up_the_pending_departures_and_counts_them() -> None:
    """Given up: counted as ATS timeouts, no longer pending, not received."""
    book = DepartureBook(3, 3)
    line = _line([True, True, True], [True, True, False], [0, 1, 0])
    assert book.give_up_pending(4, line) == [(0, 0), (1, 1)]
    assert book.ats_misses == 2
    assert book.pending(4, line) == []
    assert book.given_up[0, 0] and book.given_up[1, 1] and not book.received.any()
    assert book.give_up_pending(4, line) == [] and book.ats_misses == 2
