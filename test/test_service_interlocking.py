"""Terminus interlocking: derived conflicts, safe route setting, no deadlock, no starvation."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import List, Optional

import numpy as np
import pytest

from metro_atc.core.service.interlocking import (KMH, Interlocking, InterlockingError, Layout,
                                                 Route, brute_force_conflict, check_safe,
                                                 routes_conflict, scissors_terminus,
                                                 tail_track_terminus)

LAYOUTS = [tail_track_terminus(1), tail_track_terminus(3), scissors_terminus()]
CROSSOVERS = {"ta", "td", "x1", "x2", "xd"}


def test_conflicts_are_derived_from_the_track() -> None:
    """The conflict relation equals the geometric one; the scissors allows parallel moves."""
    for lay in LAYOUTS:
        for (a, b), c in lay.conflict_matrix().items():
            assert c == brute_force_conflict(lay.route(a), lay.route(b), lay), (lay.name, a, b)
            assert c == lay.conflict_matrix()[(b, a)]
    sc = scissors_terminus()
    assert not routes_conflict(sc.route("arr_p1"), sc.route("p2_dep"))
    assert routes_conflict(sc.route("arr_p2"), sc.route("p1_dep"))  # the diamond
    assert routes_conflict(sc.route("arr_p1"), sc.route("arr_p2"))
    tt = tail_track_terminus(2)
    # the arrival overlap protects the tail: no move into a siding while it is locked
    assert routes_conflict(tt.route("arr_pa"), tt.route("pa_sd2"))
    assert not routes_conflict(tt.route("arr_pa"), tt.route("sd1_pd"))


def test_point_position_conflict_without_shared_section() -> None:
    """Two routes needing one point in two positions conflict even with disjoint sections."""
    a = Route("a", "s1", "s2", ("x",), (("p", "normal"),))
    b = Route("b", "s3", "s4", ("y",), (("p", "reverse"),))
    assert routes_conflict(a, b)
    assert not routes_conflict(a, Route("c", "s5", "s6", ("y",), (("p", "normal"),)))


def test_layout_validation_is_one_line() -> None:
    """Bad layouts are refused with one line naming the problem."""
    with pytest.raises(InterlockingError, match="at least one siding"):
        tail_track_terminus(0)
    bad = Layout("bad", {"a": 1.0, "b": 1.0, "dep": 1.0}, {},
                 (Route("r0", "s0", "s1", ("a", "b"), stage=0),
                  Route("r1", "s1", "s2", ("a", "dep"), stage=1)),
                 (("r0", "r1"),), 10.0, ("b",), "dep", "a")
    with pytest.raises(InterlockingError, match="runs through berth") as ei:
        Layout("bad2", bad.section_length_m, {}, bad.routes + (
            Route("r2", "s2", "s3", ("b", "a"), stage=0),), bad.itineraries, 10.0, ("b",),
            "dep", "a").validate()
    assert "\n" not in str(ei.value)
    with pytest.raises(InterlockingError, match="speed limit"):
        scissors_terminus(crossover_speed_mps=0.0)
    il = Interlocking(scissors_terminus())
    for bad_call in (lambda: il.occupy("zz"), lambda: il.clear("zz"),
                     lambda: il.request("t", "nowhere"), lambda: il.arrived("arr_p1")):
        with pytest.raises(InterlockingError):
            bad_call()
    il.request("t", "arr_p1")
    with pytest.raises(InterlockingError, match="pending"):
        il.request("t", "arr_p2")
    assert il.occupied == set() and not il.lock and len(il.queue) == 1


def test_min_turnback_and_movement_authority() -> None:
    """Turnback lower bound = routes at their limits + reversal; MA ends at the exit signal."""
    sc = scissors_terminus(reversal_s=90.0, crossover_speed_mps=30.0 * KMH)
    assert sc.min_turnback_s(1) == pytest.approx(90.0 + (60.0 * 3 + 140.0) / (30.0 * KMH))
    il = Interlocking(sc)
    assert il.movement_authority("arr_p2") is None
    il.request("t1", "arr_p2")
    assert il.process() == [("t1", "arr_p2")]
    assert il.movement_authority("arr_p2") == ("s_p2", pytest.approx(320.0))


def test_standing_train_on_crossover_blocks_only_routes_through_it() -> None:
    """A train stalled on the diamond: nothing is set through it, the parallel move is."""
    il = Interlocking(scissors_terminus())
    il.occupy("p1")
    il.request("a", "p1_dep")
    assert il.process() == [("a", "p1_dep")]
    il.occupy("x1")
    il.clear("p1")
    il.occupy("xd")
    il.clear("x1")           # train a stands on the diamond, x1 released behind it
    assert "x1" not in il.lock and il.lock["xd"] == "p1_dep"
    il.request("b", "arr_p2")
    il.request("c", "arr_p1")
    for _ in range(5):
        granted = il.process()
        assert ("b", "arr_p2") not in granted
    assert "arr_p1" in il.set_routes  # only x1/p1: runs parallel behind the standing train
    il.occupy("x2")
    il.clear("xd")
    il.occupy("dep")
    il.clear("x2")
    il.clear("dep")
    assert "p1_dep" not in il.set_routes
    assert il.process() == []          # arr_p2 still conflicts with arr_p1 (x1)


@dataclass
class _Train:
    name: str
    itinerary: tuple
    stage: int = 0
    sections: List[str] = field(default_factory=list)
    route: Optional[str] = None
    todo: List[str] = field(default_factory=list)
    wait: int = 0
    requested: bool = False
    done: bool = False


def _no_live_conflict(il: Interlocking) -> None:
    """Brute force: routes that conflict on the track never both hold the shared part."""
    lay = il.layout
    rs = il.locked_routes()
    for i, a in enumerate(rs):
        for b in rs[i + 1:]:
            if not brute_force_conflict(a, b, lay):
                continue
            held_a = {s for s in a.locked_sections if il.lock.get(s) == a.name}
            held_b = {s for s in b.locked_sections if il.lock.get(s) == b.name}
            assert not (held_a & set(b.locked_sections) & held_b), (a.name, b.name)
            for p, pos in a.points:
                if lay.point_section[p] in held_a and lay.point_section[p] in held_b:
                    raise AssertionError(f"{a.name}/{b.name} both hold point {p}")


def _simulate(lay: Layout, n_trains: int, seed: int, stall_p: float, max_steps: int = 40000
              ) -> dict:
    """Random occupy/clear/request sequences; safety checked after every event."""
    rng = np.random.default_rng(seed)
    il = Interlocking(lay)
    trains: List[_Train] = []
    spawned = 0
    granted_log = []
    stalls = 0
    for step in range(max_steps):
        if spawned < n_trains and lay.entry_section not in il.occupied and rng.random() < 0.3:
            t = _Train(f"t{spawned}", lay.itineraries[rng.integers(len(lay.itineraries))])
            t.sections = [lay.entry_section]
            il.occupy(lay.entry_section)
            trains.append(t)
            spawned += 1
        for t in trains:
            if not t.done and t.route is None and not t.requested and t.wait == 0:
                il.request(t.name, t.itinerary[t.stage])
                t.requested = True
        occupied_before = set(il.occupied)
        for tr, rn in il.process():
            r = lay.route(rn)
            assert not (r.locked_sections & occupied_before), f"{rn} set over a train"
            t = next(x for x in trains if x.name == tr)
            t.route, t.todo, t.requested = rn, list(r.sections), False
            granted_log.append(rn)
        assert check_safe(il) is None, check_safe(il)
        _no_live_conflict(il)
        live = [t for t in trains if not t.done]
        if not live and spawned == n_trains:
            return {"steps": step, "granted": granted_log, "stalls": stalls, "il": il}
        rng.shuffle(live)
        for t in live[:2]:
            if t.wait > 0:
                t.wait -= 1
                continue
            if t.route is None:
                continue
            front = t.sections[-1]
            if front in CROSSOVERS and rng.random() < stall_p:
                t.wait = int(rng.integers(5, 40))  # standing still on the crossover
                stalls += 1
                continue
            if len(t.sections) == 2:
                il.clear(t.sections.pop(0))
            elif t.todo:
                nxt = t.todo.pop(0)
                assert il.lock.get(nxt) == t.route, f"{t.name} enters {nxt} without a route"
                il.occupy(nxt)
                t.sections.append(nxt)
            elif t.sections[-1] == lay.exit_section:
                il.clear(t.sections.pop())
                t.done, t.route = True, None
            else:
                il.arrived(t.route)
                t.route = None
                t.stage += 1
                t.wait = int(rng.integers(0, 6))  # dwell / reversal
            assert check_safe(il) is None, check_safe(il)
    pending = [(q.train, q.route.name) for q in il.queue]
    raise AssertionError(f"{lay.name}: not every train got through in {max_steps} steps "
                         f"(deadlock/starvation): queue {pending}")


@pytest.mark.parametrize("lay", LAYOUTS, ids=lambda x: x.name)
def test_random_sequences_are_safe_and_live(lay: Layout) -> None:
    """Random runs with stalls on crossovers: never two conflicting routes, everyone served."""
    stalls = 0
    for seed in range(12):
        out = _simulate(lay, n_trains=12, seed=seed, stall_p=0.15)
        stalls += out["stalls"]
        names = {r.name for r in lay.routes}
        assert set(out["granted"]) <= names
        assert len(out["granted"]) == 12 * len(lay.itineraries[0])
        assert not out["il"].lock and not out["il"].set_routes and not out["il"].queue
    assert stalls > 50  # trains did stand still on the crossovers


def test_naive_fifo_would_deadlock_where_ours_does_not() -> None:
    """The rule matters: plain FIFO with no-overtaking on conflicts deadlocks the tail track.

    A train at the arrival platform asks for the only siding, occupied by a train that asks
    to leave the siding next; the siding move shares the tail with nothing, but a strict
    FIFO that lets no conflicting later request pass an earlier one, counting an occupied
    route as waiting, blocks both.
    """
    lay = tail_track_terminus(1)
    il = Interlocking(lay)
    il.occupy("sd1")
    il.occupy("pa")
    il.request("A", "pa_sd1")   # first, but its siding is occupied
    il.request("B", "sd1_pd")   # second
    assert il.process() == [("B", "sd1_pd")]
    # a strict FIFO over all requests would hold B behind A when they conflict
    assert not routes_conflict(lay.route("pa_sd1"), lay.route("sd1_pd"))
    lay2 = tail_track_terminus(1)
    shared = Route("sd1_pd", "s_sd1_r", "s_pd", ("ta", "pd"), (("xa", "sd1"),), (), 10.0, 2)
    routes = tuple(shared if r.name == "sd1_pd" else r for r in lay2.routes)
    il2 = Interlocking(Layout("tail_shared", lay2.section_length_m, lay2.point_section, routes,
                              lay2.itineraries, lay2.reversal_s, lay2.reversal_sections,
                              "dep", "app"))
    il2.occupy("sd1")
    il2.occupy("pa")
    il2.request("A", "pa_sd1")
    il2.request("B", "sd1_pd")
    # the occupied request A is not ready and does not hold back B although they conflict
    assert il2.process() == [("B", "sd1_pd")]
