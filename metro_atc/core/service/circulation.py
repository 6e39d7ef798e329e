"""Train circulation with the minimum fleet over a two-direction trip list (ROS-free).

A trip runs from one terminus to the other (departure / arrival instants [s]).  A train that
arrives at terminus s at instant a can run a trip departing from s at d when
d - a >= turnback_s[s] (the minimum turnback time of that terminus, e.g. from
:meth:`metro_atc.core.service.interlocking.Layout.min_turnback_s` plus the platform dwell).
A train may start the day with a pull-out from a depot and end it with a pull-in at a
terminus that has a depot connection.

Algorithm (deficit sweep, one terminus at a time): at every terminus, events are sorted by
time (a train becoming ready at the same instant as a departure serves it); each departure
takes a ready train (the one ready longest, FIFO, or the one ready last, LIFO) or, if none,
a pull-out from the depot.
Trains left at a terminus at the end of the day pull in.  The fleet is the number of
pull-outs.  This is minimal: at every terminus the pull-outs equal
max_t (departures in [0, t] - trains ready in [0, t]), the deficit function, which no
assignment can undercut (each departure needs a train and trains only come from arrivals or
the depot); the tests check it against brute force on small instances and against the
closed form ceil(cycle / headway) on uniform timetables.

A terminus without a depot connection must be fed by arrivals alone; a trip list that needs
a pull-out or a pull-in there is refused with one line naming the terminus and instant.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass, field
from typing import Dict, List, Mapping, Sequence, Set, Tuple


class CirculationError(ValueError):
    """The trip list cannot be served (one line naming the terminus, instant and cause).

    ``instant_s``: the instant [s] of the trip that cannot be served, when there is one.
    """

    def __init__(self, message: str, instant_s: float | None = None) -> None:
        """Keep the one-line ``message`` and the ``instant_s`` [s] it is about."""
        super().__init__(message)
        self.instant_s = instant_s


@dataclass(frozen=True)
class Trip:
    """One trip: ``origin`` -> ``destination`` termini (station codes), instants [s]."""

    trip_id: str
    origin: str
    destination: str
    departure_s: float
    arrival_s: float


@dataclass(frozen=True)
class Block:
    """One spell of a train out of the depot: pull-out terminus, trips, pull-in terminus."""

    train: str
    trips: Tuple[Trip, ...]

    @property
    def pull_out(self) -> str:
        """Terminus where the train enters service from the depot."""
        return self.trips[0].origin

    @property
    def pull_in(self) -> str:
        """Terminus where the train leaves service to the depot."""
        return self.trips[-1].destination


@dataclass(frozen=True)
class Circulation:
    """In-service spells (blocks) of the fleet; per-terminus pull-outs / pull-ins.

    A train (``Block.train``) has one block per spell out of the depot; ``fleet`` counts
    trains, not blocks.
    """

    blocks: Tuple[Block, ...]
    pull_outs: Dict[str, int] = field(default_factory=dict)
    pull_ins: Dict[str, int] = field(default_factory=dict)

    @property
    def fleet(self) -> int:
        """Number of trains used."""
        return len({b.train for b in self.blocks})

    def in_service(self, t_s: float, depot_lead_s: float = 0.0) -> int:
        """Trains out of the depot at instant ``t_s`` [s] (from pull-out - lead to pull-in)."""
        return sum(1 for b in self.blocks
                   if b.trips[0].departure_s - depot_lead_s <= t_s <= b.trips[-1].arrival_s)

    def layovers(self) -> List[Tuple[str, float]]:
        """(terminus, layover [s]) of every turnback: next departure - arrival."""
        return [(a.destination, b.departure_s - a.arrival_s)
                for blk in self.blocks for a, b in zip(blk.trips, blk.trips[1:])]

    def trains(self) -> Dict[str, List[Trip]]:
        """Trips of every train in order, over all its blocks."""
        out: Dict[str, List[Trip]] = {}
        for b in self.blocks:
            out.setdefault(b.train, []).extend(b.trips)
        return out


def _fmt(t: float) -> str:
    t = int(round(t))
    return f"{t // 3600:02d}:{t % 3600 // 60:02d}:{t % 60:02d}"


def build_circulation(trips: Sequence[Trip], turnback_s: Mapping[str, float],
                      depots: Set[str] | None = None,
                      stable_after_s: float = math.inf,
                      prefer: str = "longest_wait") -> Circulation:
    """Minimum-fleet circulation (see the module docstring); one-line CirculationError.

    ``turnback_s[s]``: minimum turnback time at terminus s [s]; ``depots``: termini with a
    depot connection (None: every terminus); ``stable_after_s`` [s]: a train waiting longer
    than this at a terminus with a depot is withdrawn to the depot and pulled out again for
    its next trip (the depot withdrawal after a peak); the fleet is unchanged by it.
    ``prefer``: which ready train a departure takes, ``"longest_wait"`` (FIFO among the
    trains standing no longer than ``stable_after_s``, the largest turnback buffer; a
    withdrawn train only when none of those is ready) or ``"shortest_wait"`` (LIFO: surplus
    trains stand long enough to be withdrawn).  The fleet does not depend on it (deficit
    argument).
    """
    if prefer not in ("longest_wait", "shortest_wait"):
        raise CirculationError(f"prefer must be longest_wait or shortest_wait, got {prefer!r}")
    termini = {t.origin for t in trips} | {t.destination for t in trips}
    for s in sorted(termini):
        if s not in turnback_s:
            raise CirculationError(f"terminus {s}: no minimum turnback time given")
        if not (turnback_s[s] >= 0.0 and math.isfinite(turnback_s[s])):
            raise CirculationError(f"terminus {s}: turnback time must be finite and >= 0 s")
    for t in trips:
        if not (math.isfinite(t.departure_s) and t.arrival_s > t.departure_s):
            raise CirculationError(f"trip {t.trip_id}: arrival must follow departure")
        if t.origin == t.destination:
            raise CirculationError(f"trip {t.trip_id}: origin and destination are the same")
    dep_ok = termini if depots is None else set(depots)
    order = sorted(trips, key=lambda t: (t.departure_s, t.trip_id))
    # per terminus a sorted list of (ready instant, seq, train index)
    ready: Dict[str, List[Tuple[float, int, int]]] = {s: [] for s in termini}
    chains: List[List[Trip]] = []
    pull_outs: Dict[str, int] = {s: 0 for s in termini}
    seq = 0
    # arrivals become ready in time order; process all trips by departure
    for trip in order:
        heap = ready[trip.origin]
        i = bisect.bisect_right(heap, (trip.departure_s, math.inf, 0))
        if i > 0:
            if prefer == "longest_wait":
                # FIFO among the trains still turning (standing no longer than
                # stable_after_s); a train standing longer is in the depot and comes out
                # only when no turning train is ready (else every train of a surplus
                # after a peak would take its turn in the depot, one trip each)
                lo = bisect.bisect_left(heap, (trip.departure_s - stable_after_s
                                               + turnback_s[trip.origin], -1, -1), 0, i)
                _, _, k = heap.pop(lo if lo < i else 0)
            else:
                _, _, k = heap.pop(i - 1)
        else:
            if trip.origin not in dep_ok:
                need = (f"next train ready at {_fmt(heap[0][0])}" if heap
                        else "no train arrives before it")
                raise CirculationError(
                    f"terminus {trip.origin} has no depot connection: departure "
                    f"{trip.trip_id} at {_fmt(trip.departure_s)} has no train ({need}, "
                    f"turnback {turnback_s[trip.origin]:.0f} s)", trip.departure_s)
            k = len(chains)
            chains.append([])
            pull_outs[trip.origin] += 1
        chains[k].append(trip)
        bisect.insort(ready[trip.destination],
                      (trip.arrival_s + turnback_s[trip.destination], seq, k))
        seq += 1
    pull_ins: Dict[str, int] = {s: 0 for s in termini}
    for s, heap in ready.items():
        for _, _, k in heap:
            if s not in dep_ok:
                raise CirculationError(f"terminus {s} has no depot connection: train of trip "
                                       f"{chains[k][-1].trip_id} ends its day there",
                                       chains[k][-1].arrival_s)
            pull_ins[s] += 1
    blocks: List[Block] = []
    for i, c in enumerate(chains):
        name = f"train_{i + 1:02d}"
        start = 0
        for j in range(1, len(c) + 1):
            if j == len(c) or (c[j - 1].destination in dep_ok
                               and c[j].departure_s - c[j - 1].arrival_s > stable_after_s):
                blocks.append(Block(name, tuple(c[start:j])))
                if j < len(c):  # withdrawn to the depot, back out for c[j]
                    pull_ins[c[j - 1].destination] += 1
                    pull_outs[c[j].origin] += 1
                start = j
    return Circulation(tuple(blocks), pull_outs, pull_ins)


def closed_form_fleet(cycle_s: float, headway_s: float) -> int:
    """Trains needed on a uniform service: ceil(cycle time / headway) [-].

    ``cycle_s``: both running times plus both minimum turnbacks [s]; ``headway_s`` [s].
    """
    if not (headway_s > 0.0 and cycle_s >= 0.0):
        raise ValueError("headway must be > 0 s and cycle time >= 0 s")
    return int(math.ceil(cycle_s / headway_s - 1e-9))


def propagate_delay(arrival_delay_s: float, layover_s: float, min_turnback_s: float) -> float:
    """Departure delay [s] of the next trip after an arrival ``arrival_delay_s`` late.

    The turnback buffer ``layover_s - min_turnback_s`` [s] absorbs the delay first:
    next delay = max(0, arrival delay - buffer).  Lin 2010a (Experiment 2) keeps 210 s of
    turnback buffer at the 105 s peak headway, so a terminal delay up to 210 s is absorbed.
    """
    buffer = layover_s - min_turnback_s
    if buffer < 0.0:
        raise ValueError("layover shorter than the minimum turnback time")
    return max(0.0, arrival_delay_s - buffer)


def propagate_block(block: Block, turnback_s: Mapping[str, float], trip_index: int,
                    arrival_delay_s: float) -> List[float]:
    """Departure delays [s] of the later trips of ``block`` after a late arrival.

    Trip ``trip_index`` arrives ``arrival_delay_s`` late; trips run to time (no recovery in
    running), so each later trip departs late by what its turnback buffer did not absorb.
    """
    out: List[float] = []
    d = arrival_delay_s
    trips = block.trips
    for a, b in zip(trips[trip_index:], trips[trip_index + 1:]):
        d = propagate_delay(d, b.departure_s - a.arrival_s, turnback_s[a.destination])
        out.append(d)
    return out
