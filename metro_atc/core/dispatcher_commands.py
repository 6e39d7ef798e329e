"""The dispatcher's run-time commands: validation, a bounded queue, application to the plant.

ROS-free.  An operator command (:class:`Command`: impose or lift a temporary speed
restriction, hold or release a train at a station) is validated when it arrives
(:meth:`Dispatcher.submit`: a one-line reason, nothing queued when refused), queued in a
bounded queue (a flood is refused and counted, never waited on), and applied at the next
lockstep step boundary (:meth:`Dispatcher.apply_due`, before the plant advances from step
k).  Applied commands go through the plant's own incident machinery, as a scripted incident
does: a TSR becomes one more zone of :attr:`metro_atc.core.plant.incidents.Incidents.tsrs`
(the ATP knows it ``signalling.tsr_notice_s`` before ``from_s``), a hold an infinite extra
hold of :attr:`~metro_atc.core.plant.incidents.Incidents.extra_hold` until its release; a
withdrawal marks the train's next station as the end of its service
(:meth:`metro_atc.core.plant.line.LineSim.withdraw`: its passengers alight there, as at the
terminus, and it leaves service at its departure); a skip has the train run through a
station of its future (:meth:`~metro_atc.core.plant.line.LineSim.skip_stop`: its next stop
is the one after, the ATO plans the run past it, the ATS sees no arrival nor departure
there, which its regulators take as a missed event); a regulator switch is validated here by
building the regulator as the ATS will (:func:`regulator_problem`), recorded with the time
it takes effect, ``from_s`` = the step's time + :data:`LEAD_S`, and the ATS regulates the
events from that time on with it (:class:`metro_atc.core.atr.switch.RegulatorSwitch`).
The ATOs learn an applied TSR as the same :class:`~metro_atc.core.ato.onboard.TsrZone` a
scripted one gives (:class:`TsrBook`).

Determinism: a command takes effect at the step it is applied at, recorded with it
(:class:`Applied`); :meth:`Dispatcher.load_replay` applies recorded commands at their steps
(``run --replay-commands``), so a replayed run gives the same events.  A TSR must be
imposed at least ``tsr_notice_s`` + :data:`LEAD_S` before ``from_s``: the ATP and every ATO
then learn it at the same simulated time, ``from_s - tsr_notice_s``, whatever the wall
time the message took to reach an ATO process.
"""

from __future__ import annotations

import math
import re
from collections import deque
from dataclasses import dataclass, replace
from typing import Any, Callable, Iterable, Optional, Sequence

from metro_atc.core.line.scenario import line_extent_m

from metro_atc.core.plant.fleet import RUN, WAIT

KIND_TSR_IMPOSE = 1
KIND_TSR_LIFT = 2
KIND_HOLD = 3
KIND_RELEASE = 4
KIND_WITHDRAW = 5
KIND_SKIP = 6
KIND_REGULATOR = 7
KIND_NAMES = {KIND_TSR_IMPOSE: "tsr_imposed", KIND_TSR_LIFT: "tsr_lifted",
              KIND_HOLD: "hold", KIND_RELEASE: "release", KIND_WITHDRAW: "withdraw",
              KIND_SKIP: "skip", KIND_REGULATOR: "regulator"}
"""Command kind (the DispatcherCommand.KIND_* values) -> its name in events.csv."""

LEAD_S = 5.0
"""Least simulated time between applying a TSR and the ATP learning it [s] (20 steps of
0.25 s): the applied command reaches every ATO process before it matters."""
QUEUE_MAX = 64
"""Default bound of the queue of accepted commands waiting for a step boundary."""
TSR_MAX = 64
"""Dispatcher restrictions in force or announced at once (more impositions are refused):
the ATP and every ATO supervise each zone, so their number is bounded, whatever the rate
at which requests arrive."""
NAME_MAX = 64
"""Longest train id, station or TSR name a request may carry [characters]."""
_TSR_ID = re.compile(r"^[A-Za-z0-9_.-]{1,64}$")


@dataclass(frozen=True)
class Command:
    """One operator command (SI units; the fields a kind does not use are ignored).

    ``start_m``/``end_m`` zone chainage [m], ``speed_mps`` [m/s], ``from_s`` simulation
    time [s]; ``track`` '' (the line's one track); ``tsr_id`` the restriction's name;
    ``train_id``/``station`` (name or code) of a hold or release; ``regulator`` and
    ``weights_file`` ('' : the shipped or cached weights) of a regulator switch (applied:
    ``from_s`` is the time it takes effect).
    """

    kind: int
    track: str = ""
    start_m: float = math.nan
    end_m: float = math.nan
    speed_mps: float = math.nan
    from_s: float = math.nan
    tsr_id: str = ""
    train_id: str = ""
    station: str = ""
    regulator: str = ""
    weights_file: str = ""


@dataclass(frozen=True)
class Applied:
    """A command applied at step ``step`` (time ``t_s`` [s]), ``sequence`` 1, 2, ...

    ``event_index``: the number of plant events before it (its place in events.csv).
    A TSR's ``command.tsr_id`` is the resolved name.
    """

    step: int
    t_s: float
    sequence: int
    command: Command
    event_index: int = 0

    def csv_row(self, station_names: Sequence[str], station_index: int) -> list[str]:
        """Its events.csv row (the columns of :func:`metro_atc.plots.write_events_csv`)."""
        c = self.command
        kind = KIND_NAMES[c.kind]
        if c.kind == KIND_TSR_IMPOSE:
            detail = (f"{c.tsr_id} [{c.start_m:.1f}, {c.end_m:.1f}] m {c.speed_mps:.3f} m/s "
                      f"from {c.from_s:.2f} s")
        elif c.kind == KIND_TSR_LIFT:
            detail = c.tsr_id
        elif c.kind == KIND_REGULATOR:
            detail = f"{c.regulator} from {c.from_s:.2f} s" + (
                f" ({c.weights_file})" if c.weights_file else "")
        else:
            detail = ""
        st = ("", "") if station_index < 0 else (str(station_index),
                                                 station_names[station_index])
        return [c.train_id, st[0], st[1], kind, f"{self.t_s:.2f}", "", "", "", "", "", "",
                f"step {self.step}; {detail}".rstrip("; ")]


class TsrBook:
    """The applied TSRs as an ATO knows them (the zones of a scripted TSR, by name)."""

    def __init__(self, notice_s: float) -> None:
        """No TSR yet; ``notice_s``: the line's ``signalling.tsr_notice_s`` [s]."""
        self.notice_s = float(notice_s)
        self.zones: dict[str, Any] = {}
        self.seen: set[tuple[int, int, int, str]] = set()

    def apply(self, a: Applied) -> bool:
        """Take an applied command once; True when the zones changed.

        Once: by (sequence, step, kind, name), so the history a resumed simulator publishes
        again changes nothing, while a command it applies anew under a sequence number of
        one lost with the rewind is taken.
        """
        from metro_atc.core.ato.onboard import TsrZone
        c = a.command
        key = (a.sequence, a.step, c.kind, c.tsr_id)
        if key in self.seen or c.kind not in (KIND_TSR_IMPOSE, KIND_TSR_LIFT):
            return False
        self.seen.add(key)
        if c.kind == KIND_TSR_IMPOSE:
            self.zones[c.tsr_id] = TsrZone(c.start_m, c.end_m, c.speed_mps,
                                           max(c.from_s - self.notice_s, 0.0), c.from_s,
                                           math.inf)
        elif c.tsr_id in self.zones:
            self.zones[c.tsr_id] = replace(self.zones[c.tsr_id], to_s=a.t_s)
        return True

    def tuple(self) -> tuple[Any, ...]:
        """The zones in the order imposed."""
        return tuple(self.zones.values())


def regulator_problem(scn: Any, name: str, weights_file: str) -> Optional[str]:
    """Why the ATS could not run regulator ``name`` (one line), or None.

    Builds it as the ``ats_regulator`` node does
    (:func:`metro_atc.core.atr.dispatch.make_dispatcher`: the name, the weights' traffic
    model); a trained one loads its weights (seconds the first time).
    """
    from metro_atc.core.atr.dispatch import make_dispatcher
    from metro_atc.core.atr.registry import REGULATORS
    if name not in REGULATORS.names:
        return f"regulator '{name}': expected one of {', '.join(REGULATORS.names)}"
    try:
        make_dispatcher(scn, name, weights_file)
    except (ValueError, FileNotFoundError, OSError, RuntimeError) as exc:
        return f"regulator '{name}': " + " ".join(str(exc).split())
    return None


def _finite(cmd: Command, names: Iterable[str]) -> Optional[str]:
    """A reason when one of the fields ``names`` of ``cmd`` is not a finite number."""
    for n in names:
        v = getattr(cmd, n)
        if not isinstance(v, (int, float)) or not math.isfinite(float(v)):
            return f"{n} is {v}: expected a finite number"
    return None


class Dispatcher:
    """Validates, queues and applies the dispatcher's commands on one :class:`LineSim`.

    ``queue_max``: accepted commands waiting for a step boundary (more are refused).
    Counters: ``accepted``, ``applied``, ``refused`` (by reason kind: ``invalid``,
    ``queue_full``, ``replaying``), ``stale`` (accepted, invalid by the boundary: dropped).
    """

    def __init__(self, sim: Any, queue_max: int = QUEUE_MAX, closed: str = "") -> None:
        """Nothing queued; ``sim`` a :class:`~metro_atc.core.plant.line.LineSim`.

        ``closed``: why every request is refused (kind ``closed``; '' : requests served).
        """
        if queue_max < 1:
            raise ValueError(f"queue_max {queue_max}: expected >= 1")
        self.closed = str(closed)
        self.sim = sim
        self.queue: deque[tuple[int, Command]] = deque()
        self.queue_max = int(queue_max)
        self.tickets = 0
        self.accepted = 0
        self.applied_count = 0
        self.stale = 0
        self.refused: dict[str, int] = {}
        self.log: list[Applied] = []
        self.tsr_index: dict[str, int] = {}
        """TSR name -> its index in ``sim.incidents.tsrs``."""
        self.holds: dict[tuple[int, int], float] = {}
        """(train, station) held -> the scripted extra hold it replaced [s]."""
        self.replay: Optional[dict[int, list[Command]]] = None
        self.stations = {name: j for j, name in enumerate(sim.station_names)}
        self.stations.update({code: j for j, code in enumerate(sim.station_codes)})
        self.trains = {tid: i for i, tid in enumerate(sim.train_ids)}
        self.lo_m, self.hi_m = line_extent_m(sim.scn, float(sim.p.length_m))
        self.regulator_check: Callable[[str, str], Optional[str]] = \
            lambda name, w: regulator_problem(sim.scn, name, w)
        """(regulator, weights_file) -> why it cannot run, or None."""
        self._regulator_ok: dict[tuple[str, str], Optional[str]] = {}

    # ------------------------------------------------------------------ validation
    def check(self, cmd: Command, pending: Sequence[Command] = ()) -> Optional[str]:
        """Why ``cmd`` cannot be applied now (one line), or None.

        ``pending``: commands accepted before it and not applied yet (a lift may name a TSR
        they impose, a release a hold they set).
        """
        k = cmd.kind
        if k not in KIND_NAMES:
            return (f"kind {k}: expected one of {sorted(KIND_NAMES)} "
                    f"({', '.join(KIND_NAMES.values())})")
        for n in ("track", "tsr_id", "train_id", "station", "regulator", "weights_file"):
            v = getattr(cmd, n)
            if not isinstance(v, str) or len(v) > NAME_MAX:
                return f"{n}: expected a string of at most {NAME_MAX} characters"
        if k == KIND_TSR_IMPOSE:
            return self._check_impose(cmd, pending)
        if k == KIND_WITHDRAW:
            return self._check_withdraw(cmd, pending)
        if k == KIND_SKIP:
            return self._check_skip(cmd, pending)
        if k == KIND_REGULATOR:
            key = (cmd.regulator, cmd.weights_file)
            if key not in self._regulator_ok:  # built once per choice
                self._regulator_ok[key] = self.regulator_check(*key)
            return self._regulator_ok[key]
        if k == KIND_TSR_LIFT:
            imposed = {c.tsr_id for c in pending if c.kind == KIND_TSR_IMPOSE}
            lifted = {c.tsr_id for c in pending if c.kind == KIND_TSR_LIFT}
            if cmd.tsr_id not in self.tsr_index and cmd.tsr_id not in imposed:
                return f"tsr_id '{cmd.tsr_id}': no such restriction imposed"
            if cmd.tsr_id in lifted or (cmd.tsr_id in self.tsr_index and math.isfinite(
                    self.sim.incidents.tsrs[self.tsr_index[cmd.tsr_id]][4])):
                return f"tsr_id '{cmd.tsr_id}': already lifted"
            return None
        return self._check_hold(cmd, pending)

    def _check_impose(self, cmd: Command, pending: Sequence[Command]) -> Optional[str]:
        sim = self.sim
        if cmd.track != "":
            return f"track '{cmd.track}': this line has one track ('')"
        bad = _finite(cmd, ("start_m", "end_m", "speed_mps", "from_s"))
        if bad:
            return bad
        a, b, v, f = cmd.start_m, cmd.end_m, cmd.speed_mps, cmd.from_s
        if not b > a:
            return f"zone [{a:g}, {b:g}] m: expected end_m > start_m"
        if a < self.lo_m or b > self.hi_m:
            return (f"zone [{a:g}, {b:g}] m is not on the line: it spans "
                    f"[{self.lo_m:g}, {self.hi_m:g}] m")
        g = sim.geometry
        k0 = max(int(math.floor((a - g.x0) / g.dx)), 0)
        k1 = min(max(int(math.ceil((b - g.x0) / g.dx)), k0 + 1), g.n_cells)
        line_max = float(g.static_limit[k0:k1].max())
        if not 0.0 < v < line_max:
            return (f"speed {v:g} m/s: a restriction is above 0 and below the line's limit "
                    f"there ({line_max:.3f} m/s)")
        earliest = float(sim.t) + float(sim.atp.tsr_notice_s) + LEAD_S
        if f < earliest - 1e-9:
            return (f"from_s {f:g} s: the earliest is {earliest:g} s (now {float(sim.t):g} s "
                    f"+ the TSR notice {float(sim.atp.tsr_notice_s):g} s + {LEAD_S:g} s)")
        if cmd.tsr_id:
            if not _TSR_ID.match(cmd.tsr_id):
                return f"tsr_id '{cmd.tsr_id}': letters, digits, '_', '.', '-' only"
            if cmd.tsr_id in self.tsr_index or any(
                    c.kind == KIND_TSR_IMPOSE and c.tsr_id == cmd.tsr_id for c in pending):
                return f"tsr_id '{cmd.tsr_id}': already imposed"
        return None

    def _train_station(self, cmd: Command) -> tuple[int, int] | str:
        """(train index, station index) a command names, or why it names none."""
        i = self.trains.get(cmd.train_id)
        if i is None:
            return f"train_id '{cmd.train_id}': unknown train"
        j = self.stations.get(cmd.station)
        if j is None:
            return f"station '{cmd.station}': unknown station"
        return i, j

    def _check_hold(self, cmd: Command, pending: Sequence[Command]) -> Optional[str]:
        sim, fl = self.sim, self.sim.fleet
        ij = self._train_station(cmd)
        if isinstance(ij, str):
            return ij
        i, j = ij
        key = (i, j)
        held = set(self.holds)
        for c in pending:
            ck = (self.trains.get(c.train_id), self.stations.get(c.station))
            if c.kind == KIND_HOLD:
                held.add(ck)  # type: ignore[arg-type]
            elif c.kind == KIND_RELEASE:
                held.discard(ck)  # type: ignore[arg-type]
        if cmd.kind == KIND_RELEASE:
            return None if key in held else \
                f"{cmd.train_id} is not held at {sim.station_names[j]}"
        if key in held:
            return f"{cmd.train_id} is held at {sim.station_names[j]} already"
        st = int(fl.status[i])
        if st not in (WAIT, RUN):
            return f"{cmd.train_id} is out of service"
        first = int(fl.cur_station[i]) if (st == RUN and bool(fl.dwelling[i])) \
            else int(fl.next_stop[i])
        if j < first:
            return (f"{cmd.train_id} has left {sim.station_names[j]} (its next departure is "
                    f"from station {first})")
        return None

    def withdraw_station(self, i: int) -> int:
        """The station train i would be withdrawn at now: its next station."""
        return int(self.sim.fleet.next_stop[i])

    def _check_withdraw(self, cmd: Command, pending: Sequence[Command]) -> Optional[str]:
        sim, fl = self.sim, self.sim.fleet
        i = self.trains.get(cmd.train_id)
        if i is None:
            return f"train_id '{cmd.train_id}': unknown train"
        if int(sim.stations.withdraw_at[i]) >= 0 or bool(sim.stations.withdrawn[i]) or any(
                c.kind == KIND_WITHDRAW and c.train_id == cmd.train_id for c in pending):
            return f"{cmd.train_id} is withdrawn already"
        st = int(fl.status[i])
        if st == WAIT:
            return f"{cmd.train_id} has not entered service yet"
        if st != RUN:
            return f"{cmd.train_id} is out of service"
        j = self.withdraw_station(i)
        if j >= sim.n_st - 1:
            return (f"{cmd.train_id}'s next station {sim.station_names[-1]} is the terminus: "
                    "it leaves service there anyway, nothing to withdraw")
        return None

    def _check_skip(self, cmd: Command, pending: Sequence[Command]) -> Optional[str]:
        sim, fl = self.sim, self.sim.fleet
        ij = self._train_station(cmd)
        if isinstance(ij, str):
            return ij
        i, j = ij
        name = sim.station_names[j]
        if j == sim.n_st - 1:
            return f"{name} is the terminus: a train cannot run through it"
        if j == 0:
            return f"{name} is the first station: trains enter service there"
        if bool(sim.stations.skip[i, j]) or any(
                c.kind == KIND_SKIP and c.train_id == cmd.train_id
                and self.stations.get(c.station) == j for c in pending):
            return f"{cmd.train_id} skips {name} already"
        st = int(fl.status[i])
        if st not in (WAIT, RUN):
            return f"{cmd.train_id} is out of service"
        wd = int(sim.stations.withdraw_at[i])
        if wd >= 0 and j >= wd:
            return f"{cmd.train_id} is withdrawn at {sim.station_names[wd]}"
        nxt = int(fl.next_stop[i])
        if j < nxt:
            return f"{cmd.train_id} has passed {name} (its next stop is station {nxt})"
        if st == RUN and j == nxt and not bool(fl.dwelling[i]):
            v = float(fl.v[i])
            d = float(sim.geometry.station_positions_m[j]) - float(fl.x[i])
            b = float(fl.p.max_service_brake_mps2)
            brake = v * v / (2.0 * b)
            if d <= brake:
                return (f"{cmd.train_id} is {d:.1f} m from {name}, within its braking "
                        f"distance {brake:.1f} m at {v:.2f} m/s: too late to skip it")
        return None

    # ------------------------------------------------------------------ queue
    def submit(self, cmd: Command) -> tuple[bool, str, int]:
        """Validate and queue a request: (accepted, one-line reason, ticket or 0)."""
        if self.closed:
            return self._refuse("closed", self.closed)
        if self.replay is not None:
            return self._refuse("replaying", "replaying recorded commands: live commands "
                                "are refused")
        if len(self.queue) >= self.queue_max:
            return self._refuse("queue_full", f"queue full ({self.queue_max} commands wait "
                                "for the next step)")
        if getattr(cmd, "kind", None) == KIND_TSR_IMPOSE \
                and self.tsrs_in_force() + sum(1 for _, c in self.queue
                                               if c.kind == KIND_TSR_IMPOSE) >= TSR_MAX:
            return self._refuse("tsr_limit", f"{TSR_MAX} dispatcher restrictions are in "
                                "force or announced: lift one first")
        reason = self.check(cmd, [c for _, c in self.queue])
        if reason is not None:
            return self._refuse("invalid", reason)
        self.tickets += 1
        self.accepted += 1
        self.queue.append((self.tickets, cmd))
        return True, f"queued as {self.tickets}: {KIND_NAMES[cmd.kind]} at the next step", \
            self.tickets

    def tsrs_in_force(self) -> int:
        """Dispatcher restrictions imposed and not lifted (in force or announced)."""
        tsrs = self.sim.incidents.tsrs
        return sum(1 for i in self.tsr_index.values() if not math.isfinite(tsrs[i][4]))

    def _refuse(self, kind: str, reason: str) -> tuple[bool, str, int]:
        self.refused[kind] = self.refused.get(kind, 0) + 1
        return False, reason, 0

    def load_replay(self, recorded: Iterable[tuple[int, Command]]) -> None:
        """Apply these (step, command) at their steps instead of any live request."""
        self.replay = {}
        for step, cmd in recorded:
            self.replay.setdefault(int(step), []).append(cmd)

    def apply_due(self, step: int) -> list[Applied]:
        """At the boundary of step ``step`` (plant at its time): apply what is due.

        Live: every queued command, in order (one no longer valid is dropped and counted
        in ``stale``).  Replay: the recorded commands of ``step``.
        """
        if self.replay is not None:
            due = self.replay.pop(int(step), [])
        else:
            due = [c for _, c in self.queue]
            self.queue.clear()
        out: list[Applied] = []
        for cmd in due:
            if self.check(cmd) is not None:
                self.stale += 1
                continue
            out.append(self._apply(cmd, int(step)))
        if any(a.command.kind in (KIND_TSR_IMPOSE, KIND_TSR_LIFT) for a in out):
            self.sim.tsrs_changed()  # once for all the step's TSRs
        return out

    # ------------------------------------------------------------------ applying
    def _apply(self, cmd: Command, step: int) -> Applied:
        sim = self.sim
        inc = sim.incidents
        t = float(sim.t)
        seq = len(self.log) + 1
        if cmd.kind == KIND_TSR_IMPOSE:
            cmd = replace(cmd, tsr_id=cmd.tsr_id or f"tsr_{seq}")
            self.tsr_index[cmd.tsr_id] = len(inc.tsrs)
            inc.tsrs.append((float(cmd.start_m), float(cmd.end_m), float(cmd.speed_mps),
                             float(cmd.from_s), math.inf))
        elif cmd.kind == KIND_TSR_LIFT:
            n = self.tsr_index[cmd.tsr_id]
            a, b, v, f, _ = inc.tsrs[n]
            inc.tsrs[n] = (a, b, v, f, t)
        elif cmd.kind == KIND_WITHDRAW:
            i = self.trains[cmd.train_id]
            j = self.withdraw_station(i)
            cmd = replace(cmd, station=sim.station_names[j])
            sim.withdraw(i, j)
        elif cmd.kind == KIND_SKIP:
            sim.skip_stop(self.trains[cmd.train_id], self.stations[cmd.station])
        elif cmd.kind == KIND_REGULATOR:
            cmd = replace(cmd, from_s=t + LEAD_S)  # the ATS switches for events from then
        else:
            i, j = self.trains[cmd.train_id], self.stations[cmd.station]
            if cmd.kind == KIND_HOLD:
                self.holds[(i, j)] = float(inc.extra_hold[i, j])
                inc.extra_hold[i, j] = math.inf
            else:
                inc.extra_hold[i, j] = self.holds.pop((i, j))
            sim.hold_changed(i, j)
        a_ = Applied(step, t, seq, cmd, len(sim.stations.events))
        self.log.append(a_)
        self.applied_count += 1
        return a_

    def station_of(self, a: Applied) -> int:
        """Station index of an applied hold / release / withdrawal / skip (-1: a TSR)."""
        return self.stations.get(a.command.station, -1) \
            if a.command.kind in (KIND_HOLD, KIND_RELEASE, KIND_WITHDRAW, KIND_SKIP) else -1

    @property
    def state(self) -> dict[str, Any]:
        """What a checkpoint keeps of it, as plain values (see :meth:`restore`)."""
        def cmd(c: Command) -> list[Any]:
            return [c.kind, c.track, c.start_m, c.end_m, c.speed_mps, c.from_s, c.tsr_id,
                    c.train_id, c.station, c.regulator, c.weights_file]
        return {"log": [[a.step, a.t_s, a.sequence, a.event_index, *cmd(a.command)]
                        for a in self.log],
                "queue": [[n, *cmd(c)] for n, c in self.queue],
                "holds": [[i, j, v] for (i, j), v in self.holds.items()],
                "tsr_index": dict(self.tsr_index),
                "counts": [self.tickets, self.accepted, self.applied_count, self.stale],
                "refused": dict(self.refused)}

    @state.setter
    def state(self, st: dict[str, Any]) -> None:
        """Take a :attr:`state` back (a resumed simulator)."""
        def cmd(v: Sequence[Any]) -> Command:
            return Command(int(v[0]), str(v[1]), float(v[2]), float(v[3]), float(v[4]),
                           float(v[5]), str(v[6]), str(v[7]), str(v[8]),
                           *(str(x) for x in v[9:11]))
        self.log = [Applied(int(r[0]), float(r[1]), int(r[2]), cmd(r[4:]), int(r[3]))
                    for r in st["log"]]
        self.queue = deque((int(r[0]), cmd(r[1:])) for r in st["queue"])
        self.holds = {(int(i), int(j)): float(v) for i, j, v in st["holds"]}
        self.tsr_index = {str(k): int(v) for k, v in st["tsr_index"].items()}
        self.tickets, self.accepted, self.applied_count, self.stale = (
            int(x) for x in st["counts"])
        self.refused = {str(k): int(v) for k, v in st["refused"].items()}

    def counters(self) -> dict[str, Any]:
        """For /diagnostics and the KPIs: accepted, applied, queued, refused per kind, stale."""
        return {"accepted": self.accepted, "applied": self.applied_count,
                "queued": len(self.queue), "stale": self.stale,
                "refused": dict(sorted(self.refused.items())),
                "refused_total": sum(self.refused.values())}
