"""Train circulation: minimum fleet (brute force, closed form), depots, delay propagation."""

from __future__ import annotations

import math
from typing import Dict, List, Optional, Set

import numpy as np
import pytest

from metro_atc.core.service.circulation import (CirculationError, Trip, build_circulation,
                                                closed_form_fleet, propagate_block,
                                                propagate_delay)


def _brute_fleet(trips: List[Trip], tb: Dict[str, float], depots: Set[str]) -> Optional[int]:
    """Fewest trains over every assignment of trips to trains (exhaustive search)."""
    order = sorted(trips, key=lambda t: t.departure_s)
    best: List[Optional[int]] = [None]

    def rec(i: int, trains: List[Trip]) -> None:  # trains: last trip of each train
        if best[0] is not None and len(trains) >= best[0]:
            return
        if i == len(order):
            if all(t.destination in depots for t in trains):
                best[0] = len(trains)
            return
        tr = order[i]
        for k, last in enumerate(trains):
            if last.destination == tr.origin and tr.departure_s - last.arrival_s >= \
                    tb[tr.origin]:
                rec(i + 1, trains[:k] + [tr] + trains[k + 1:])
        if tr.origin in depots:
            rec(i + 1, trains + [tr])

    rec(0, [])
    return best[0]


def _random_trips(rng: np.random.Generator, n: int) -> List[Trip]:
    out = []
    for i in range(n):
        a = "A" if rng.random() < 0.5 else "B"
        d = float(rng.integers(0, 40)) * 30.0
        out.append(Trip(f"t{i}", a, "B" if a == "A" else "A", d,
                        d + float(rng.integers(4, 12)) * 30.0))
    return out


def test_minimum_fleet_equals_brute_force() -> None:
    """On 150 random small instances the sweep uses exactly the fewest trains possible."""
    rng = np.random.default_rng(7)
    tb = {"A": 60.0, "B": 90.0}
    checked = 0
    for _ in range(150):
        trips = _random_trips(rng, int(rng.integers(2, 8)))
        for depots in ({"A", "B"}, {"A"}):
            bf = _brute_fleet(trips, tb, depots)
            for prefer in ("longest_wait", "shortest_wait"):
                try:
                    c = build_circulation(trips, tb, depots, prefer=prefer)
                except CirculationError:
                    assert bf is None
                    continue
                assert bf is not None and c.fleet == bf
                served = sorted(t.trip_id for b in c.blocks for t in b.trips)
                assert served == sorted(t.trip_id for t in trips)
                for term, lay in c.layovers():
                    assert lay >= tb[term]
                checked += 1
    assert checked > 150


@pytest.mark.parametrize("h,r,ta,tb_", [(105.0, 2400.0, 210.0, 210.0),
                                        (300.0, 1000.0, 120.0, 400.0),
                                        (120.0, 777.0, 95.0, 95.0)])
def test_uniform_timetable_closed_form(h: float, r: float, ta: float, tb_: float) -> None:
    """Uniform service fed from one depot: fleet = ceil((2 r + t_A + t_B) / H)."""
    n = 80
    trips = [Trip(f"u{k}", "A", "B", k * h, k * h + r) for k in range(n)]
    trips += [Trip(f"d{k}", "B", "A", k * h + r + tb_, k * h + 2 * r + tb_)
              for k in range(n)]
    c = build_circulation(trips, {"A": ta, "B": tb_}, {"A"})
    assert c.fleet == closed_form_fleet(2 * r + ta + tb_, h)
    assert c.pull_outs == {"A": c.fleet, "B": 0}


def test_terminus_without_depot_is_refused_in_one_line() -> None:
    """A departure no arrival can feed at a depot-less terminus is named with its instant."""
    trips = [Trip("u0", "A", "B", 0.0, 600.0), Trip("d0", "B", "A", 650.0, 1200.0)]
    with pytest.raises(CirculationError) as ei:
        build_circulation(trips, {"A": 60.0, "B": 120.0}, {"A"})
    msg = str(ei.value)
    assert "terminus B" in msg and "00:10:50" in msg and "00:12:00" in msg and "\n" not in msg
    assert build_circulation(trips, {"A": 60.0, "B": 50.0}, {"A"}).fleet == 1
    with pytest.raises(CirculationError, match="ends its day there"):
        build_circulation(trips[:1], {"A": 60.0, "B": 50.0}, {"A"})
    with pytest.raises(CirculationError, match="no minimum turnback"):
        build_circulation(trips, {"A": 60.0}, None)


def test_withdrawal_keeps_the_fleet() -> None:
    """Long layovers at a depot terminus become pull-in + pull-out; the fleet is unchanged."""
    trips = [Trip("u0", "A", "B", 0.0, 600.0), Trip("d0", "B", "A", 700.0, 1300.0),
             Trip("u1", "A", "B", 9000.0, 9600.0), Trip("d1", "B", "A", 9700.0, 10300.0)]
    tb = {"A": 60.0, "B": 60.0}
    c0 = build_circulation(trips, tb)
    c1 = build_circulation(trips, tb, stable_after_s=1800.0)
    assert c0.fleet == c1.fleet == 1
    assert len(c0.blocks) == 1 and len(c1.blocks) == 2
    assert c1.pull_ins["A"] == 2 and c1.pull_outs["A"] == 2
    assert c1.in_service(5000.0) == 0 and c0.in_service(5000.0) == 1


def test_delay_propagation() -> None:
    """The turnback buffer absorbs a late arrival first; Lin 2010a's 104 s fits in 210 s."""
    assert propagate_delay(104.0, 210.0 + 90.0, 90.0) == 0.0
    assert propagate_delay(250.0, 300.0, 90.0) == pytest.approx(40.0)
    with pytest.raises(ValueError):
        propagate_delay(10.0, 50.0, 90.0)
    trips = [Trip("u0", "A", "B", 0.0, 600.0), Trip("d0", "B", "A", 700.0, 1300.0),
             Trip("u1", "A", "B", 1400.0, 2000.0)]
    c = build_circulation(trips, {"A": 60.0, "B": 60.0})
    # 150 s late at B: 40 s buffer there -> 110 s late; 40 s buffer at A -> 70 s
    assert propagate_block(c.blocks[0], {"A": 60.0, "B": 60.0}, 0, 150.0) == \
        pytest.approx([110.0, 70.0])


def test_closed_form_edges() -> None:
    """ceil on exact multiples does not round up; bad headways are refused."""
    assert closed_form_fleet(1050.0, 105.0) == 10
    assert closed_form_fleet(1050.1, 105.0) == 11
    with pytest.raises(ValueError):
        closed_form_fleet(100.0, 0.0)
    assert math.isfinite(closed_form_fleet(0.0, 1.0))


def test_prefer_picks_the_ready_train() -> None:
    """FIFO takes the train ready longest, LIFO the one ready last; same fleet either way."""
    trips = [Trip("b0", "B", "A", 0.0, 40.0), Trip("b1", "B", "A", 100.0, 140.0),
             Trip("a0", "A", "B", 3000.0, 3100.0)]
    tb = {"A": 60.0, "B": 60.0}
    fifo = build_circulation(trips, tb, prefer="longest_wait").trains()
    lifo = build_circulation(trips, tb, prefer="shortest_wait").trains()
    assert [t.trip_id for t in fifo["train_01"]] == ["b0", "a0"]
    assert [t.trip_id for t in lifo["train_02"]] == ["b1", "a0"]
    assert len(fifo) == len(lifo) == 2
    with pytest.raises(CirculationError, match="prefer"):
        build_circulation(trips, tb, prefer="random")


def test_after_a_peak_the_turning_trains_keep_turning() -> None:
    """The surplus of a peak goes to the depot once; the trains left keep turning.

    Both directions every 120 s for an hour, then every 600 s (running 1 500 s, minimum
    turnback 300 s, a train standing over 800 s is withdrawn: one headway more than the
    minimum).  FIFO over every ready
    train gave each off-peak departure to the train that had stood longest, a withdrawn
    one, so every train of the surplus took its turn: one trip, back to the depot.  Off
    the peak a train now comes out of the depot only when no turning train is ready: the
    off-peak trips are run by the off-peak fleet, trip after trip.
    """
    trips: List[Trip] = []
    for direction, (a, b) in enumerate((("A", "B"), ("B", "A"))):
        t, n = 0.0, 0
        while t < 4 * 3600.0:
            trips.append(Trip(f"{a}{n}", a, b, t, t + 1500.0))
            t += 120.0 if t < 3600.0 else 600.0
            n += 1
    circ = build_circulation(trips, {"A": 300.0, "B": 300.0}, None, 800.0, "longest_wait")
    late = [b for b in circ.blocks if b.trips[0].departure_s > 3600.0 + 1800.0]
    assert not late  # after the transition no block starts: nobody is pulled out again
    off_peak = 2 * sum(1 for t in trips if t.origin == "A" and t.departure_s > 5400.0)
    runners = {b.train for b in circ.blocks
               if any(t.departure_s > 5400.0 for t in b.trips)}
    # the off-peak fleet: a cycle of 2 x (1 500 + 300) s at 600 s headway
    assert len(runners) == math.ceil(2 * 1800.0 / 600.0)
    assert off_peak > 4 * len(runners)
