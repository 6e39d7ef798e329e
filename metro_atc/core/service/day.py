"""The day of a metro line: TSK periods, both directions, fleet and depot (ROS-free).

Lin 2010a (eq. 7-10) splits the operating day into L periods [z_{n-1}, z_n), each with
headway H_n and hourly passenger flows p_{j,n}; here a period also has a flow factor per
direction.  From a period table (:func:`load_day`, YAML) and the line's traffic model
(:class:`metro_atc.core.atr.blue_line.LineData`) this module builds:

- the departures of both directions from their termini.  Transition rule: with a transition
  window W (``transition_s``) the headway is H(z) = H_n inside period n and, within W/2 of a
  boundary z_n, interpolates linearly from H_n to H_{n+1} across [z_n - W/2, z_n + W/2];
  departures follow z_{k+1} = z_k + H(z_k).  Consecutive headways therefore never jump by
  more than |H_{n+1} - H_n| * max(H) / W.  With W = 0 the rule is the crisp membership of
  Lin 2010a, eq. 8 and the instants are those of
  :func:`metro_atc.core.atr.tsk.dispatch_instants` (called, not re-implemented);
- trip times per period from the scheduled offsets of the traffic model
  (:func:`metro_atc.core.atr.traffic.schedule_offsets`, Lin 2010a, eq. 5/10);
- the fleet needed per period, closed form ceil(cycle / H_n)
  (:func:`metro_atc.core.service.circulation.closed_form_fleet`) and the actual
  circulation with depot pull-outs / pull-ins
  (:func:`metro_atc.core.service.circulation.build_circulation`);
- validation: :class:`DayError`, one line naming the period and the minimum fleet or time
  needed (fleet too small, turnback shorter than the terminus layout needs, a terminus the
  timetable cannot feed, a depot at a station that does not exist or is not a terminus).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any, Dict, Iterator, List, Sequence, Tuple

import numpy as np

from metro_atc.core.atr.blue_line import LineData, Period, taipei_blue
from metro_atc.core.atr.traffic import schedule_offsets
from metro_atc.core.atr.tsk import dispatch_instants
from metro_atc.core.safe_yaml import YamlLimitError, load_yaml_file, one_line, short_repr
from metro_atc.core.service.circulation import (Circulation, CirculationError, Trip,
                                                build_circulation, closed_form_fleet)
from metro_atc.core.service.interlocking import KMH, Layout, scissors_terminus, \
    tail_track_terminus

LIN2010A_PEAK_HEADWAY_S = 105.0
"""Peak headway of the Taipei Blue line [s] (Lin 2010a, Experiment 2)."""
LIN2010A_TURNBACK_BUFFER_S = 210.0
"""Minimum turnback buffer at the peak headway [s] (Lin 2010a, Experiment 2)."""


HEADWAY_RANGE_S = (60.0, 3600.0)
"""Headways a period table may give [s] (shortest, longest)."""


class DayError(ValueError):
    """A day that cannot be run (one line naming the period and what is needed)."""


@dataclass(frozen=True)
class DayPeriod:
    """One period of the day (Lin 2010a, eq. 7-8).

    ``start_s``/``end_s`` [s after midnight], headway ``headway_s`` [s], flow factors per
    direction relative to the AM peak [-], whether the numbers are estimates and their basis.
    """

    name: str
    start_s: float
    end_s: float
    headway_s: float
    flow_up: float
    flow_down: float
    estimate: bool
    basis: str

    def as_tsk(self, direction: str) -> Period:
        """Return the period as a TSK duration (Lin 2010a, eq. 7-8) for ``direction`` up/down."""
        return Period(self.start_s, self.end_s, self.headway_s,
                      self.flow_up if direction == "up" else self.flow_down)


@dataclass(frozen=True)
class TerminusSpec:
    """A terminus: station code, layout data, turnback times [s], depot connection.

    ``min_turnback_s`` [s] is the technical minimum (routes, reversal, platform work);
    ``buffer_s`` [s] the recovery margin the timetable adds on top, so a scheduled layover
    is at least ``layover_s`` = minimum + buffer, and a terminal delay up to the buffer is
    absorbed (Lin 2010a, Experiment 2: 210 s at the 105 s peak headway).
    """

    station: str
    layout: Layout
    min_turnback_s: float
    depot: str | None
    buffer_s: float = 0.0

    @property
    def layover_s(self) -> float:
        """Shortest layover the timetable schedules [s]: minimum turnback plus buffer."""
        return self.min_turnback_s + self.buffer_s


@dataclass(frozen=True)
class TrackTsr:
    """A temporary speed restriction on one running track of a two-track line.

    ``track``: ``up`` or ``down`` (:data:`metro_atc.core.service.records.DIRECTIONS`);
    ``start_m`` < ``end_m`` [m]: the zone in the line's chainage (the scenario's station
    positions), whichever way the track runs; ``limit_kmh`` [km/h]; in force for the day's
    simulated time [``from_s``, ``to_s``) [s after midnight].
    """

    track: str
    start_m: float
    end_m: float
    limit_kmh: float
    from_s: float = 0.0
    to_s: float = math.inf


@dataclass(frozen=True)
class TrackLimit:
    """A permanent speed limit of one running track lower than the line's there.

    ``track`` up / down; ``start_m`` < ``end_m`` [m] in the line's chainage; ``limit_kmh``
    [km/h].  The line scenario's limits apply to both tracks; this lowers one of them.
    """

    track: str
    start_m: float
    end_m: float
    limit_kmh: float


@dataclass(frozen=True)
class TrackCurve:
    """A horizontal curve of one running track.

    ``track`` up / down, ``start_m`` < ``end_m`` [m] in the line's chainage, ``radius_m``
    [m].  A track with any curve of its own has those instead of the line scenario's.
    """

    track: str
    start_m: float
    end_m: float
    radius_m: float


@dataclass(frozen=True)
class DayPlan:
    """A validated day: periods, termini (up origin first), fleet, transition window [s].

    ``tsrs``: temporary speed restrictions per running track (:class:`TrackTsr`);
    ``track_limits``: permanent limits of one track (:class:`TrackLimit`);
    ``track_curves``: the curves of a track replacing the line's (:class:`TrackCurve`).
    """

    name: str
    line: LineData
    periods: Tuple[DayPeriod, ...]
    termini: Tuple[TerminusSpec, TerminusSpec]
    fleet: int
    transition_s: float
    down_offset_s: float
    tsrs: Tuple[TrackTsr, ...] = ()
    track_limits: Tuple[TrackLimit, ...] = ()
    track_curves: Tuple[TrackCurve, ...] = ()


def _hms(t: float) -> str:
    t = int(round(t))
    return f"{t // 3600:02d}:{t % 3600 // 60:02d}"


def headway_at(periods: Sequence[DayPeriod], z_s: float, transition_s: float) -> float:
    """Headway H(z) [s] of the transition rule (module docstring) at instant ``z_s`` [s]."""
    n = max(0, min(len(periods) - 1,
                   int(np.searchsorted([p.start_s for p in periods], z_s, side="right")) - 1))
    h = periods[n].headway_s
    half = 0.5 * transition_s
    if half <= 0.0:
        return h
    if n + 1 < len(periods) and z_s >= periods[n].end_s - half:
        a, b = periods[n].headway_s, periods[n + 1].headway_s
        return a + (b - a) * (z_s - (periods[n].end_s - half)) / transition_s
    if n > 0 and z_s < periods[n].start_s + half:
        a, b = periods[n - 1].headway_s, periods[n].headway_s
        return a + (b - a) * (z_s - (periods[n].start_s - half)) / transition_s
    return h


def departures(periods: Sequence[DayPeriod], first_s: float, transition_s: float
               ) -> np.ndarray:
    """Departure instants [s] from ``first_s`` to the end of the last period."""
    if transition_s <= 0.0:
        return dispatch_instants([p.as_tsk("up") for p in periods], first_s)
    out = []
    z = first_s
    while z < periods[-1].end_s:
        out.append(z)
        z += headway_at(periods, z, transition_s)
    return np.asarray(out)


def period_index(periods: Sequence[DayPeriod], z_s: float) -> int:
    """Index of the period containing instant ``z_s`` [s] (the last one at the end)."""
    for n, p in enumerate(periods):
        if p.start_s <= z_s < p.end_s:
            return n
    return len(periods) - 1


def trip_time_s(line: LineData, headway_s: float, flow_factor: float) -> float:
    """Terminus departure to terminus arrival [s] on the scheduled timetable of the line.

    From the steady-state offsets O_j of :func:`metro_atc.core.atr.traffic.schedule_offsets`
    (Lin 2010a, eq. 5/10): arrival at the last station O_{N-2} + R_{N-2}, minus the
    departure O_0 from the first.
    """
    o = schedule_offsets(line, headway_s, flow_factor)
    return float(o[-2] + line.run_s[-1] - o[0])


def cycle_time_s(plan: DayPlan, n: int) -> float:
    """Cycle time [s] of period n: both trip times plus both scheduled minimum layovers."""
    p = plan.periods[n]
    return (trip_time_s(plan.line, p.headway_s, p.flow_up)
            + trip_time_s(plan.line, p.headway_s, p.flow_down)
            + plan.termini[0].layover_s + plan.termini[1].layover_s)


def trips(plan: DayPlan) -> List[Trip]:
    """Both directions' trips of the day (up from termini[0], down from termini[1]).

    The down direction runs the period table shifted by ``down_offset_s`` [s] (its first
    departure, its period boundaries and its last departure), so both directions run the
    same trips: a terminus without a depot is fed by the up trips' arrivals and its last
    trains go back to the other terminus.
    """
    a, b = plan.termini[0].station, plan.termini[1].station
    out: List[Trip] = []
    first = plan.periods[0].start_s
    for direction, origin, dest, shift in (("up", a, b, 0.0),
                                           ("down", b, a, plan.down_offset_s)):
        per = [dataclasses.replace(p, start_s=p.start_s + shift, end_s=p.end_s + shift)
               for p in plan.periods] if shift else list(plan.periods)
        for k, z in enumerate(departures(per, first + shift, plan.transition_s)):
            p = per[period_index(per, float(z))]
            ff = p.flow_up if direction == "up" else p.flow_down
            run = trip_time_s(plan.line, p.headway_s, ff)
            out.append(Trip(f"{direction}{k:03d}", origin, dest, float(z), float(z) + run))
    return out


@dataclass(frozen=True)
class PeriodReport:
    """Per period: closed-form fleet, peak trains in service, pull-outs, pull-ins."""

    name: str
    cycle_s: float
    closed_form_fleet: int
    peak_in_service: int
    pull_outs: int
    pull_ins: int


def run_day(plan: DayPlan, stable_after_s: float = 1800.0,
            timed: Sequence[Trip] | None = None, prefer: str = "shortest_wait"
            ) -> Tuple[Circulation, List[PeriodReport]]:
    """Circulation of the whole day and its per-period report; DayError when impossible.

    ``stable_after_s`` [s]: a train idle longer than this at a terminus with a depot is
    withdrawn (depot withdrawal after a peak); departures take the train ready last
    (``prefer="shortest_wait"``) so that surplus trains stand and are withdrawn once.
    ``timed``: the day's trips with other trip times (e.g. those the plant can run,
    :func:`metro_atc.core.service.dayplant.plant_timed`), default :func:`trips`;
    ``prefer``: :func:`build_circulation`'s choice of the ready train (``longest_wait``:
    first in, first out, the order a single departure platform imposes on the plant).
    """
    ts = trips(plan) if timed is None else list(timed)
    tb = {t.station: t.layover_s for t in plan.termini}
    depots = {t.station for t in plan.termini if t.depot is not None}
    try:
        circ = build_circulation(ts, tb, depots, stable_after_s, prefer)
    except CirculationError as exc:
        where = (f"period {plan.periods[period_index(plan.periods, exc.instant_s)].name}: "
                 if exc.instant_s is not None else "")
        raise DayError(one_line(f"day {plan.name}: {where}{exc}")) from None
    reports = []
    for n, p in enumerate(plan.periods):
        grid = [tr.departure_s for tr in ts if p.start_s <= tr.departure_s < p.end_s]
        peak = max((circ.in_service(t) for t in grid), default=0)
        outs = sum(1 for b in circ.blocks if p.start_s <= b.trips[0].departure_s < p.end_s)
        ins = sum(1 for b in circ.blocks if p.start_s <= b.trips[-1].arrival_s < p.end_s
                  or (n == len(plan.periods) - 1 and b.trips[-1].arrival_s >= p.end_s))
        cyc = cycle_time_s(plan, n)
        reports.append(PeriodReport(p.name, cyc, closed_form_fleet(cyc, p.headway_s), peak,
                                    outs, ins))
    need = max(reports, key=lambda r: r.peak_in_service)
    if circ.fleet > plan.fleet:
        first = next(r for r in reports if r.peak_in_service > plan.fleet) \
            if any(r.peak_in_service > plan.fleet for r in reports) else need
        raise DayError(one_line(
            f"day {plan.name}: period {first.name}: needs {circ.fleet} trains "
            f"(peak {first.peak_in_service} in service, cycle {first.cycle_s:.0f} s / "
            f"headway {plan.periods[reports.index(first)].headway_s:.0f} s), fleet is "
            f"{plan.fleet}"))
    return circ, reports


# --------------------------------------------------------------------------- loading

_LAYOUTS = ("tail_track", "scissors")


def _num(raw: Any, path: str, src: str, lo: float, hi: float) -> float:
    if isinstance(raw, bool) or not isinstance(raw, (int, float)) or not math.isfinite(raw) \
            or not lo <= raw <= hi:
        raise DayError(one_line(f"day {src}: {path}: expected a number in [{lo:g}, {hi:g}], "
                                f"got {short_repr(raw)}"))
    return float(raw)


def _int(raw: Any, path: str, src: str, lo: int, hi: int) -> int:
    if isinstance(raw, bool) or not isinstance(raw, int) or not lo <= raw <= hi:
        raise DayError(one_line(f"day {src}: {path}: expected an integer in [{lo}, {hi}], "
                                f"got {short_repr(raw)}"))
    return raw


def _str(raw: Any, path: str, src: str) -> str:
    if not isinstance(raw, str) or not raw or len(raw) > 160 or not raw.isprintable():
        raise DayError(one_line(f"day {src}: {path}: expected a short text, "
                                f"got {short_repr(raw)}"))
    return raw


def _map(raw: Any, path: str, src: str, keys: Sequence[str]) -> Dict[str, Any]:
    if not isinstance(raw, dict):
        raise DayError(one_line(f"day {src}: {path}: expected a mapping, got {short_repr(raw)}"))
    unknown = sorted(set(map(str, raw)) - set(keys))
    if unknown:
        raise DayError(one_line(f"day {src}: {path}: unknown key {unknown[0]!r} "
                                f"(known: {', '.join(keys)})"))
    missing = [k for k in keys if k not in raw
               and k not in ("depot", "basis", "n_sidings", "turnback_buffer_s",
                             "platform_m", "siding_m", "tsrs", "from_h", "to_h",
                             "track_limits", "track_curves")]
    if missing:
        raise DayError(one_line(f"day {src}: {path}: missing key {missing[0]!r}"))
    return raw


def _layout(raw: Dict[str, Any], path: str, src: str) -> Layout:
    kind = raw["layout"]
    if kind not in _LAYOUTS:
        raise DayError(one_line(f"day {src}: {path}.layout: expected one of "
                                f"{', '.join(_LAYOUTS)}, got {short_repr(kind)}"))
    rev = _num(raw["reversal_s"], f"{path}.reversal_s", src, 0.0, 3600.0)
    vx = _num(raw["crossover_speed_kmh"], f"{path}.crossover_speed_kmh", src, 5.0, 80.0) * KMH
    plat = _num(raw.get("platform_m", 140.0), f"{path}.platform_m", src, 20.0, 1000.0)
    if kind == "scissors":
        return scissors_terminus(rev, vx, platform_m=plat)
    n = _int(raw.get("n_sidings", 1), f"{path}.n_sidings", src, 1, 8)
    sid = _num(raw.get("siding_m", 160.0), f"{path}.siding_m", src, 20.0, 1000.0)
    return tail_track_terminus(n, rev, vx, platform_m=plat, siding_m=sid)


def parse_day(raw: Any, src: str, line: LineData | None = None) -> DayPlan:
    """Validate a parsed period table (see the shipped YAML); DayError (one line)."""
    ln = taipei_blue() if line is None else line
    top = _map(raw, "<top>", src, ("name", "sources", "line", "fleet", "transition_s",
                                   "down_offset_s", "termini", "periods", "tsrs",
                                   "track_limits", "track_curves"))
    if top["line"] != ln.name:
        raise DayError(one_line(f"day {src}: line: the table is for {short_repr(top['line'])}, "
                                f"the line is {ln.name}"))
    codes = ln.station_codes
    if not isinstance(top["termini"], list) or len(top["termini"]) != 2:
        raise DayError(one_line(f"day {src}: termini: expected a list of two termini"))
    ends = (codes[0], codes[-1])
    termini = []
    for i, t in enumerate(top["termini"]):
        path = f"termini[{i}]"
        m = _map(t, path, src, ("station", "layout", "reversal_s", "crossover_speed_kmh",
                                "n_sidings", "min_turnback_s", "turnback_buffer_s", "depot",
                                "depot_station", "platform_m", "siding_m"))
        if m["station"] != ends[i]:
            raise DayError(one_line(f"day {src}: {path}.station: expected terminus "
                                    f"{ends[i]}, got {short_repr(m['station'])}"))
        dst = m["depot_station"]
        if m.get("depot") is not None:
            _str(m["depot"], f"{path}.depot", src)
        if dst is not None and dst not in codes:
            raise DayError(one_line(f"day {src}: {path}: depot {m.get('depot')} connects at "
                                    f"{short_repr(dst)}, not a station of {ln.name} "
                                    f"({codes[0]}..{codes[-1]})"))
        if dst is not None and dst != m["station"]:
            raise DayError(one_line(f"day {src}: {path}: depot {m.get('depot')} connects at "
                                    f"{dst}, not at terminus {m['station']} (only depot "
                                    f"connections at a terminus are modelled)"))
        lay = _layout(m, path, src)
        tb = _num(m["min_turnback_s"], f"{path}.min_turnback_s", src, 0.0, 7200.0)
        need = lay.min_turnback_s(0)
        if tb < need:
            raise DayError(one_line(
                f"day {src}: {path}: terminus {m['station']} turnback {tb:.0f} s is shorter "
                f"than its {lay.name} layout needs ({need:.0f} s: routes at their speed "
                f"limits + {lay.reversal_s:.0f} s reversal)"))
        buf = 0.0 if m.get("turnback_buffer_s") is None else _num(
            m["turnback_buffer_s"], f"{path}.turnback_buffer_s", src, 0.0, 7200.0)
        termini.append(TerminusSpec(m["station"], lay, tb,
                                    str(m.get("depot")) if dst is not None else None, buf))
    if not isinstance(top["periods"], list) or not top["periods"]:
        raise DayError(one_line(f"day {src}: periods: expected a non-empty list"))
    periods: List[DayPeriod] = []
    for i, p in enumerate(top["periods"]):
        path = f"periods[{i}]"
        m = _map(p, path, src, ("name", "start_h", "end_h", "headway_s", "flow_up",
                                "flow_down", "estimate", "basis"))
        _str(m["name"], f"{path}.name", src)
        if m.get("basis") is not None:
            _str(m["basis"], f"{path}.basis", src)
        start = _num(m["start_h"], f"{path}.start_h", src, 0.0, 30.0) * 3600.0
        end = _num(m["end_h"], f"{path}.end_h", src, 0.0, 30.0) * 3600.0
        if periods and start != periods[-1].end_s:
            raise DayError(one_line(f"day {src}: {path} ({m['name']}): starts at "
                                    f"{_hms(start)}, the previous period ends at "
                                    f"{_hms(periods[-1].end_s)}"))
        if end <= start:
            raise DayError(one_line(f"day {src}: {path} ({m['name']}): ends before it starts"))
        if not isinstance(m["estimate"], bool):
            raise DayError(one_line(f"day {src}: {path}.estimate: expected true/false"))
        if m["estimate"] and not m.get("basis"):
            raise DayError(one_line(f"day {src}: {path} ({m['name']}): an estimate needs a "
                                    f"basis"))
        periods.append(DayPeriod(
            str(m["name"]), start, end,
            _num(m["headway_s"], f"{path}.headway_s", src, *HEADWAY_RANGE_S),
            _num(m["flow_up"], f"{path}.flow_up", src, 0.0, 3.0),
            _num(m["flow_down"], f"{path}.flow_down", src, 0.0, 3.0),
            m["estimate"], str(m.get("basis", ""))))
    trans = _num(top["transition_s"], "transition_s", src, 0.0, 7200.0)
    shortest = min(p.end_s - p.start_s for p in periods)
    if trans > shortest:
        raise DayError(one_line(f"day {src}: transition_s {trans:.0f} s exceeds the shortest "
                                f"period ({shortest:.0f} s)"))
    for p in periods:  # a terminus cannot turn trains faster than its berths allow
        for t in termini:
            need = t.layout.min_headway_s(t.min_turnback_s)
            if p.headway_s < need - 1e-9:
                raise DayError(one_line(
                    f"day {src}: period {p.name}: terminus {t.station} ({t.layout.name}, "
                    f"{len(t.layout.berths)} berths) turns a train in {t.min_turnback_s:.0f} s "
                    f"and needs a headway >= {need:.0f} s, the headway is "
                    f"{p.headway_s:.0f} s"))
    fleet = _int(top["fleet"], "fleet", src, 1, 500)
    off = _num(top["down_offset_s"], "down_offset_s", src, 0.0, 7200.0)
    return DayPlan(_str(top["name"], "name", src), ln, tuple(periods),
                   (termini[0], termini[1]), fleet, trans, off,
                   _tsrs(top.get("tsrs", []), src),
                   _track_limits(top.get("track_limits", []), src),
                   _track_curves(top.get("track_curves", []), src))


def _track_entries(raw: Any, name: str, src: str, keys: Sequence[str]
                   ) -> Iterator[Tuple[str, Dict[str, Any], Tuple[str, float, float]]]:
    """The entries of a per-track list ``name`` of a period table, their zones validated.

    Yields (path, the entry's mapping, (track, start_m, end_m)); DayError (one line) for a
    list that is not one, an unknown or missing key, a track neither up nor down, or a
    zone with start_m >= end_m.
    """
    if not isinstance(raw, list):
        raise DayError(one_line(f"day {src}: {name}: expected a list, got {short_repr(raw)}"))
    for i, t in enumerate(raw):
        path = f"{name}[{i}]"
        m = _map(t, path, src, keys)
        if m["track"] not in ("up", "down"):
            raise DayError(one_line(f"day {src}: {path}.track: expected up or down, got "
                                    f"{short_repr(m['track'])}"))
        a = _num(m["start_m"], f"{path}.start_m", src, -1e7, 1e7)
        b = _num(m["end_m"], f"{path}.end_m", src, -1e7, 1e7)
        if not a < b:
            raise DayError(one_line(f"day {src}: {path}: needs start_m < end_m"))
        yield path, m, (str(m["track"]), a, b)


def _limit(m: Dict[str, Any], path: str, src: str) -> float:
    """The ``limit_kmh`` of a per-track entry [km/h], validated."""
    return _num(m["limit_kmh"], f"{path}.limit_kmh", src, 5.0, 400.0)


def _track_curves(raw: Any, src: str) -> Tuple[TrackCurve, ...]:
    """The ``track_curves`` list of a period table (:class:`TrackCurve`)."""
    return tuple(TrackCurve(*zone, _num(m["radius_m"], f"{path}.radius_m", src, 100.0, 1e5))
                 for path, m, zone in _track_entries(
                     raw, "track_curves", src, ("track", "start_m", "end_m", "radius_m")))


def _track_limits(raw: Any, src: str) -> Tuple[TrackLimit, ...]:
    """The ``track_limits`` list of a period table (:class:`TrackLimit`)."""
    return tuple(TrackLimit(*zone, _limit(m, path, src))
                 for path, m, zone in _track_entries(
                     raw, "track_limits", src, ("track", "start_m", "end_m", "limit_kmh")))


def _tsrs(raw: Any, src: str) -> Tuple[TrackTsr, ...]:
    """The ``tsrs`` list of a period table (:class:`TrackTsr`; hours for the times)."""
    out = []
    keys = ("track", "start_m", "end_m", "limit_kmh", "from_h", "to_h")
    for path, m, zone in _track_entries(raw, "tsrs", src, keys):
        f = _num(m.get("from_h", 0.0), f"{path}.from_h", src, 0.0, 30.0) * 3600.0
        e = math.inf if m.get("to_h") is None else \
            _num(m["to_h"], f"{path}.to_h", src, 0.0, 30.0) * 3600.0
        if not f < e:
            raise DayError(one_line(f"day {src}: {path}: needs from_h < to_h"))
        out.append(TrackTsr(*zone, _limit(m, path, src), f, e))
    return tuple(out)


def day_file(name: str = "taipei_blue_day_periods") -> Path:
    """Path of a shipped period table (``metro_atc/data/<name>.yaml``)."""
    return Path(str(resources.files("metro_atc").joinpath("data", f"{name}.yaml")))


def load_day(path: str | Path | None = None, line: LineData | None = None) -> DayPlan:
    """Load and validate a period table (default: the shipped Taipei Blue day)."""
    p = day_file() if path is None else Path(path)
    try:
        raw = load_yaml_file(p)
    except (YamlLimitError, OSError) as exc:
        raise DayError(one_line(f"day {p.name}: {exc}")) from None
    return parse_day(raw, p.name, line)


def taipei_blue_day() -> DayPlan:
    """Return the Taipei Blue line day (six periods, 06:00-24:00; peak headway of Lin 2010a)."""
    return load_day()
