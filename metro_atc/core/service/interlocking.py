"""Route-based interlocking of a metro terminus (ROS-free, SI units).

Data model
----------
- A *section* is a track circuit / axle-counter section [length m]; it is occupied or clear.
- A *point* lies in one section and has named positions (``"normal"``, ``"reverse"`` or a
  siding name).  It can be moved only while its section is clear and not locked.
- A *route* runs from an entry signal to an exit signal over ``sections`` (in travel order,
  the section the train stands in before the entry signal excluded), needs ``points`` in
  given positions, and protects ``overlap`` sections beyond the exit signal.  It has a speed
  limit [m/s] (the crossover limit for a diverging route) and a ``stage`` (0 = arrival into
  the terminus, increasing along a train's turnback itinerary, last = departure).

Conflicts are *derived*, never listed: two routes conflict when their locked sections
(route sections plus overlap) intersect or when they need one point in different positions.

Rules
-----
1. Setting: a route is set (its sections and overlap locked, its points moved and locked)
   only when none of its sections or overlap is occupied or still locked by another route
   and none of its points is locked in another position; with sectional release (rule 2)
   a conflicting route may thus be set behind a train as soon as the shared part is free.
   A set route gives the train a movement authority up to its exit signal
   (:meth:`Interlocking.movement_authority`).
2. Sectional release: a locked section is released when the train has occupied it and
   cleared it again, and every earlier section of the route is already released.  When the
   train stops at the exit signal (:meth:`Interlocking.arrived`, the destination section
   occupied) the destination section and the overlap are released.
3. Request handling (deadlock- and starvation-free, see docs/service_day.md for the proof):
   a request is *ready* when none of the route's sections or overlap is occupied.  Ready
   requests are ordered by stage (higher stage first: trains deeper in the turnback, i.e.
   departures, before arrivals) and then first-in first-out.  Going down that order a ready
   request is granted when it conflicts neither with a locked route nor with a ready request
   earlier in the order that is still waiting.  A request whose route is occupied does not
   hold back anyone (it waits for the occupying train to move on).

Terminus layouts are built as data by :func:`tail_track_terminus` (reversal beyond the
platform in N sidings) and :func:`scissors_terminus` (reversal at the platform through a
scissors crossover in front of the station).  Each layout validates that no route runs
through a berth (a section where trains stop) other than its own destination, the property
the deadlock proof needs.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from typing import Dict, FrozenSet, List, Optional, Sequence, Set, Tuple

KMH = 1.0 / 3.6
"""One km/h in m/s."""


class InterlockingError(ValueError):
    """An invalid layout or an impossible operation (one line)."""


@dataclass(frozen=True)
class Route:
    """A route from ``entry_signal`` to ``exit_signal`` (see the module docstring).

    ``sections``: locked sections in travel order; ``points``: (point, position) pairs;
    ``overlap``: sections beyond the exit signal; ``speed_limit_mps`` [m/s];
    ``stage``: position in the turnback itinerary (0 = arrival).
    """

    name: str
    entry_signal: str
    exit_signal: str
    sections: Tuple[str, ...]
    points: Tuple[Tuple[str, str], ...] = ()
    overlap: Tuple[str, ...] = ()
    speed_limit_mps: float = 80.0 * KMH
    stage: int = 0

    @property
    def locked_sections(self) -> FrozenSet[str]:
        """Sections the route locks: its own plus its overlap."""
        return frozenset(self.sections) | frozenset(self.overlap)

    @property
    def destination(self) -> str:
        """The last section before the exit signal (where the train stops or runs out)."""
        return self.sections[-1]


def routes_conflict(a: Route, b: Route) -> bool:
    """Return True if routes ``a`` and ``b`` may not be locked together (shared section/point)."""
    if a.name == b.name:
        return True
    if a.locked_sections & b.locked_sections:
        return True
    pa = dict(a.points)
    return any(p in pa and pa[p] != pos for p, pos in b.points)


@dataclass(frozen=True)
class Layout:
    """A terminus as data: sections [m], points (point -> section), routes, itineraries.

    ``itineraries``: the alternative route sequences a train follows through the terminus
    (arrival ... departure); ``reversal_s``: driver change / reversal time [s] at the berth
    where the train changes direction; ``reversal_sections``: those berths; ``exit_section``:
    the departure line section (open line beyond, always drains).
    """

    name: str
    section_length_m: Dict[str, float]
    point_section: Dict[str, str]
    routes: Tuple[Route, ...]
    itineraries: Tuple[Tuple[str, ...], ...]
    reversal_s: float
    reversal_sections: Tuple[str, ...]
    exit_section: str
    entry_section: str

    def route(self, name: str) -> Route:
        """Return the route called ``name``; InterlockingError when unknown."""
        for r in self.routes:
            if r.name == name:
                return r
        raise InterlockingError(f"layout {self.name}: unknown route {name!r}")

    @property
    def berths(self) -> FrozenSet[str]:
        """Sections where trains stop: destinations of every route but the departures."""
        return frozenset(r.destination for r in self.routes if r.destination != self.exit_section)

    def conflict_matrix(self) -> Dict[Tuple[str, str], bool]:
        """Return the derived conflict relation over all pairs of route names."""
        return {(a.name, b.name): routes_conflict(a, b)
                for a, b in itertools.product(self.routes, self.routes)}

    def route_length_m(self, name: str) -> float:
        """Distance from the entry to the exit signal of route ``name`` [m]."""
        return sum(self.section_length_m[s] for s in self.route(name).sections)

    def min_turnback_s(self, itinerary: int = 0) -> float:
        """Lower bound of the turnback time [s] from the arrival signal to the departure.

        Every route of the itinerary except the departure is run at its speed limit (no
        acceleration, a lower bound), plus the reversal time; platform dwell is not included.
        """
        names = self.itineraries[itinerary]
        run = sum(self.route_length_m(n) / self.route(n).speed_limit_mps for n in names[:-1])
        return run + self.reversal_s

    def min_headway_s(self, turnback_s: float) -> float:
        """Shortest headway [s] at which the layout can turn trains taking ``turnback_s``.

        Every train in the turnback holds a berth (the one it stands in or the one its set
        route leads to) from its arrival to its departure, at least ``turnback_s`` [s], so
        at most ``len(berths)`` trains turn at once: H >= turnback_s / berths (Little's
        law).  A reversal berth holds its train for ``reversal_s`` at least: H >=
        reversal_s / reversal berths.  A lower bound: route runs are not counted.
        """
        return max(turnback_s / len(self.berths),
                   self.reversal_s / len(self.reversal_sections))

    def validate(self) -> None:
        """Raise InterlockingError (one line) unless the layout is consistent."""
        names = [r.name for r in self.routes]
        if len(set(names)) != len(names):
            raise InterlockingError(f"layout {self.name}: duplicate route names")
        for r in self.routes:
            for s in (*r.sections, *r.overlap):
                if s not in self.section_length_m:
                    raise InterlockingError(f"layout {self.name}: route {r.name} names unknown "
                                            f"section {s!r}")
            for p, _pos in r.points:
                if p not in self.point_section:
                    raise InterlockingError(f"layout {self.name}: route {r.name} names unknown "
                                            f"point {p!r}")
                if self.point_section[p] not in r.sections:
                    raise InterlockingError(f"layout {self.name}: route {r.name} sets point "
                                            f"{p} outside its sections")
            if not (r.speed_limit_mps > 0.0):
                raise InterlockingError(f"layout {self.name}: route {r.name} speed limit must "
                                        f"be > 0 m/s")
            through = set(r.sections[:-1]) & self.berths
            if through:
                raise InterlockingError(f"layout {self.name}: route {r.name} runs through "
                                        f"berth {sorted(through)[0]}")
        for it in self.itineraries:
            stages = [self.route(n).stage for n in it]
            if stages != sorted(stages) or len(set(stages)) != len(stages):
                raise InterlockingError(f"layout {self.name}: itinerary {it} stages must "
                                        f"increase")
            if self.route(it[-1]).destination != self.exit_section:
                raise InterlockingError(f"layout {self.name}: itinerary {it} must end on "
                                        f"the exit section")
        if not (self.reversal_s >= 0.0):
            raise InterlockingError(f"layout {self.name}: reversal time must be >= 0 s")


def tail_track_terminus(n_sidings: int = 2, reversal_s: float = 60.0,
                        crossover_speed_mps: float = 35.0 * KMH,
                        platform_m: float = 140.0, siding_m: float = 160.0,
                        tail_m: float = 80.0) -> Layout:
    """Reversal beyond the platform in a tail track / ``n_sidings`` sidings.

    Track 1 (arrival): ``app`` -> platform ``pa`` (passengers alight) -> tail ``ta`` ->
    siding ``sd_k`` (reversal) -> tail ``td`` -> platform ``pd`` (boarding) on track 2 ->
    ``dep`` (open line).  Point ``xa`` in ``ta`` and ``xd`` in ``td`` select the siding; the
    arrival into ``pa`` has ``ta`` as overlap.  Lengths [m], speeds [m/s], time [s].
    """
    if n_sidings < 1:
        raise InterlockingError("tail track terminus needs at least one siding")
    sec = {"app": 400.0, "pa": platform_m, "ta": tail_m, "td": tail_m, "pd": platform_m,
           "dep": 400.0}
    sidings = [f"sd{k + 1}" for k in range(n_sidings)]
    for s in sidings:
        sec[s] = siding_m
    routes: List[Route] = [Route("arr_pa", "s_app", "s_pa", ("pa",), (), ("ta",),
                                 60.0 * KMH, 0)]
    itin = []
    for s in sidings:
        routes.append(Route(f"pa_{s}", "s_pa", f"s_{s}", ("ta", s), (("xa", s),), (),
                            crossover_speed_mps, 1))
        routes.append(Route(f"{s}_pd", f"s_{s}_r", "s_pd", ("td", "pd"), (("xd", s),), (),
                            crossover_speed_mps, 2))
        itin.append(("arr_pa", f"pa_{s}", f"{s}_pd", "pd_dep"))
    routes.append(Route("pd_dep", "s_pd", "s_dep", ("dep",), (), (), 80.0 * KMH, 3))
    lay = Layout(f"tail_track_{n_sidings}", sec, {"xa": "ta", "xd": "td"}, tuple(routes),
                 tuple(itin), reversal_s, tuple(sidings), "dep", "app")
    lay.validate()
    return lay


def scissors_terminus(reversal_s: float = 90.0, crossover_speed_mps: float = 35.0 * KMH,
                      platform_m: float = 140.0, crossover_m: float = 60.0) -> Layout:
    """Reversal at the platform through a scissors crossover in front of the station.

    Arrival track 1 ``app`` -> scissors (``x1`` on track 1 with points ``p1a``/``p1b``,
    ``x2`` on track 2 with ``p2a``/``p2b``, diamond ``xd``) -> stub platforms ``p1`` (track 1)
    or ``p2`` (track 2); the train reverses at the platform and leaves on track 2 ``dep``.
    Straight routes run at the platform approach speed, diagonal routes at
    ``crossover_speed_mps``.  ``arr_p1`` and ``p2_dep`` are parallel moves (no conflict).
    """
    sec = {"app": 400.0, "x1": crossover_m, "x2": crossover_m, "xd": crossover_m,
           "p1": platform_m, "p2": platform_m, "dep": 400.0}
    pts = {"p1a": "x1", "p1b": "x1", "p2a": "x2", "p2b": "x2"}
    straight = 40.0 * KMH
    routes = (
        Route("arr_p1", "s_app", "s_p1", ("x1", "p1"), (("p1a", "normal"), ("p1b", "normal")),
              (), straight, 0),
        Route("arr_p2", "s_app", "s_p2", ("x1", "xd", "x2", "p2"),
              (("p1a", "reverse"), ("p2b", "reverse")), (), crossover_speed_mps, 0),
        Route("p1_dep", "s_p1", "s_dep", ("x1", "xd", "x2", "dep"),
              (("p1b", "reverse"), ("p2a", "reverse")), (), crossover_speed_mps, 1),
        Route("p2_dep", "s_p2", "s_dep", ("x2", "dep"), (("p2a", "normal"), ("p2b", "normal")),
              (), straight, 1),
    )
    lay = Layout("scissors", sec, pts, routes, (("arr_p1", "p1_dep"), ("arr_p2", "p2_dep")),
                 reversal_s, ("p1", "p2"), "dep", "app")
    lay.validate()
    return lay


@dataclass
class _Request:
    seq: int
    train: str
    route: Route


@dataclass
class Interlocking:
    """Mutable interlocking state of one :class:`Layout` (see the module rules)."""

    layout: Layout
    occupied: Set[str] = field(default_factory=set)
    lock: Dict[str, str] = field(default_factory=dict)        # section -> route name
    point_pos: Dict[str, str] = field(default_factory=dict)   # point -> position
    point_lock: Dict[str, str] = field(default_factory=dict)  # point -> route name
    set_routes: Dict[str, str] = field(default_factory=dict)  # route name -> train
    visited: Dict[str, Set[str]] = field(default_factory=dict)  # route -> sections entered
    queue: List[_Request] = field(default_factory=list)
    _seq: int = 0

    def request(self, train: str, route: str) -> None:
        """Queue ``train``'s request for ``route`` (FIFO sequence number assigned here)."""
        r = self.layout.route(route)
        if any(q.train == train for q in self.queue):
            raise InterlockingError(f"train {train} already has a pending route request")
        self.queue.append(_Request(self._seq, train, r))
        self._seq += 1

    def _ready(self, r: Route) -> bool:
        return not (r.locked_sections & self.occupied)

    def _free(self, r: Route) -> bool:
        """No section of ``r`` is still locked and no point it needs is locked elsewhere."""
        if any(s in self.lock for s in r.locked_sections):
            return False
        return all(p not in self.point_lock or self.point_pos.get(p) == pos
                   for p, pos in r.points)

    def process(self) -> List[Tuple[str, str]]:
        """Grant what rule 3 allows; returns the (train, route) pairs granted now."""
        ready = sorted((q for q in self.queue if self._ready(q.route)),
                       key=lambda q: (-q.route.stage, q.seq))
        waiting: List[Route] = []
        granted: List[Tuple[str, str]] = []
        for q in ready:
            if self._free(q.route) and not any(routes_conflict(q.route, w) for w in waiting):
                self._set(q.train, q.route)
                self.queue.remove(q)
                granted.append((q.train, q.route.name))
            else:
                waiting.append(q.route)
        return granted

    def _set(self, train: str, r: Route) -> None:
        for s in r.locked_sections:
            self.lock[s] = r.name
        for p, pos in r.points:
            self.point_pos[p] = pos
            self.point_lock[p] = r.name
        self.set_routes[r.name] = train
        self.visited[r.name] = set()

    def movement_authority(self, route: str) -> Optional[Tuple[str, float]]:
        """(exit signal, distance from the entry signal to it [m]) of a set route, else None."""
        if route not in self.set_routes:
            return None
        return self.layout.route(route).exit_signal, self.layout.route_length_m(route)

    def occupy(self, section: str) -> None:
        """Report that a train entered ``section`` (track circuit occupied)."""
        if section not in self.layout.section_length_m:
            raise InterlockingError(f"unknown section {section!r}")
        self.occupied.add(section)
        owner = self.lock.get(section)
        if owner is not None and owner in self.visited:
            self.visited[owner].add(section)

    def clear(self, section: str) -> None:
        """Report that a train left ``section``; sectional release behind it (rule 2)."""
        if section not in self.layout.section_length_m:
            raise InterlockingError(f"unknown section {section!r}")
        self.occupied.discard(section)
        for name in list(self.set_routes):
            r = self.layout.route(name)
            for s in r.sections:
                if self.lock.get(s) != name:
                    continue  # already released
                if s in self.visited[name] and s not in self.occupied:
                    self._release_section(name, s)
                else:
                    break
            self._maybe_done(name)

    def arrived(self, route: str) -> None:
        """Report the train of ``route`` standing at its exit signal: release dest. + overlap."""
        r = self.layout.route(route)
        if route not in self.set_routes or r.destination not in self.occupied:
            raise InterlockingError(f"route {route}: no train standing at its exit signal")
        for s in (*r.sections, *r.overlap):
            if self.lock.get(s) == route:
                self._release_section(route, s)
        self._maybe_done(route)

    def _release_section(self, route: str, s: str) -> None:
        del self.lock[s]
        for p, sec in self.layout.point_section.items():
            if sec == s and self.point_lock.get(p) == route:
                del self.point_lock[p]

    def _maybe_done(self, route: str) -> None:
        r = self.layout.route(route)
        if all(self.lock.get(s) != route for s in r.sections):
            for s in r.overlap:  # a run-through route frees its overlap with its last section
                if self.lock.get(s) == route:
                    self._release_section(route, s)
            del self.set_routes[route]
            del self.visited[route]

    def locked_routes(self) -> List[Route]:
        """Routes currently set (some of their sections still locked)."""
        return [self.layout.route(n) for n in self.set_routes]


def check_safe(il: Interlocking) -> Optional[str]:
    """Brute-force safety check of an interlocking state; None when safe, else the reason.

    Independent of the setting logic: two set routes holding one section, a point lying in
    a section a set route still holds but not in the position that route needs, a point
    locked in another position than its route needs, or a locked section owned by a route
    that does not contain it.
    """
    rs = il.locked_routes()
    live = {r.name: {s for s in r.locked_sections if il.lock.get(s) == r.name} for r in rs}
    for a, b in itertools.combinations(rs, 2):
        both = live[a.name] & live[b.name]
        if both:
            return f"{a.name} and {b.name} both lock {sorted(both)}"
    for r in rs:
        for p, pos in r.points:
            if il.layout.point_section[p] in live[r.name] and il.point_pos.get(p) != pos:
                return f"point {p} not in the position route {r.name} needs"
    for s, owner in il.lock.items():
        if s not in il.layout.route(owner).locked_sections:
            return f"section {s} locked by {owner} which does not use it"
    for p, owner in il.point_lock.items():
        want = dict(il.layout.route(owner).points)[p]
        if il.point_pos.get(p) != want:
            return f"point {p} locked by {owner} in the wrong position"
    return None


def brute_force_conflict(a: Route, b: Route, layout: Layout) -> bool:
    """Conflict from the track geometry alone: any shared section (points included)."""
    def footprint(r: Route) -> Set[str]:
        return set(r.sections) | set(r.overlap) | {layout.point_section[p] for p, _ in r.points}
    return a.name == b.name or bool(footprint(a) & footprint(b))


def all_routes(layouts: Sequence[Layout]) -> List[Route]:
    """Every route of ``layouts`` (convenience for tests and documentation)."""
    return [r for lay in layouts for r in lay.routes]
