"""The two-track line unfolded into one loop: the path a circulating train runs (ROS-free, SI).

A train of a two-direction day runs one path coordinate ``s`` [m] along the unfolded loop:

    up track, first station (terminus A) -> last station (terminus B): s = c - c_0
    terminus B: arrival route, reversal berth, departure route (tail track), or the
        platform itself (scissors: arrival, reversal and departure at one stop)
    down track, last station -> first: s = D + (c_{N-1} - c), grade sign reversed
    terminus A: as B; the loop closes at the departure stop of A (s = P = s of stop 0)

The loop is a one-way :class:`metro_atc.core.line.scenario.Scenario` (its stops are the
platforms of both directions and the reversal berths), so the plant, its ATP grids and the
ATO run it unchanged; the last stop lies at the period ``P`` and is the first stop again
(the plant wraps the coordinate by ``-P`` while the train stands there:
:attr:`metro_atc.core.plant.stations.Stations.wrap_m`).  Speed limits and curves are
those of the chainage on both tracks (limits and curves per track equal); a route's
``speed_limit_mps`` applies from its entry over its points and into its berth, not over the
open line a departure route leads to.

The unfolded turnback puts a route's sections end to end over the route's length in the
layout (:meth:`metro_atc.core.service.interlocking.Layout.route_length_m`); routes of one
stage that are parallel alternatives (sidings ``sd1``/``sd2``, platforms ``p1``/``p2``)
share the interval of the longest of them; a route's destination section keeps its length
at the end of the interval and the sections before it share the rest in proportion to their
lengths.  The reversal is a standstill: the train's length is not
carried across it (the front after the reversal stands where the front was).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, Dict, List, Optional, Sequence, Tuple

from metro_atc.core.ato.control_kernel import AUTH_MARGIN as AUTHORITY_MARGIN_M
from metro_atc.core.line.rolling_stock import KMH, train_params_for
from metro_atc.core.line.scenario import (CurveSpec, GradientSpec, PeriodSpec, Scenario,
                                          ScenarioError, SpeedLimitSpec, StationSpec, TsrSpec,
                                          validate_scenario)

from .interlocking import Layout, Route

ENTRY_M = 400.0
"""Open line ahead of a terminus's first route: the approach before its entry signal [m]."""


class LoopError(ValueError):
    """A loop cannot be built from the line and the terminus layouts (one line)."""


@dataclass(frozen=True)
class LoopStop:
    """One stop of the loop.

    ``station``: index of the line's station (-1 at a reversal berth); ``direction``: ``up``
    or ``down`` of the platform (None at a reversal berth); ``terminus``: 0 (A) / 1 (B) or
    None; ``role``: ``platform``, ``arrival`` (terminus arrival platform), ``reversal``
    (berth in a siding), ``departure`` (terminus departure platform), ``turn`` (scissors:
    arrival, reversal and departure at the platform) or ``wrap`` (the last stop: stop 0
    again).
    """

    name: str
    s_m: float
    station: int
    direction: Optional[str]
    terminus: Optional[int]
    role: str


@dataclass(frozen=True)
class RouteSpan:
    """A route's interval on the loop [m] and its sections' intervals, in travel order."""

    route: Route
    entry_m: float
    exit_m: float
    sections: Tuple[Tuple[str, float, float], ...]


@dataclass(frozen=True)
class TerminusPath:
    """One terminus on the loop: layout, stops and the spans of its routes."""

    index: int
    station: int
    layout: Layout
    spans: Dict[str, RouteSpan]
    arrival_stop: int
    departure_stop: int
    reversal_stop: int
    """Loop stop of the reversal berth (the arrival stop at a scissors terminus)."""

    def itinerary_spans(self, itinerary: Sequence[str]) -> List[RouteSpan]:
        """Spans of an itinerary's routes in order."""
        return [self.spans[r] for r in itinerary]


@dataclass(frozen=True)
class LoopLine:
    """The unfolded loop of a line with two terminus layouts (see module docstring)."""

    scenario: Scenario
    stops: Tuple[LoopStop, ...]
    period_m: float
    termini: Tuple[TerminusPath, TerminusPath]
    up_stop: Tuple[int, ...]
    """Loop stop of each station's up platform."""
    down_stop: Tuple[int, ...]
    """Loop stop of each station's down platform."""

    def stop_s(self, k: int) -> float:
        """Path coordinate of loop stop ``k`` [m]."""
        return self.stops[k].s_m


def _spans(lay: Layout, start_m: float) -> Tuple[Dict[str, RouteSpan], List[float]]:
    """Route spans by stage from ``start_m`` (the arrival route's exit signal).

    Returns the spans and the exit positions of the stages (stage 0: the arrival platform).
    """
    stages = sorted({r.stage for r in lay.routes})
    length = {st: max(lay.route_length_m(r.name) for r in lay.routes if r.stage == st)
              for st in stages}
    spans: Dict[str, RouteSpan] = {}
    exits: List[float] = []
    pos = start_m - length[stages[0]]
    for st in stages:
        a, b = pos, pos + length[st]
        for r in lay.routes:
            if r.stage != st:
                continue
            # the destination keeps its length (a train stands in it alone); the
            # sections before it share the rest of the span in proportion
            last = min(lay.section_length_m[r.sections[-1]], b - a)
            rest = sum(lay.section_length_m[s] for s in r.sections[:-1])
            secs, x = [], a
            for s in r.sections[:-1]:
                w = (b - a - last) * lay.section_length_m[s] / rest
                secs.append((s, x, x + w))
                x += w
            secs.append((r.sections[-1], x, b))
            spans[r.name] = RouteSpan(r, a, b, tuple(secs))
        exits.append(b)
        pos = b
    return spans, exits


def build_loop(scn: Scenario, layouts: Tuple[Layout, Layout], name: str = "",
               tsrs: Sequence[Any] = (), track_limits: Sequence[Any] = (),
               track_curves: Sequence[Any] = ()) -> LoopLine:
    """The loop of ``scn``'s line with ``layouts`` (terminus A = first station, B = last).

    ``tsrs``: temporary speed restrictions per running track (objects with ``track`` up /
    down, ``start_m`` < ``end_m`` in the line's chainage, ``limit_kmh``, ``from_s``,
    ``to_s``: :class:`metro_atc.core.service.day.TrackTsr`), placed on the loop where that
    track runs (the up track from A, the down track read backwards); a zone not inside the
    line between its terminus stations is a LoopError.  The one-way scenario's own TSRs
    and incidents are not carried over (they have no track).  ``track_limits``: permanent
    limits of one track lower than the line's there (``track``, ``start_m``, ``end_m``,
    ``limit_kmh``: :class:`metro_atc.core.service.day.TrackLimit`), placed the same way.
    ``track_curves``: the curves of a track (``track``, ``start_m``, ``end_m``,
    ``radius_m``: :class:`metro_atc.core.service.day.TrackCurve`); a track with any
    replaces the line's curves on that track (the other keeps the line's).

    The loop scenario keeps the rolling stock, signalling, passengers' rates, disturbances
    and sensors of ``scn`` and has one train (the day's plant runs a loop per train);
    ``boarding_pph`` of the down platforms is that of the up platform of the same station
    (an estimate: scale per direction with :func:`with_periods`).  LoopError (one line)
    when a layout has more than one departure route stage or the stations are too close.
    """
    st = scn.line.stations
    n = len(st)
    c = [s.position_m for s in st]
    c0, cn = c[0], c[-1]
    length = cn - c0
    for lay in layouts:
        stages = sorted({r.stage for r in lay.routes})
        if len(stages) < 2:
            raise LoopError(f"layout {lay.name}: a turnback needs an arrival and a departure "
                            f"stage")
    stops: List[LoopStop] = []
    up_stop = [0] * n
    down_stop = [0] * n
    for j in range(n - 1):
        stops.append(LoopStop(f"{st[j].name} (up)", c[j] - c0, j, "up",
                              0 if j == 0 else None, "departure" if j == 0 else "platform"))
        up_stop[j] = len(stops) - 1
    spans_b, ex_b = _spans(layouts[1], length)
    b_path = _turn(stops, st[n - 1].name, n - 1, 1, layouts[1], ex_b, "up", "down")
    up_stop[n - 1] = b_path[0]
    down_stop[n - 1] = b_path[2]
    d0 = ex_b[-2]  # the down departure platform of B
    for j in range(n - 2, 0, -1):
        stops.append(LoopStop(f"{st[j].name} (down)", d0 + (cn - c[j]), j, "down", None,
                              "platform"))
        down_stop[j] = len(stops) - 1
    spans_a, ex_a = _spans(layouts[0], d0 + length)
    a_path = _turn(stops, st[0].name, 0, 0, layouts[0], ex_a, "down", "up")
    down_stop[0] = a_path[0]
    period = ex_a[-2]
    # the last stop is stop 0 again (wrap); the departure route of A runs from s = 0
    if stops[-1].s_m != period:  # pragma: no cover - _turn ends at the departure stage
        raise LoopError("internal: loop does not close")
    stops[-1] = dataclasses.replace(stops[-1], role="wrap", name=stops[-1].name + " again")
    wrap_shift = -period
    spans_a = {k: _shift(v, wrap_shift) if v.route.stage == max(
        r.stage for r in layouts[0].routes) else v for k, v in spans_a.items()}
    last_k = len(stops) - 1
    a_stops = [0 if k == last_k else k for k in a_path]  # the wrap stop is stop 0 again
    term = (TerminusPath(0, 0, layouts[0], spans_a, a_stops[0], 0, a_stops[1]),
            TerminusPath(1, n - 1, layouts[1], spans_b, b_path[0], b_path[2], b_path[1]))
    for k in range(1, len(stops)):
        if stops[k].s_m <= stops[k - 1].s_m + 10.0:
            raise LoopError(f"loop stops {stops[k - 1].name!r} and {stops[k].name!r} are "
                            f"{stops[k].s_m - stops[k - 1].s_m:.0f} m apart (need > 10 m)")
    check_crossovers(scn, stops, term, period)
    loop_scn = _scenario(scn, stops, c0, cn, d0, length, term, name or f"{scn.name}_loop",
                         [loop_tsr(z, c0, cn, d0) for z in tsrs],
                         [track_interval(z, c0, cn, d0) + (float(z.limit_kmh),)
                          for z in track_limits],
                         {tr: [track_interval(z, c0, cn, d0) + (float(z.radius_m),)
                               for z in track_curves if z.track == tr]
                          for tr in ("up", "down") if any(z.track == tr for z in track_curves)})
    return LoopLine(loop_scn, tuple(stops), period, term, tuple(up_stop), tuple(down_stop))


def crossover_sections(lay: Layout) -> Tuple[str, ...]:
    """Sections of ``lay`` with points or crossings: on a route, not a berth, entry or exit.

    Scissors: ``x1``, ``xd``, ``x2``; tail track: ``ta``, ``td``.
    """
    on_routes = [s for r in lay.routes for s in r.sections]
    skip = lay.berths | {lay.entry_section, lay.exit_section}
    return tuple(dict.fromkeys(s for s in on_routes if s not in skip))


def check_crossovers(scn: Scenario, stops: Sequence[LoopStop],
                     term: Sequence[TerminusPath], period_m: float) -> None:
    """LoopError (one line) when a terminus's crossover lies on another station's platform.

    A platform is where a train stands at its stop: from the stop point back over the train
    length [m].  Every crossover section of a terminus (:func:`crossover_sections`) as the
    loop places it must lie clear of every platform of the other stations (a scissors in
    front of a terminus needs an interstation longer than the crossover plus the train).
    The terminus's entry signal must stand at least the ATO's authority margin
    (:data:`metro_atc.core.ato.control_kernel.AUTH_MARGIN`, 10 m) beyond the stop point of
    the platform before it: a train standing there with the signal at danger has its
    authority end at the signal, and the ATO aims that margin short of its authority (it
    would rest short of the stop point and never call there, nor ask for the route).
    """
    length = float(train_params_for(scn).length_m)
    st = scn.line.stations
    for tp in term:
        xs = set(crossover_sections(tp.layout))
        code = st[tp.station].code or st[tp.station].name
        for sp in tp.spans.values():
            for sec, a, b in sp.sections:
                if sec not in xs:
                    continue
                for stop in stops:
                    if stop.station < 0 or stop.station == tp.station:
                        continue
                    for d in (0.0, period_m, -period_m):
                        lo, hi = stop.s_m - length + d, stop.s_m + d
                        if not (b > lo and a < hi):
                            continue
                        gap = abs(st[stop.station].position_m - st[tp.station].position_m)
                        need = gap + min(b - lo, hi - a)
                        raise LoopError(
                            f"terminus {code} ({tp.layout.name}): crossover section {sec} "
                            f"({a:.0f}-{b:.0f} m on the loop) overlaps the platform of "
                            f"{stop.name} ({lo:.0f}-{hi:.0f} m, a {length:.0f} m train); the "
                            f"interstation {st[stop.station].code or stop.name}-{code} must be "
                            f">= {need:.0f} m, it is {gap:.0f} m")
        # the entry signal: a train stopping at the platform before it has its authority
        # end there and berths only with the ATO's margin of room beyond its stop point
        entry = min(sp.entry_m for sp in tp.spans.values() if sp.route.stage == 0)
        for stop in stops:
            if stop.station < 0 or stop.station == tp.station:
                continue
            for d in (0.0, period_m, -period_m):
                room = entry - (stop.s_m + d)
                if not 0.0 <= room < AUTHORITY_MARGIN_M:
                    continue
                gap = abs(st[stop.station].position_m - st[tp.station].position_m)
                raise LoopError(
                    f"terminus {code} ({tp.layout.name}): its entry signal ({entry:.0f} m on "
                    f"the loop) stands {room:.1f} m beyond the stop point of {stop.name}, "
                    f"the ATO berths there with >= {AUTHORITY_MARGIN_M:.0f} m of authority "
                    f"beyond it; the interstation {st[stop.station].code or stop.name}-{code} "
                    f"must be >= {gap + AUTHORITY_MARGIN_M - room:.0f} m, it is {gap:.0f} m")


def _shift(sp: RouteSpan, d: float) -> RouteSpan:
    return RouteSpan(sp.route, sp.entry_m + d, sp.exit_m + d,
                     tuple((s, a + d, b + d) for s, a, b in sp.sections))


def _turn(stops: List[LoopStop], name: str, station: int, term: int, lay: Layout,
          exits: List[float], d_in: str, d_out: str) -> Tuple[int, int, int]:
    """Append a terminus's stops (exit of every stage but the departure's).

    Returns the loop stops (arrival, reversal, departure).
    """
    k_arr = len(stops)
    if len(exits) == 2:  # scissors: arrival, reversal and departure at one platform
        stops.append(LoopStop(f"{name} ({d_in}/{d_out})", exits[0], station, d_out, term,
                              "turn"))
        return k_arr, k_arr, k_arr
    stops.append(LoopStop(f"{name} ({d_in})", exits[0], station, d_in, term, "arrival"))
    for m, x in enumerate(exits[1:-2]):
        stops.append(LoopStop(f"{name} (reversal {m + 1})", x, -1, None, term, "reversal"))
    stops.append(LoopStop(f"{name} ({d_out})", exits[-2], station, d_out, term, "departure"))
    return k_arr, k_arr + 1, len(stops) - 1


def _steps_mirror(items: Sequence[Tuple[float, float]], c0: float, cn: float,
                  ) -> List[Tuple[float, float]]:
    """A step function of chainage (start, value) over [c0, cn] as seen in the down direction.

    Returns (offset from the down start, value) pairs: the down track starts at c_{N-1} and
    runs towards c_0.
    """
    starts = [a for a, _ in items]
    vals = [v for _, v in items]
    out: List[Tuple[float, float]] = []
    # value at chainage c is that of the last start <= c; going down from cn, a value
    # holds from the next start above (or cn) to its own start
    bounds = sorted({min(max(a, c0), cn) for a in starts} | {c0, cn})
    for hi, lo in zip(reversed(bounds[1:]), reversed(bounds[:-1])):
        mid = 0.5 * (lo + hi)
        k = max((i for i, a in enumerate(starts) if a <= mid), default=0)
        out.append((cn - hi, vals[k]))
    return out


def track_interval(z: Any, c0: float, cn: float, d0: float) -> Tuple[float, float]:
    """A zone of one track on the loop: up at ``x - c0``, down at ``d0 + cn - x`` [m].

    ``z``: ``track`` (up / down), ``start_m`` < ``end_m`` in the line's chainage; ``c0``,
    ``cn``: chainage of the first and last station [m]; ``d0``: loop position of the down
    track's start (its departure platform at the last station) [m].  LoopError when the
    zone is not inside [c0, cn] or the track is neither up nor down.
    """
    a, b = float(z.start_m), float(z.end_m)
    if z.track not in ("up", "down") or not c0 <= a < b <= cn:
        raise LoopError(f"zone on track {z.track!r} at {a:g}..{b:g} m: needs track up or "
                        f"down and c0 <= start < end <= cn, the line's stations lie at "
                        f"{c0:g}..{cn:g} m")
    return (a - c0, b - c0) if z.track == "up" else (d0 + cn - b, d0 + cn - a)


def loop_tsr(z: Any, c0: float, cn: float, d0: float) -> TsrSpec:
    """A track's TSR ``z`` on the loop (:func:`track_interval`)."""
    lo, hi = track_interval(z, c0, cn, d0)
    return TsrSpec(start_m=lo, end_m=hi, limit_kmh=float(z.limit_kmh),
                   from_s=float(z.from_s), to_s=float(z.to_s))


def _scenario(scn: Scenario, stops: List[LoopStop], c0: float, cn: float, d0: float,
              length: float, term: Tuple[TerminusPath, TerminusPath], name: str,
              tsrs: Sequence[TsrSpec] = (),
              track_caps: Sequence[Tuple[float, float, float]] = (),
              track_curves: Optional[Dict[str, List[Tuple[float, float, float]]]] = None
              ) -> Scenario:
    """The one-way scenario of the loop (see :func:`build_loop`).

    ``track_caps``: (start, end [m on the loop], limit [km/h]) lowering the line's limits;
    ``track_curves[track]``: (start, end [m on the loop], radius [m]) replacing the line's
    curves on that track.
    """
    own = track_curves or {}
    ln = scn.line
    line_kmh = ln.line_speed_kmh
    lim_up = [(x.start_m, x.limit_kmh) for x in ln.speed_limits] or [(c0, line_kmh)]
    lim_up = [(a, v) for a, v in lim_up]
    if lim_up[0][0] > c0:
        lim_up.insert(0, (c0 - 1.0, line_kmh))
    grd = [(x.start_m, x.grade_permille) for x in ln.gradients] or [(c0, 0.0)]
    if grd[0][0] > c0:
        grd.insert(0, (c0 - 1.0, 0.0))
    # the loop's step functions: (s, value), later entries override from their start
    lim: List[Tuple[float, float]] = [(-1e6, line_kmh)]
    lim += [(max(a, c0) - c0, v) for a, v in lim_up if a < cn]
    gr: List[Tuple[float, float]] = [(-1e6, 0.0)]
    gr += [(max(a, c0) - c0, v) for a, v in grd if a < cn]
    gr.append((length, 0.0))
    lim.append((length, line_kmh))
    for off, v in _steps_mirror(lim_up, c0, cn):
        lim.append((d0 + off, v))
    for off, v in _steps_mirror(grd, c0, cn):
        gr.append((d0 + off, -v))
    gr.append((d0 + length, 0.0))
    lim.append((d0 + length, line_kmh))
    # route speed limits over their spans (crossovers, turnback moves)
    caps: List[Tuple[float, float, float]] = list(track_caps)
    for tp in term:
        lay = tp.layout
        pts = set(lay.point_section.values())
        for sp in tp.spans.values():
            # over the points and into a berth; not over the open line a route leads to
            ends = [b for s, _, b in sp.sections if s in pts or (
                s == sp.route.destination and s != lay.exit_section)]
            if ends:
                caps.append((sp.entry_m, max(ends), sp.route.speed_limit_mps / KMH))
    period = stops[-1].s_m
    limits = _apply_caps(lim, caps, period)
    curves = []
    for cv in ln.curves:
        a, b = max(cv.start_m, c0), min(cv.end_m, cn)
        if b > a:
            if "up" not in own:
                curves.append(CurveSpec(start_m=a - c0, end_m=b - c0, radius_m=cv.radius_m))
            if "down" not in own:
                curves.append(CurveSpec(start_m=d0 + cn - b, end_m=d0 + cn - a,
                                        radius_m=cv.radius_m))
    for zones in own.values():
        curves += [CurveSpec(start_m=a, end_m=b, radius_m=r) for a, b, r in zones]
    curves.sort(key=lambda x: x.start_m)
    stations = [StationSpec(name=x.name, position_m=x.s_m, code=_code(scn, x))
                for x in stops]
    pph = [_boarding(scn, x, p.boarding_pph) for p in scn.timetable.periods for x in stops]
    m = len(stops)
    periods = [dataclasses.replace(p, boarding_pph=pph[k * m:(k + 1) * m])
               for k, p in enumerate(scn.timetable.periods)]
    af = [_alight(scn, x) for x in stops]
    out = dataclasses.replace(
        scn, name=name,
        trains=dataclasses.replace(scn.trains, count=1),
        line=dataclasses.replace(
            ln, stations=stations, speed_limits=_steps(limits, SpeedLimitSpec, "limit_kmh"),
            gradients=_steps(_merge(gr), GradientSpec, "grade_permille"), curves=curves,
            temporary_speed_limits=list(tsrs)),
        timetable=dataclasses.replace(scn.timetable, periods=periods, first_departure_s=0.0),
        passengers=dataclasses.replace(scn.passengers, alight_fraction=af),
        incidents=[], faults=[], sensors=dataclasses.replace(scn.sensors, trains=[]))
    try:
        return validate_scenario(out, name)
    except ScenarioError as exc:
        raise LoopError(str(exc)) from None


def _merge(items: List[Tuple[float, float]]) -> List[Tuple[float, float]]:
    """Sort a step function's (start, value) pairs; a later duplicate start wins."""
    d: Dict[float, float] = {}
    for a, v in items:
        d[round(a, 6)] = v
    out: List[Tuple[float, float]] = []
    for a in sorted(d):
        if not out or out[-1][1] != d[a]:
            out.append((a, d[a]))
    return out


def _value_at(steps: List[Tuple[float, float]], x: float) -> float:
    v = steps[0][1]
    for a, w in steps:
        if a <= x:
            v = w
        else:
            break
    return v


def _apply_caps(lim: List[Tuple[float, float]], caps: List[Tuple[float, float, float]],
                period: float) -> List[Tuple[float, float]]:
    """The limit step function with the route caps (min over each span) applied."""
    base = _merge(lim)
    pts = sorted({a for a, _ in base} | {a for a, _, _ in caps} | {b for _, b, _ in caps})
    out: List[Tuple[float, float]] = []
    for x in pts:
        v = _value_at(base, x)
        for a, b, cap in caps:
            if a <= x < b:
                v = min(v, cap)
        out.append((x, v))
    return _merge(out)


def _steps(items: List[Tuple[float, float]], cls: type, key: str) -> list:  # type: ignore
    return [cls(**{"start_m": a, key: v}) for a, v in _merge(items)]


def _code(scn: Scenario, x: LoopStop) -> str:
    base = scn.line.stations[x.station].code if x.station >= 0 else ""
    tag = {"up": "u", "down": "d", None: "r"}[x.direction]
    if x.role == "wrap":
        tag += "w"
    return f"{base or 'T'}{tag}" if x.station >= 0 else f"T{x.terminus}r"


def _boarding(scn: Scenario, x: LoopStop, pph: Sequence[float]) -> float:
    """Boarding demand of a loop stop [pax/h] (0 at berths, arrival platforms, the wrap).

    The down platform of station j has the up demand of the mirrored station N-1-j (the
    scenario's profile seen from the other terminus; an estimate).
    """
    if x.station < 0 or x.role in ("arrival", "wrap"):
        return 0.0
    n = len(pph)
    return float(pph[x.station] if x.direction == "up" else pph[n - 1 - x.station])


def _alight(scn: Scenario, x: LoopStop) -> float:
    """Share alighting at a loop stop: everyone at a terminus, mirrored on the down track."""
    af = scn.passengers.alight_fraction
    n = len(af)
    if x.station < 0:
        return 0.0
    if x.terminus is not None and x.role != "departure" or x.role == "wrap":
        return 1.0
    if x.role == "departure":
        return 1.0 if x.terminus == 0 else 0.0
    return float(af[x.station] if x.direction == "up" else af[n - 1 - x.station])


Period = Tuple[float, float, float, float, str]
"""A day period for :func:`with_periods`: start [s], headway [s], up and down flow, name."""


def with_periods(scn: Scenario, loop: LoopLine, periods: Sequence[Period]) -> Scenario:
    """The loop scenario with day periods (start [s], headway [s], up and down flow factors).

    Boarding at the up / down platforms is the base scenario's first-period profile times
    the direction's factor.
    """
    base = loop.scenario.timetable.periods[0].boarding_pph
    out = []
    for start, hw, fu, fd, label in periods:
        pph = [float(b) * (fu if x.direction == "up" else fd)
               for b, x in zip(base, loop.stops)]
        out.append(PeriodSpec(start_s=float(start), headway_s=float(hw), boarding_pph=pph,
                              name=label))
    return validate_scenario(dataclasses.replace(
        loop.scenario, timetable=dataclasses.replace(loop.scenario.timetable,
                                                     periods=out)), loop.scenario.name)


__all__ = ["ENTRY_M", "LoopError", "LoopLine", "LoopStop", "RouteSpan", "TerminusPath",
           "build_loop", "check_crossovers", "crossover_sections", "with_periods"]
