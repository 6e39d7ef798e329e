"""ato_controller node(s): one ATO per train, namespaced ``/<train_id>/``.

Per train: its state every lockstep step (from the process's fleet state, below) and
``departure_command`` (transient-local); on each departure command it plans the
inter-station speed profile (:class:`metro_atc.core.ato.controller.AtoCore`: MMAS, coasting
control FOTP/FCTP/ECTP/ACTP or the DP reference; Ke 2010/002) for the ATS's target running
time and publishes it on ``speed_profile`` (transient-local); on each state it answers the
traction/brake effort of the tracker (fuzzy, Li n.d., or PI) for that lockstep step.

The tracker follows the plan; two guards only ever *lower* its command: braking to the end
of the ATP movement authority (train ahead) and staying below the ATP supervision speed
(temporary restrictions the plan does not know). ATP in the simulator stays the safety layer.

Restart and resume (``checkpoint_dir``): every state the ATO acts on is appended to
``<checkpoint_dir>/ato_<train>.jsonl`` before its command is published.  The ATO's commands
are a deterministic function of that sequence of states (departure commands only pre-plan
while standing; the run is planned from the state at departure), so a restarted ATO replays
its journal into a fresh :class:`OnboardAto` and answers on as if never stopped; and when the
simulator resumes from a checkpoint (its step goes back) and re-sends a state the journal
holds, field for field, the ATO rebuilds itself from the journal up to that step.

One process may host several trains (parameter ``train_ids``), each its own node on one
SingleThreadedExecutor: rclpy shares one DDS participant per process, and the trains of a
process share their planners' pre-work tables and finished plans (same line, same train).

Fleet lockstep: the simulator publishes the states of all active trains in one
``/line/fleet_state`` message per step; a :class:`FleetLink` per process answers the trains
it hosts with one ``/line/fleet_command`` message. Each entry is validated and answered
exactly as a per-train state was (same rules, step window and tracker). The ATO takes its
states from the fleet topic only (two carriers of one step would race); where the entry's
``echo`` is set (the simulator published ``/<train>/state`` for that step too, every
``train_state_period_s`` and every step while recording) it also publishes its command on
``/<train>/command``, so outside tools see matching per-train states and commands.
"""

from __future__ import annotations

import json
import math
import os
import struct
import time
from pathlib import Path
from typing import Any, NamedTuple, Sequence

import numpy as np
from diagnostic_msgs.msg import DiagnosticStatus
from metro_atc_msgs.msg import (DepartureCommand, DispatcherCommand, FleetCommand, FleetState,
                                SpeedProfile, TractionCommand)
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.serialization import deserialize_message

from metro_atc.core.ato.cab import CabWatch
from metro_atc.core.ato.coasting import warm_up_plan_kernel
from metro_atc.core.ato.onboard import OnboardAto, PlanEvent
from metro_atc.core.ato.plan_store import PlanStore
from metro_atc.core.ato.planner import Profile
from metro_atc.core.ato.registry import PLANNERS, TRACKERS
from metro_atc.core.ato.wiring import MmasSettings, ato_wiring
from metro_atc.core.bridge import timetable_for
from metro_atc.core.dispatcher_commands import TsrBook
from metro_atc.core.journal import read_entries
from metro_atc.core.line.scenario import ScenarioError
from metro_atc.core.service.dayrun import day_table, load_run_scenario
from metro_atc.core.validate import Rejections, StepWindow, bounds_for
from metro_atc.nodes import conversions as conv
from metro_atc.nodes import dispatch_msgs
from metro_atc.nodes.wire import fleet_command, fleet_state, traction_command
from metro_atc.nodes.wire.cdr import stamp_parts
from metro_atc.nodes.common import (OK, QOS_EVENTS, QOS_LATCHED, QOS_LATCHED_IN, QOS_RELIABLE,
                                    WARN, WarnLimiter,
                                    NodeConfigError, RuntimeParams, bulk_publisher,
                                    bulk_subscription, declare, diag_status, run_nodes,
                                    spin_fast, static)


class Cmd(NamedTuple):
    """One traction command as the ATO decided it (step, stamp [s], effort [-1, 1], mode).

    Plain fields: the fleet command carries them; a TractionCommand message is built only
    for the per-train echo (a rosidl message per train and step cost more than the
    tracker).
    """

    step: int
    t_s: float
    effort: float
    mode: int


class AtoController(Node):
    """The ATO of one train (see module docstring)."""

    def __init__(self, train_id: str, scenario: Any = None, timetable: Any = None,
                 shared: dict[str, Any] | None = None, **kwargs: Any) -> None:
        """Declare parameters, load the line, create the per-train topics."""
        # the executor (parameter and type-description services, timers) is spun every
        # 0.25 s by spin_fast, so the services cost little: all are on (remote tools can
        # fetch the types of /<train>/command and /<train>/speed_profile)
        super().__init__("ato_controller", namespace=f"/{train_id}", **kwargs)
        self.train_id = train_id
        self.scenario_name = static(self, "scenario", "taipei_blue",
                                    "embedded scenario name or path to a scenario YAML")
        static(self, "train_ids", [""], "trains hosted by this process (launcher use)")
        planner = static(self, "planner", "ectp", "speed-profile planner: " + PLANNERS.help(),
                         choices=PLANNERS.names)
        tracker = static(self, "tracker", "fuzzy", "speed tracker: " + TRACKERS.help(),
                         choices=TRACKERS.names)
        mmas_default = MmasSettings()
        mmas_ants = static(self, "mmas_ants", mmas_default.n_ants,
                           "MMAS: ants per iteration (Ke 2010)", 1, 1000)
        mmas_iter = static(self, "mmas_iterations", mmas_default.n_iterations,
                           "MMAS: iterations (Ke 2010)", 1, 10000)
        mmas_sections = static(self, "mmas_sections", mmas_default.n_sections,
                               "MMAS: sections per run (Ke 2010)", 2, 500)
        plan_dir = static(self, "plan_store_dir", "",
                          "directory shared by the ATO processes of a run: finished plans "
                          "are planned once per run and target ('': per process only)")
        self.planner, self.tracker = planner, tracker
        self.plans = 0
        self.infeasible = 0
        self.last_step = -1
        self.planned_from = -1
        self._tick = (0, 0)
        # /diagnostics stamped with the simulated time of the last state acted on (the
        # launcher runs the ATOs without use_sim_time: they need no /clock)
        self.rt = RuntimeParams(self, self.health, stamp=self.last_state_t)
        if scenario is None:
            try:
                scenario = load_run_scenario(self.scenario_name)
            except ScenarioError as exc:
                raise NodeConfigError(str(exc)) from None
        self.tt = timetable if timetable is not None else timetable_for(scenario)
        if train_id not in self.tt.train_ids:
            raise NodeConfigError(f"train_id '{train_id}' is not in scenario "
                                  f"'{self.scenario_name}' ({self.tt.train_ids[0]} .. "
                                  f"{self.tt.train_ids[-1]})")
        self.idx = self.tt.train_ids.index(train_id)
        # what this train's OnboardAto is built from, as the ROS-free closed loop builds it;
        # the ATP model (one plant grid per process) is shared by the trains of the process
        try:
            self.wiring = ato_wiring(
                scenario, planner, tracker, MmasSettings(mmas_ants, mmas_iter, mmas_sections),
                tt=self.tt, atp=shared.get("atp_model") if shared is not None else None)
        except ValueError as exc:
            raise NodeConfigError(str(exc)) from None
        if shared is not None:
            shared["atp_model"] = self.wiring.atp
        train = self.wiring.train
        if plan_dir and shared is not None and "plan_store" not in shared:
            try:
                shared["plan_store"] = PlanStore(plan_dir, context=f"{self.scenario_name}|"
                                                 f"{planner}|{train!r}")
            except OSError as exc:
                raise NodeConfigError(f"plan_store_dir '{plan_dir}': {exc}") from None
        if shared is None or not shared.get("plan_kernel_loaded"):
            # the first plan runs inside the lockstep callback: load the kernel before
            warm_up_plan_kernel(train, self.wiring.limits)
            if shared is not None:
                shared["plan_kernel_loaded"] = True

        self.tsr_notice_s = float(scenario.signalling.tsr_notice_s)
        self.dispatched_tsrs: tuple[Any, ...] = ()
        """The dispatcher's TSRs (:class:`TsrBook`), known to the ATO as scripted ones."""

        def new_onboard() -> OnboardAto:
            ob = self.wiring.onboard(shared)
            ob.tsrs = tuple(self.wiring.tsrs) + self.dispatched_tsrs
            return ob

        self._new_onboard = new_onboard
        self.onboard = new_onboard()
        self.core = self.onboard.core
        self.cab = CabWatch() if day_table(self.scenario_name) is not None else None
        """In a service day: when this train's ATO starts afresh (:mod:`core.ato.cab`)."""
        self.history: list[dict[str, Any]] = []
        """The states acted on, in order (the journal's content; kept with a journal only:
        what a resumed simulator's rewind replays)."""
        ck_dir = static(self, "checkpoint_dir", "",
                        "directory of the per-train state journal ('' : none): a restarted "
                        "ATO replays it, a simulator resumed behind is followed back")
        self.journal_path = Path(ck_dir) / f"ato_{train_id}.jsonl" if ck_dir else None
        self._journal: Any = None
        self.rejected = 0
        self.rejections = Rejections()
        """Rejected input messages per kind (:mod:`metro_atc.core.validate`)."""
        self.bounds = bounds_for(scenario)
        self.steps = StepWindow()
        self._last_cmd: Cmd | None = None
        self.echoed_step = -1
        """Step of the last command echoed on ``/<train>/command`` (fleet lockstep)."""
        self._warn = WarnLimiter(self)
        self.cmd_pub = bulk_publisher(self, TractionCommand, "command", QOS_RELIABLE)
        self.profile_pub = bulk_publisher(self, SpeedProfile, "speed_profile", QOS_LATCHED)
        self.fast_subs = [
            bulk_subscription(self, DepartureCommand, "departure_command", self._on_departure,
                              QOS_LATCHED_IN)]
        if self.journal_path is not None:
            self._open_journal()

    # ------------------------------------------------------------------ restart
    def _open_journal(self) -> None:
        """Replay an existing journal (a restart), then keep appending to it."""
        assert self.journal_path is not None
        self.journal_path.parent.mkdir(parents=True, exist_ok=True)
        states = _read_states(self.journal_path)
        if states:
            self._replay(states)
            self.get_logger().warning(
                f"restarted: replayed {len(states)} states of the journal up to step "
                f"{self.last_step}")
        self._rewrite_journal()

    def _rewrite_journal(self) -> None:
        """Write ``history`` as the journal (atomically) and reopen it for appending."""
        assert self.journal_path is not None
        if self._journal is not None:
            self._journal.close()
        tmp = self.journal_path.with_name(self.journal_path.name + ".tmp")
        tmp.write_text("".join(json.dumps(s) + "\n" for s in self.history))
        os.replace(tmp, self.journal_path)
        # unbuffered: each line is one write(2) to the OS as it is written (then it
        # survives a SIGKILL; no text layer and no flush per line)
        self._journal = open(self.journal_path, "ab", buffering=0)

    def _replay(self, states: list[dict[str, Any]]) -> None:
        """A fresh on-board ATO driven through ``states`` (no publication)."""
        self.onboard = self._new_onboard()
        self.core = self.onboard.core
        self.steps = StepWindow()
        self.history = []
        self._last_cmd = None
        self.last_step = -1
        for s in states:
            effort, mode, _ = self.onboard.control(s)
            self.steps.accept(int(s["step"]))
            self._remember(s, effort, mode)

    def _remember(self, s: dict[str, Any], effort: float, mode: int) -> None:
        """Record a state acted on and its command (the state itself with a journal only)."""
        if self.journal_path is not None:
            self.history.append(s)
        self.last_step = int(s["step"])
        self._last_cmd = Cmd(int(s["step"]), float(s["t_s"]), float(effort), int(mode))

    def _rewind(self, msg: Any, topic: str) -> bool:
        """A state of an earlier step the journal holds identically: the simulator resumed.

        Rebuild the ATO from the journal's states before that step; True when done.
        """
        if not self.history:
            return False
        j = int(msg.step) - int(self.history[0]["step"])
        if not 0 <= j < len(self.history):
            return False
        try:
            s = conv.state_from_msg(msg, topic, self.train_id, self.bounds, StepWindow())
        except conv.MessageRejected:
            return False
        if _state_key(s) != _state_key(self.history[j]):
            return False
        before = self.last_step
        self._replay(self.history[:j])
        self._rewrite_journal()
        self.get_logger().warning(f"the simulator went back from step {before} to step "
                                  f"{int(msg.step)}: replayed the journal up to it")
        return True

    def health(self) -> list[DiagnosticStatus]:
        """/diagnostics: this train's planner/tracker, plans, infeasible plans, rejections.

        WARN when a plan of the last period was infeasible (the target running time cannot
        be met; the tracker follows the planner's best effort) or an input was rejected.
        """
        inf0, rej0 = self._tick
        self._tick = (self.infeasible, self.rejected)
        level, msg = OK, "tracking"
        if self.infeasible > inf0:
            level, msg = WARN, f"{self.infeasible - inf0} infeasible plans in the last period"
        elif self.rejected > rej0:
            level, msg = WARN, f"{self.rejected - rej0} inputs rejected in the last period"
        return [diag_status(f"ato_controller: {self.train_id}", self.train_id, level, msg, {
            "planner": self.planner, "tracker": self.tracker, "plans": self.plans,
            "infeasible_plans": self.infeasible, "rejected_inputs": self.rejected,
            "last_step": self.last_step, "planned_from_station": self.planned_from})]

    def last_state_t(self) -> float:
        """Simulated time [s] of the last state acted on (0 before the first)."""
        return self._last_cmd.t_s if self._last_cmd is not None else 0.0

    # ------------------------------------------------------------------ planning
    def _reject(self, what: str, exc: conv.MessageRejected) -> None:
        """Count a rejected message per kind; log it (at most 1/s per kind, all counts)."""
        self.rejected += 1
        line = self.rejections.note(what, exc, time.monotonic())  # per-kind rate limit
        if line is not None:
            self.get_logger().warning(line)

    def _on_departure(self, msg: DepartureCommand) -> None:
        topic = f"/{self.train_id}/departure_command"
        try:
            st, dep, run, _dwell = conv.departure_from_msg(msg, topic, self.train_id,
                                                           self.bounds)
            conv.guarded(topic, self._take_departure, st, dep, run,
                         conv.from_time(msg.header.stamp))
        except conv.MessageRejected as exc:
            self._reject("departure command", exc)

    def _take_departure(self, st: int, dep: float, run: float, stamp_s: float) -> None:
        """Hand a validated departure command to the onboard ATO; publish a pre-plan."""
        planned = self.onboard.on_departure(st, dep, run, stamp_s)
        if planned is not None:
            # pre-planned while standing (publishes the profile early, warms the plan cache);
            # the run is planned definitively from the state at departure
            self._publish_plan(planned)

    def _publish_plan(self, ev: PlanEvent) -> None:
        """Publish a planned run's profile (warn when it is infeasible and not late)."""
        self.planned_from = ev.station
        self.plans += 1
        self.infeasible += int(not ev.profile.feasible)
        if not ev.profile.feasible and not ev.late:
            self._warn("plan", f"run {ev.station}->{ev.to_station}: {ev.profile.message}")
        self.profile_pub.publish(self._profile_msg(ev.station, ev.target_s, ev.profile,
                                                   ev.stamp_s, ev.to_station))

    def _profile_msg(self, st: int, target_s: float, prof: Profile,
                     stamp_s: float, to: int = -1) -> SpeedProfile:
        p = SpeedProfile()
        p.header.stamp = conv.to_time(stamp_s)
        p.header.frame_id = "line"
        p.train_id = self.train_id
        p.from_station, p.to_station = st, (to if to > st else st + 1)
        p.section_boundaries_m = [float(x) for x in prof.section_bounds_m]
        # core modes 0 accelerate, 1 cruise, 2 coast, 3 brake -> SpeedProfile.MODE_* (2..5)
        p.section_modes = [int(m) + SpeedProfile.MODE_ACCELERATE for m in prof.modes]
        p.section_speed_codes_mps = [float(v) for v in prof.codes_mps]
        p.coasting_point_m = float(prof.coast_point_m)
        p.target_running_time_s = float(target_s)
        p.predicted_running_time_s = float(prof.running_time_s)
        p.predicted_energy_j = float(prof.energy_j)
        p.feasible = bool(prof.feasible)
        p.planner = str(prof.planner)
        p.message = str(prof.message)
        p.planned_position_m, p.planned_speed_mps = planned_curve(prof)
        return p

    # ------------------------------------------------------------------ tracking
    def answer(self, msg: Any, topic: str, flush: bool = True) -> Cmd | None:
        """The command for a state (a fleet entry, TrainState fields); None if rejected.

        A rejected state gets no answer (the plan and the tracker are left as they are:
        the simulator keeps waiting for this train's genuine state of the step); a re-sent
        state gets the same command again without running the tracker twice.  ``flush``
        False: the journal line is written but not flushed; the caller must call
        :meth:`flush_journal` before the command leaves the process.
        """
        self._back_from_depot(int(getattr(msg, "step", -1)))
        try:
            try:
                s = conv.state_from_msg(msg, topic, self.train_id, self.bounds, self.steps)
            except conv.MessageRejected as exc:
                if exc.kind != "step" or not self._rewind(msg, topic):
                    raise
                s = conv.state_from_msg(msg, topic, self.train_id, self.bounds, self.steps)
            return self._act(s, topic, flush)
        except conv.MessageRejected as exc:
            self._reject("state", exc)
            return None

    def answer_checked(self, s: dict[str, Any], entry: Any, topic: str,
                       flush: bool = True) -> Cmd | None:
        """:meth:`answer` for a state already validated field by field (fleet fast path).

        ``s``: the dict :func:`conversions.state_from_msg` would return, without ``again``;
        ``entry``: the TrainState-like view, used as :meth:`answer` does when the step is
        outside the window (a re-synchronisation or a resumed simulator).
        """
        k = s["step"]
        self._back_from_depot(k)
        last = self.steps.last
        if last is not None and k != last + 1 and k != last:
            return self.answer(entry, topic, flush)
        try:
            s["again"] = self.steps.accept(k, f"{topic}.step") == "again"
            return self._act(s, topic, flush)
        except conv.MessageRejected as exc:
            self._reject("state", exc)
            return None

    def _act(self, s: dict[str, Any], topic: str, flush: bool) -> Cmd | None:
        """The command for a validated state (its step accepted); journal it."""
        last = self._last_cmd
        if s["again"] and last is not None and last.step == s["step"]:
            return last
        effort, mode = conv.guarded(topic, self.control, s)
        self._remember(s, effort, mode)
        if self._journal is not None:
            # an unbuffered file: the line is in the OS when write returns (``flush`` and
            # :meth:`flush_journal` have nothing left to do; kept for the callers' contract)
            line = (state_json(s) + "\n").encode()
            n = self._journal.write(line)
            while n is not None and n < len(line):  # a short write (rare): the rest
                line = line[n:]
                n = self._journal.write(line)
        return self._last_cmd

    def _back_from_depot(self, k: int) -> None:
        """In a service day, a state steps ahead of the last one: the train is back in service.

        The simulator asks a train's ATO every step while it is in service and never while
        it stands in the depot, so a state of a later step than the next one starts a new
        step window (and a new cab, :meth:`control`); going back stays rejected.
        """
        last = self.steps.last
        if self.cab is not None and last is not None and k > last + 1:
            self.steps = StepWindow()

    def flush_journal(self) -> None:
        """Hand the journal's written lines to the OS (then they survive a SIGKILL).

        Called before the command of the state leaves the process.  The journal is an
        unbuffered file (each line is written to the OS by :meth:`_act` itself): nothing
        is pending, the call is kept for the contract of ``flush=False``.
        """
        if self._journal is not None:
            self._journal.flush()

    def control(self, s: dict[str, Any]) -> tuple[float, int]:
        """Effort in [-1, 1] and intended mode for one state (:class:`OnboardAto`)."""
        if self.cab is not None and self.cab.new_cab(s["step"], s["current_station"]):
            self.onboard = self._new_onboard()  # pull-out or a new lap: the other cab
            self.core = self.onboard.core
        u, mode, planned = self.onboard.control(s)
        if planned is not None:
            self._publish_plan(planned)
        return u, mode


_STATE_KEYS = ("step", "t_s", "x_m", "v_mps", "a_mps2", "current_station", "next_station",
               "mode", "departure_time_s", "target_running_time_s", "supervision_speed_mps",
               "movement_authority_m", "mass_kg", "again")
"""The keys of a validated state (:func:`conversions.state_from_msg`), in its order."""


_isfinite = math.isfinite


def _jf(x: float) -> str:
    """A float as :func:`json.dumps` writes it (``float.__repr__``, NaN, +-Infinity)."""
    if x != x:
        return "NaN"
    if x == math.inf:
        return "Infinity"
    if x == -math.inf:
        return "-Infinity"
    return float.__repr__(x)


def state_json(s: dict[str, Any]) -> str:
    """``json.dumps(s)`` of a validated state, written out (the same text).

    The journal writes one line per train and step; ``json.dumps`` walked the dict in
    general.  Any other dict (keys, order or value types not a validated state's) goes to
    ``json.dumps``.
    """
    if len(s) != 14 or tuple(s) != _STATE_KEYS:
        return json.dumps(s)
    k, t, x, v, a, cur, nxt, md, dep, tgt, sup, ma, mass, again = s.values()
    if not (type(k) is int and type(cur) is int and type(nxt) is int  # noqa: E721
            and type(md) is int and type(again) is bool and type(t) is float
            and type(x) is float and type(v) is float and type(a) is float
            and type(dep) is float and type(tgt) is float and type(sup) is float
            and type(ma) is float and type(mass) is float):
        return json.dumps(s)
    if _isfinite(t + x + v + a + dep + tgt + sup + ma + mass):
        # a finite sum: no NaN or infinity among them, each written as float.__repr__
        # (``!r`` of a float; one format, no call per field)
        return (f'{{"step": {k}, "t_s": {t!r}, "x_m": {x!r}, "v_mps": {v!r}, '
                f'"a_mps2": {a!r}, "current_station": {cur}, "next_station": {nxt}, '
                f'"mode": {md}, "departure_time_s": {dep!r}, '
                f'"target_running_time_s": {tgt!r}, "supervision_speed_mps": {sup!r}, '
                f'"movement_authority_m": {ma!r}, "mass_kg": {mass!r}, '
                f'"again": {"true" if again else "false"}}}')
    return (f'{{"step": {k}, "t_s": {_jf(t)}, "x_m": {_jf(x)}, "v_mps": {_jf(v)}, '
            f'"a_mps2": {_jf(a)}, "current_station": {cur}, "next_station": {nxt}, '
            f'"mode": {md}, "departure_time_s": {_jf(dep)}, '
            f'"target_running_time_s": {_jf(tgt)}, "supervision_speed_mps": {_jf(sup)}, '
            f'"movement_authority_m": {_jf(ma)}, "mass_kg": {_jf(mass)}, '
            f'"again": {"true" if again else "false"}}}')


def _state_key(s: dict[str, Any]) -> str:
    """A state's fields as one comparable text (NaN equal to NaN; ``again`` left out)."""
    return json.dumps({k: v for k, v in s.items() if k != "again"}, sort_keys=True)


def _read_states(path: Path) -> list[dict[str, Any]]:
    """The journal's states, consecutive steps from the first (a torn line ends it)."""
    return read_entries(path, lambda s, out: not out
                        or int(s["step"]) == int(out[-1]["step"]) + 1)


class FleetLink:
    """The fleet lockstep of one ATO process: one FleetState in, one FleetCommand out.

    The subscription and the publisher live on the first hosted node; each entry for a
    hosted train goes through that train's :meth:`AtoController.answer` (validation, step
    window, tracker), in the order of the message.
    """

    TOPIC_STATE = "/line/fleet_state"
    TOPIC_COMMAND = "/line/fleet_command"

    def __init__(self, nodes: Sequence[AtoController]) -> None:
        """Create the fleet subscription and publisher on ``nodes[0]``."""
        self.nodes = {n.train_id: n for n in nodes}
        host = nodes[0]
        self.pub = bulk_publisher(host, FleetCommand, self.TOPIC_COMMAND, QOS_RELIABLE)
        # the CDR bytes, read by wire.fleet_state (rclpy's message objects cost more than the
        # answers); the commands go out as CDR bytes too
        self.sub = host.create_subscription(
            FleetState, self.TOPIC_STATE, self.on_fleet_state, QOS_RELIABLE, raw=True,
            event_callbacks=SubscriptionEventCallbacks(use_default_callbacks=False))
        # the fast path checks all entries with one set of bounds (the hosted trains share
        # their scenario; otherwise every entry takes the per-train path)
        b = {n.bounds for n in nodes}
        self.bounds = next(iter(b)) if len(b) == 1 else None
        # the dispatcher's applied commands: its TSRs become zones of every hosted ATO
        self.book = TsrBook(host.tsr_notice_s)
        self.dispatch_sub = host.create_subscription(
            DispatcherCommand, dispatch_msgs.APPLIED_TOPIC, self.on_dispatched, QOS_EVENTS)

    def on_dispatched(self, msg: DispatcherCommand) -> None:
        """An applied dispatcher command: a TSR imposed or lifted reaches every hosted ATO."""
        try:
            changed = self.book.apply(dispatch_msgs.applied_from_msg(msg))
        except (ValueError, TypeError, OverflowError) as exc:
            next(iter(self.nodes.values()))._reject("dispatcher command", conv.MessageRejected(
                "dispatch", f"{dispatch_msgs.APPLIED_TOPIC}: {exc}"))
            return
        if changed:
            zones = self.book.tuple()
            for node in self.nodes.values():
                node.dispatched_tsrs = zones
                node.onboard.tsrs = tuple(node.wiring.tsrs) + zones

    def on_fleet_state(self, data: "bytes | FleetState") -> None:
        """Answer the hosted trains of a fleet state (a malformed message: counted, dropped).

        ``data``: the message's CDR bytes (the subscription's) or a FleetState.  Bytes are
        read by :func:`fleet_state.decode`; what it does not read exactly goes
        through rclpy's deserialisation (then validated as before), and bytes rclpy cannot
        read either are counted as a rejected fleet state (kind ``cdr``).
        """
        msg: Any = data
        if isinstance(data, bytes):
            msg = fleet_state.decode(data)
            if msg is None:
                try:
                    msg = deserialize_message(data, FleetState)
                except Exception as exc:  # noqa: BLE001 - any failure of rclpy's reader
                    next(iter(self.nodes.values()))._reject("fleet state", conv.MessageRejected(
                        "cdr", f"{self.TOPIC_STATE}: undecodable CDR ({exc})"))
                    return
        topic = self.TOPIC_STATE
        checked = fleet_state.checked(msg, topic, self.nodes, self.bounds) \
            if self.bounds is not None else None
        if checked is None:
            try:
                entries = fleet_state.entries(msg, topic, self.nodes)
            except conv.MessageRejected as exc:
                next(iter(self.nodes.values()))._reject("fleet state", exc)
                return
        else:
            entries = [(tid, _Lazy(msg, tid, s, e)) for tid, s, e in checked]
        ids: list[str] = []
        efforts: list[float] = []
        modes: list[int] = []
        step, stamp = None, None
        echoes: list[tuple[AtoController, Cmd]] = []
        answered: list[AtoController] = []
        for tid, e in entries:
            node = self.nodes[tid]
            cmd = node.answer_checked(e.state, e, topic, flush=False) \
                if isinstance(e, _Lazy) else node.answer(e, topic, flush=False)
            answered.append(node)
            if cmd is None or (step is not None and cmd.step != step):
                continue
            if e.echo and node.echoed_step != cmd.step:
                echoes.append((node, cmd))  # once per step: a re-sent state is not echoed
                node.echoed_step = cmd.step
            step, stamp = cmd.step, cmd.t_s
            ids.append(tid)
            efforts.append(cmd.effort)
            modes.append(cmd.mode)
        # one flush per journal for the whole message, all before any command leaves
        for node in answered:
            node.flush_journal()
        if ids and step is not None and stamp is not None:
            # from_time(to_time(stamp)), as a TractionCommand carried it (its integer parts
            # without building a Time message)
            sec, nsec = stamp_parts(stamp)
            stamp = float(sec) + 1e-9 * float(nsec)
            try:
                out: Any = fleet_command.encode(stamp_parts(stamp), "line", step, ids,
                                                efforts, modes)
            except (ValueError, struct.error):
                out = fleet_command.to_msg(step, stamp, ids, efforts, modes)  # rclpy decides
            self.pub.publish(out)
        # the per-train echoes after the fleet command: the simulator waits for the latter
        # only (an echo arriving after the step is a stale duplicate to it, late_echo), so
        # building and sending them is off the lockstep's critical path
        for node, cmd in echoes:
            node.cmd_pub.publish(echo_bytes(node.train_id, cmd))


def echo_bytes(train_id: str, cmd: Cmd) -> Any:
    """The ``/<train>/command`` echo of a command as CDR bytes (:mod:`wire.traction_command`).

    Values the encoder refuses give the message object (rclpy's setters decide).
    """
    try:
        return traction_command.encode(stamp_parts(cmd.t_s), "line", train_id, cmd.step,
                                       cmd.effort, cmd.mode)
    except (ValueError, struct.error):
        return conv.traction_msg(train_id, cmd.step, cmd.t_s, cmd.effort, cmd.mode)


class _Lazy:
    """A fleet entry validated on the fast path: its state dict, its message view on demand.

    Reads like the TrainState-like view of :func:`fleet_state.entries` (built
    only when a train's step falls outside its window and :meth:`AtoController.answer`
    takes over).
    """

    def __init__(self, msg: FleetState, tid: str, state: dict[str, Any], echo: bool) -> None:
        self.msg, self.tid, self.state, self.echo = msg, tid, state, echo
        self._view: Any = None

    def __getattr__(self, name: str) -> Any:
        """A field of the entry's TrainState-like view (built on first use)."""
        if self._view is None:
            views = fleet_state.entries(self.msg, FleetLink.TOPIC_STATE, {self.tid: None})
            self._view = dict(views)[self.tid]
        return getattr(self._view, name)


EXECUTOR_PERIOD_S = 0.25
"""Wall period of the executor spin (parameter and type-description services, the 1 Hz
/diagnostics timers) [s]; the fleet states and departure commands are polled directly.
Each spin rebuilds a wait set of ~200 entities (15 nodes): every 50 ms of wall time that
was most of an ATO process's CPU on a loaded machine (the simulator spins at
the same period)."""

PLANNED_POINTS = 200
"""Samples of the planned speed curve carried by a SpeedProfile message."""


def planned_curve(prof: Profile) -> tuple[list[float], list[float]]:
    """The plan's speed over chainage, at most PLANNED_POINTS samples ([m], [m/s])."""
    s = np.asarray(prof.s_grid, dtype=float)
    v = np.asarray(prof.v_profile, dtype=float)
    if s.size == 0 or s.size != v.size:
        return [], []
    idx = np.unique(np.linspace(0, s.size - 1, min(s.size, PLANNED_POINTS)).astype(int))
    d = 1.0 if prof.x_stop_m >= prof.x_start_m else -1.0
    x = prof.x_start_m + d * s[idx]
    ok = np.isfinite(x) & np.isfinite(v[idx])
    return [float(a) for a in x[ok]], [float(b) for b in v[idx][ok]]


def build_nodes() -> list[Node]:
    """Create one ATO node per hosted train (``train_ids`` or the namespace)."""
    probe = Node("ato_controller")
    ids = declare(probe, "train_ids", [""], "trains hosted by this process")
    name = declare(probe, "scenario", "taipei_blue", "scenario")
    ns = probe.get_namespace().strip("/")
    probe.destroy_node()
    ids = [t for t in ids if t] or ([ns] if ns else [])
    dup = sorted({t for t in ids if ids.count(t) > 1})
    if dup:
        raise NodeConfigError(f"train_ids: {', '.join(dup)} given more than once "
                              "(one ATO per train)")
    if not ids:
        raise NodeConfigError("no train: set -p train_ids:=[train_01,...] or run in a "
                              "train namespace (-r __ns:=/train_01)")
    try:
        scn = load_run_scenario(name)
    except ScenarioError as exc:
        raise NodeConfigError(str(exc)) from None
    tt = timetable_for(scn)
    shared: dict[str, Any] = {}
    return [AtoController(t, scenario=scn, timetable=tt, shared=shared) for t in ids]


def main(args: Sequence[str] | None = None) -> int:
    """Entry point of the ``ato_controller`` executable."""
    def loop(executor: SingleThreadedExecutor, nodes: Sequence[Node]) -> None:
        atos = [n for n in nodes if isinstance(n, AtoController)]
        subs = [s for n in atos for s in n.fast_subs]
        if atos:
            link = FleetLink(atos)
            subs[:0] = [link.dispatch_sub, link.sub]
        spin_fast(executor, nodes, subs, slow_period_s=EXECUTOR_PERIOD_S)

    return run_nodes(build_nodes, loop, args)


if __name__ == "__main__":
    raise SystemExit(main())
