"""line_simulator node: the metro line plant, ATP and the simulation clock.

Publishes ``/clock`` (every ``clock_period_s``), ``/line/fleet_state`` (every lockstep
step: the states of all active trains in one message), per-train ``/<train>/state`` (every
``train_state_period_s`` of simulated time, and every step for a train not answered by a
fleet command), ``/line/brake_sensors`` (one FleetBrakeSensorData per
``sensor_batch_period_s``: every train's brake sensor samples of those steps),
``/<train>/brake_sensors`` (the same samples per train, best effort, only while the topic
has a reader), ``/line/events`` and ``/line/status``; subscribes to ``/line/fleet_command``
(the commands of one ATO process per message, taken as CDR bytes), ``/<train>/command``
(ATO traction/brake of one train) and ``/<train>/departure_command`` (ATS); serves
``/line/dispatch`` (the dispatcher's commands, :mod:`metro_atc.core.dispatcher_commands`,
applied at a step boundary and published on ``/line/dispatcher_commands``).  The fleet
state, ``/clock`` and the sensor batches go out as CDR bytes (:mod:`metro_atc.nodes.wire`).

Lockstep (default): step k -> k+1 happens only once every active train's command for step
k has arrived; on ``step_timeout_s`` the last command is applied (ATP still supervises), the
miss is counted and a warning logged. Free-run: steps are paced at ``real_time_factor``.
The physics, ATP and KPIs are the ROS-free :class:`metro_atc.core.plant.line.LineSim`.

Resume (``checkpoint_dir``): periodic checkpoints of the plant and the node's counters,
and a write-ahead journal of the departure commands applied; a respawned simulator resumes
from the last checkpoint, publishes the restored event history again and re-applies the
journaled commands at their steps (:mod:`metro_atc.nodes.sim_checkpoints`).

The node declares its parameters (:mod:`~metro_atc.nodes.sim_params`), creates its
publishers and subscriptions (QoS), converts and validates the messages, and sequences its
collaborators: the plant (``LineSim``), the fleet-state carrier
(:mod:`~metro_atc.nodes.sim_fleet`), the departure bookkeeping
(:mod:`~metro_atc.nodes.sim_departures`), the brake-sensor outbox
(:mod:`~metro_atc.nodes.sim_sensors`), the checkpoints, the run's files
(:mod:`~metro_atc.nodes.sim_outputs`); :mod:`~metro_atc.nodes.sim_lockstep` drives it and
:mod:`~metro_atc.nodes.sim_domain` keeps it alone on its ROS domain.
"""

from __future__ import annotations

import time
from functools import partial
from typing import Any, Sequence

import numpy as np
from diagnostic_msgs.msg import DiagnosticStatus
from metro_atc_msgs.msg import (BrakeDiagnosis, BrakeSensorData, DepartureCommand,
                                FleetBrakeSensorData, FleetCommand, FleetState,
                                LineStatus, SpeedProfile, TractionCommand,
                                TrainEvent, TrainState)
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.serialization import deserialize_message
from rosgraph_msgs.msg import Clock

from metro_atc.core.ato_watchdog import AtoWatchdog
from metro_atc.core.checkpoint import content_hash
from metro_atc.core.plant.kpi import service_end
from metro_atc.core.plant.line import LineSim
from metro_atc.core.plant.snapshot import scenario_hash
from metro_atc.core.line.scenario import ScenarioError, load_scenario
from metro_atc.core.validate import Rejections, bounds_for
from metro_atc.nodes import conversions as conv
from metro_atc.nodes.common import (FLEET_SENSOR_TOPIC, QOS_CLOCK, QOS_EVENTS,
                                    QOS_FLEET_SENSOR, QOS_LATCHED, QOS_LATCHED_IN,
                                    QOS_RELIABLE, QOS_SENSOR, OK, WARN, GraphNotReady,
                                    NodeConfigError, WarnLimiter,
                                    bulk_publisher, bulk_subscription, diag_status,
                                    run_nodes, spin_until_stopped)
from metro_atc.nodes.sim_checkpoints import Checkpoints, journal_key
from metro_atc.nodes.sim_day import NOT_IN_GRAPH, DayHost, day_run_for
from metro_atc.nodes.sim_departures import DepartureBook
from metro_atc.nodes.sim_dispatch import DispatchDesk
from metro_atc.nodes.sim_domain import (LINGER_S, RECORDER_GATE_TOPIC, linger, subscribed_by,
                                        wait_acked)
from metro_atc.nodes.sim_fleet import FleetStatePublisher
from metro_atc.nodes.sim_lockstep import RECORDER_SYNC_STEPS, SilenceWatch, lockstep_loop
from metro_atc.exit_codes import Exit, outcome
from metro_atc.nodes.sim_outputs import regulator_label, write_finished_file, write_outputs
from metro_atc.nodes.sim_params import SimParams
from metro_atc.nodes.sim_sensors import SensorOutbox
from metro_atc.nodes.wire import fleet_command


_REGULATOR_NAMES = {code: name for name, code in conv.REGULATOR_CODES.items()}
"""DepartureCommand.regulator codes -> regulator names (what ran, for the KPIs)."""

NODE_STATE = ("k", "cmd_step", "cmd_effort", "lockstep_misses", "rejected", "rejections",
              "event_seq", "sensor_last_t", "dep_received", "dep_given_up", "ats_misses",
              "_next_status_t", "_next_progress_t", "regulators", "planners", "planned",
              "watchdog", "brake_assessed", "dispatch_state")
"""Node attributes saved with the plant in a checkpoint."""
_STATE_ELSEWHERE = {"sensor_last_t": ("sensors", "last_t"),
                    "dep_received": ("departures", "received"),
                    "dep_given_up": ("departures", "given_up"),
                    "ats_misses": ("departures", "ats_misses"),
                    "regulators": ("departures", "regulators"),
                    "brake_assessed": ("sensors", "assessed"),
                    "dispatch_state": ("desk", "state")}
"""The :data:`NODE_STATE` values a collaborator holds: name -> (node attribute, its
attribute)."""


class LineSimulator(Node):
    """The plant node (see module docstring)."""

    def __init__(self, **kwargs: Any) -> None:
        """Declare parameters, load the scenario, create the publishers and subscriptions."""
        super().__init__("line_simulator", **kwargs)
        self.params = SimParams(self, self.health, self._set_progress_period)
        """The node's parameters (:mod:`metro_atc.nodes.sim_params`)."""
        self._next_progress_t = self.params.progress_period_s
        self.wall0 = time.monotonic()
        try:
            run = day_run_for(self.params.scenario_name)
            scn = load_scenario(self.params.scenario_name) if run is None else None
        except (ScenarioError, ValueError) as exc:
            raise NodeConfigError(str(exc)) from None
        self.day = None if run is None else DayHost(run, int(self.params.seed),
                                                    self.params.day_regulator)
        """The service day the plant runs (:mod:`metro_atc.nodes.sim_day`), or None."""
        if self.day is not None:
            if self.params.checkpoint_dir:
                raise NodeConfigError("checkpoint_dir: a service day is not checkpointed "
                                      "(no resume); leave it empty")
            self.sim = self.day.sim
            self.get_logger().info(f"{self.day.summary}; not through the graph: "
                                   f"{'; '.join(NOT_IN_GRAPH)}")
        else:
            assert scn is not None
            self.sim = LineSim(scn, seed=int(self.params.seed))
        scn = self.sim.scn
        self.bounds = bounds_for(scn)
        self.rejections = Rejections()
        """Rejected input messages per kind (:mod:`metro_atc.core.validate`)."""
        self.desk = DispatchDesk(self, self.sim, int(self.params.dispatch_queue_max),
                                 self.params.replay_commands, self.rejections,
                                 closed="a service day run takes no dispatcher commands"
                                 if self.day is not None else "")
        """The dispatcher's desk: /line/dispatch and the applied commands."""
        self.watchdog = AtoWatchdog(len(self.sim.train_ids), int(self.params.ato_lost_steps))
        """Lost-ATO decision (:mod:`metro_atc.core.ato_watchdog`)."""
        self.ids: list[str] = list(self.sim.train_ids)
        self.index = {tid: i for i, tid in enumerate(self.ids)}
        n = len(self.ids)
        self.k = 0 if self.day is None else self.day.first_step
        """Lockstep step index: its state's time is k control periods (a day starts late)."""
        self.cmd_step = np.full(n, -1, dtype=np.int64)
        self.cmd_effort = np.full(n, np.nan)
        self.lockstep_misses = 0
        self.rejected = 0
        self.event_seq = np.zeros(n, dtype=np.int64)
        self.departures = DepartureBook(n, len(self.sim.station_names))
        """Departure commands received or given up (:mod:`metro_atc.nodes.sim_departures`)."""
        self._warn_rate_limited = WarnLimiter(self)
        self._next_status_t = 0.0
        self.finished = False
        self.started = False
        self.silence = SilenceWatch()
        """Wall time (``time.monotonic``) of the first of the consecutive timed-out lockstep
        steps in which no active train's ATO answered (None: an ATO answered the last step)."""
        self.loop_span: tuple[float, float] | None = None
        """(wall time, simulated time) of the stepping loop from its first step to the end
        [s] (None before its end)."""
        self.planners: dict[str, int] = {}
        self.planned: dict[int, dict[int, tuple[np.ndarray, np.ndarray]]] = {}
        self._health_last = (time.monotonic(), 0.0, 0, 0)
        self.fleet_driven = np.zeros(n, dtype=bool)
        """Trains whose ATO answered a fleet state (their per-train state is decimated)."""
        self._cmd_ids: tuple[dict[bytes, int], dict[tuple[bytes, ...], np.ndarray]] = (
            {tid.encode("utf-8"): i for i, tid in enumerate(self.ids)}, {})
        """For the serialized fleet commands: train id (UTF-8) -> index, and the train
        indices of each train list seen (bounded)."""
        p = self.params
        dt = float(self.sim.control_period_s)
        clock_period = float(p.train_state_period_s if p.clock_period_s < 0
                             else p.clock_period_s)
        clock_pub = self.create_publisher(Clock, "/clock", QOS_CLOCK)
        self.event_pub = self.create_publisher(TrainEvent, "/line/events", QOS_EVENTS)
        self.status_pub = self.create_publisher(LineStatus, "/line/status", QOS_LATCHED)
        # (nothing is published here: a recorder subscribes once it matched every publisher)
        self.gate_pub = self.create_publisher(DiagnosticStatus, RECORDER_GATE_TOPIC,
                                              QOS_LATCHED) \
            if self.params.wait_for_subscribers else None
        state_pubs = [bulk_publisher(self, TrainState, f"/{t}/state", QOS_RELIABLE)
                      for t in self.ids]
        self.fleet = FleetStatePublisher(
            self.ids, self.sim,
            bulk_publisher(self, FleetState, "/line/fleet_state", QOS_RELIABLE), state_pubs,
            clock_pub, state_every=max(1, int(round(p.train_state_period_s / dt))),
            clock_every=max(1, int(round(clock_period / dt))))
        """The fleet state, per-train states and /clock (:mod:`metro_atc.nodes.sim_fleet`)."""
        # raw: the commands are read from their CDR bytes (fleet_command.efforts_cdr)
        self.fleet_sub = self.create_subscription(
            FleetCommand, "/line/fleet_command", self._on_fleet_command, QOS_RELIABLE,
            raw=True, event_callbacks=SubscriptionEventCallbacks(use_default_callbacks=False))
        self.sensors = SensorOutbox(
            self, self.ids,
            bulk_publisher(self, FleetBrakeSensorData, FLEET_SENSOR_TOPIC, QOS_FLEET_SENSOR),
            [bulk_publisher(self, BrakeSensorData, f"/{t}/brake_sensors", QOS_SENSOR)
             for t in self.ids], self.params, self.fleet.ids_block, self._warn_rate_limited)
        """The brake sensor outbox (:mod:`metro_atc.nodes.sim_sensors`)."""
        self.cmd_subs = [bulk_subscription(self, TractionCommand, f"/{t}/command",
                                           partial(self._on_command, i), QOS_RELIABLE)
                         for i, t in enumerate(self.ids)]
        self.dep_subs = [bulk_subscription(self, DepartureCommand, f"/{t}/departure_command",
                                           partial(self._on_departure, i), QOS_LATCHED_IN)
                         for i, t in enumerate(self.ids)]
        # what actually ran (KPIs): the planner of every profile the ATOs published
        self.profile_subs = [bulk_subscription(self, SpeedProfile, f"/{t}/speed_profile",
                                               self._on_profile, QOS_LATCHED)
                             for t in self.ids]
        """Per train: its brake diagnosis said the brake was assessed (its latest, latched
        BrakeDiagnosis: cumulative, so a restarted simulator has it back at once)."""
        self.diag_subs = [bulk_subscription(self, BrakeDiagnosis, f"/{t}/brake_diagnosis",
                                            partial(self._on_diagnosis, i), QOS_LATCHED)
                          for i, t in enumerate(self.ids)]
        identity = content_hash(scenario_hash(self.sim), bool(p.lockstep),
                                int(p.ato_lost_steps), float(p.max_sim_time_s))
        # what a checkpoint must have been made for (scenario content, seed, parameters)
        self.checkpoints = Checkpoints(p.checkpoint_dir, identity, p.checkpoint_period_s,
                                       self.sim.control_period_s, self.get_logger(),
                                       self._warn_rate_limited)
        """Checkpoints and the departure journal (:mod:`metro_atc.nodes.sim_checkpoints`)."""
        restored = self.checkpoints.open(self.sim, self._node_state())
        if restored is not None:
            self._set_node_state(restored)
            self.republish_history()
        self.get_logger().info(
            f"scenario '{self.params.scenario_name}': {n} trains, {len(self.sim.station_names)} "
            f"stations, control period {self.sim.control_period_s} s, "
            f"{'lockstep' if self.params.lockstep else f'free-run x{self.params.rtf}'}")

    # ------------------------------------------------------------------ inputs
    def _reject(self, what: str, exc: conv.MessageRejected) -> None:
        """Count a rejected message per kind; log it (at most 1/s per kind, all counts)."""
        self.rejected += 1
        line = self.rejections.note(what, exc, time.monotonic())  # per-kind rate limit
        if line is not None:
            self.get_logger().warning(line)

    def _on_command(self, i: int, msg: TractionCommand) -> None:
        """Take train i's command for the current step k only (see conv.traction_from_msg)."""
        try:
            effort = conv.traction_from_msg(msg, f"/{self.ids[i]}/command", self.ids[i],
                                            self.k, float(self.sim.t),
                                            late_echo=bool(self.fleet_driven[i]))
        except conv.MessageRejected as exc:
            self._reject("command", exc)
            return
        if effort is None:
            return  # stale duplicate from the previous step
        self.cmd_step[i] = self.k
        self.cmd_effort[i] = effort

    def _on_fleet_command(self, msg: "bytes | FleetCommand") -> None:
        """Take the commands of one ATO process for step k (each entry as a /<t>/command).

        ``msg``: the serialized message (the raw subscription) or a message object. The
        bytes of a clean message are read with :func:`fleet_command.efforts_cdr`;
        anything else is deserialized and takes the object path (its rejections counted
        as for a message object; bytes rclpy cannot read: kind ``cdr``).
        """
        topic = "/line/fleet_command"
        if isinstance(msg, bytes):
            id_bytes, ix_cache = self._cmd_ids
            if len(ix_cache) > 256:
                ix_cache.clear()  # a writer cycling through train lists
            fast = fleet_command.efforts_cdr(msg, topic, id_bytes, ix_cache,
                                             self.k, float(self.sim.t))
            if fast is not None:
                self._take_fleet(*fast)
                return
            try:
                msg = deserialize_message(msg, FleetCommand)
            except Exception as exc:  # noqa: BLE001 - any byte string may arrive raw
                self._reject("fleet command", conv.MessageRejected(
                    "cdr", f"{topic}: not a FleetCommand ({str(exc)[:80]})"))
                return
        try:
            fast = fleet_command.efforts(msg, topic, self.index, self.k, float(self.sim.t))
            if fast is not None:
                self._take_fleet(*fast)
                return
            entries = fleet_command.entries(msg, topic, self.index)
        except conv.MessageRejected as exc:
            self._reject("fleet command", exc)
            return
        # some entry breaks a rule: entry by entry, each rejection counted
        self._take_entries(topic, entries)

    def _take_fleet(self, ix: np.ndarray, efforts: np.ndarray | None) -> None:
        """Take a whole fleet command: trains ``ix``, their efforts (None: a stale one)."""
        # the trains' ATO answers the fleet state (see _take_entries)
        self.fleet_driven[ix] = True
        if efforts is not None:
            self.cmd_step[ix] = self.k
            self.cmd_effort[ix] = efforts

    def _take_entries(self, topic: str, entries: list[tuple[int, Any]]) -> None:
        """Take a fleet command entry by entry (some entry breaks a rule: each counted)."""
        for i, e in entries:
            try:
                # an entry of an earlier step is a duplicate (an ATO's answer to a fleet
                # state published again, e.g. for a late subscriber): the lockstep took that
                # step already, so it is dropped without counting, like a per-train echo
                effort = conv.traction_from_msg(e, topic, self.ids[i], self.k,
                                                float(self.sim.t), late_echo=True)
            except conv.MessageRejected as exc:
                self._reject("fleet command", exc)
                continue
            # the train's ATO answers the fleet state, even when its per-train echo of the
            # same command came first (a race): from now on its per-train state is thinned
            self.fleet_driven[i] = True
            if effort is None:
                continue
            self.cmd_step[i] = self.k
            self.cmd_effort[i] = effort

    def _on_departure(self, i: int, msg: DepartureCommand) -> None:
        """Validate an ATS departure command before it reaches the plant's table."""
        topic = f"/{self.ids[i]}/departure_command"
        try:
            st, dep, run, dwell = conv.departure_from_msg(msg, topic, self.ids[i], self.bounds)
            key = (i, st, dep, run, dwell, int(msg.regulator))
            if self.checkpoints.is_journaled(key):
                return  # applied (or to be applied) from the journal at its original step
            # journaled first: a kill between the two replays it at this step on resume
            # (applied first, a kill in between would lose the step it was applied at)
            self.checkpoints.journal(self.k, key)
            conv.guarded(topic, self._apply_departure, *key)
        except conv.MessageRejected as exc:
            self._reject("departure command", exc)

    def _apply_departure(self, i: int, st: int, dep: float, run: float, dwell: float,
                         regulator: int) -> None:
        """Hand a validated departure command to the plant; count the regulator."""
        self.sim.set_departure(i, st, dep, run, dwell)
        self.departures.receive(i, st, _REGULATOR_NAMES.get(int(regulator),
                                                            f"code {regulator}"))

    # ------------------------------------------------------------------ resume
    def _state_owner(self, name: str) -> tuple[Any, str]:
        """The object and attribute holding the :data:`NODE_STATE` value ``name``."""
        if name in _STATE_ELSEWHERE:
            owner, attr = _STATE_ELSEWHERE[name]
            return getattr(self, owner), attr
        return self, name

    def _node_state(self) -> dict[str, Any]:
        """The node's part of a checkpoint (:data:`NODE_STATE`), by name."""
        return {a: getattr(*self._state_owner(a)) for a in NODE_STATE}

    def _set_node_state(self, holder: Any) -> None:
        """Take the :data:`NODE_STATE` values of a restored checkpoint ``holder``."""
        for a in NODE_STATE:
            setattr(*self._state_owner(a), getattr(holder, a))

    def _replay_departures(self) -> None:
        """Re-apply the journaled departure commands of the current step (after a resume)."""
        for e in self.checkpoints.take_replay(self.k):
            try:
                self._apply_departure(*journal_key(e))
            except (IndexError, ValueError, TypeError) as exc:
                self.get_logger().error(f"journaled departure command {e} not applied: {exc}")

    def republish_history(self) -> None:
        """Publish the restored event history again (a restarted ATS replays it).

        The dispatcher's applied commands too (a restarted ATO learns its TSRs).
        """
        seq = np.zeros(len(self.ids), dtype=np.int64)
        for ev in self.sim.event_log():
            seq[ev.train_idx] += 1
            self.event_pub.publish(conv.event_msg(ev, self.ids, self.sim.station_names,
                                                  int(seq[ev.train_idx])))
        self.desk.republish()

    def _on_profile(self, msg: SpeedProfile) -> None:
        name = str(msg.planner)[:32] or "unknown"
        self.planners[name] = self.planners.get(name, 0) + 1
        i = self.index.get(str(msg.train_id))
        x = np.asarray(msg.planned_position_m, dtype=float)
        v = np.asarray(msg.planned_speed_mps, dtype=float)
        if i is not None and x.size and x.size == v.size and np.isfinite(x).all() \
                and np.isfinite(v).all():
            # the latest plan of each run is the one that was tracked (for the plots)
            self.planned.setdefault(i, {})[int(msg.from_station)] = (x, v)

    def _on_diagnosis(self, i: int, msg: BrakeDiagnosis) -> None:
        """Take the newest sample train i's brake diagnosis acknowledges (its stamp)."""
        try:
            t = conv.diagnosis_ack_s(msg, f"/{self.ids[i]}/brake_diagnosis", self.ids[i],
                                     self.bounds)
        except conv.MessageRejected as exc:
            self._reject(f"/{self.ids[i]}/brake_diagnosis", exc)
            return
        self.sensors.acknowledge(i, t, bool(msg.assessed))

    def _set_progress_period(self, value: float) -> None:
        self.params.progress_period_s = float(value)
        self._next_progress_t = float(self.sim.t) + self.params.progress_period_s \
            if hasattr(self, "sim") else self.params.progress_period_s

    # ------------------------------------------------------------------ health
    def health(self) -> list[DiagnosticStatus]:
        """/diagnostics: the lockstep's progress, misses and real-time factor (wall period).

        WARN when a lockstep step timed out during the last period, or when the simulated
        seconds per wall second over the period fell below ``min_real_time_factor`` (in
        free-run: below 90 % of the requested ``real_time_factor``).
        """
        now = time.monotonic()
        w0, t0, k0, m0 = self._health_last
        t = float(self.sim.t)
        self._health_last = (now, t, self.k, self.lockstep_misses)
        dw = max(now - w0, 1e-9)
        rtf = (t - t0) / dw
        steps = self.k - k0
        misses = self.lockstep_misses - m0
        level, msg = OK, "running"
        want = self.params.min_rtf if self.params.lockstep else 0.9 * self.params.rtf
        if not self.started:
            msg = "waiting for the graph before step 0"
        elif self.finished:
            msg = "scenario finished"
        elif misses > 0:
            level, msg = WARN, f"{misses} lockstep steps timed out in the last {dw:.1f} s"
        elif rtf < want:
            level, msg = WARN, f"real-time factor {rtf:.2f} below {want:.2f}"
        return [diag_status("line_simulator: lockstep", "line", level, msg, {
            "step": self.k, "sim_time_s": t, "steps_per_s": steps / dw,
            "real_time_factor": rtf,
            "step_time_ms": 1e3 * dw / steps if steps else float("nan"),
            "lockstep": self.params.lockstep, "lockstep_misses": self.lockstep_misses,
            "fleet_state_resends": self.fleet.resends,
            "lockstep_misses_in_period": misses, "ats_timeouts": self.departures.ats_misses,
            "rejected_messages": self.rejected,
            "rejected_by_kind": self.rejections.summary(),
            "ato_losses": self.watchdog.losses,
            "ato_stop_steps": int(self.watchdog.stop_steps),
            **{f"dispatch_{k}": (", ".join(f"{a} {b}" for a, b in v.items()) or "none")
               if isinstance(v, dict) else v
               for k, v in self.desk.dispatcher.counters().items()},
            "trains_in_service": int(np.count_nonzero(self.sim.active_mask()))})]

    # ------------------------------------------------------------------ stepping
    def graph_ready(self) -> bool:
        """Every train has an ATO, the ATS and the brake diagnosis connected.

        An ATO is there when its command topic has a publisher and the fleet state a
        subscriber (an ATO process that matches the fleet state late gets it again:
        :meth:`FleetStatePublisher.publish_again`).

        With ``wait_for_subscribers``, each named node must also subscribe to every topic
        the simulator publishes, the recorder gate included (``RECORDER_GATE_TOPIC``: the
        bag_recorder subscribes to it once it has matched every publisher it records; a
        recorder then has step 0).
        """
        ready = not self.graph_missing()
        if not ready or not self.params.wait_for_subscribers:
            return ready
        return subscribed_by(self, self._recorded_pubs(), self.params.wait_for_subscribers)

    def graph_missing(self) -> list[str]:
        """The endpoints :meth:`graph_ready` waits for that are not there (short names)."""
        missing = []
        if self.fleet.fleet_pub.get_subscription_count() == 0:
            missing.append("a /line/fleet_state reader (ATO)")
        missing += [f"{s.topic_name} writer (ATO)" for s in self.cmd_subs
                    if s.get_publisher_count() == 0]
        if self.day is None:  # a day's departures come from its day plant (no ATS)
            missing += [f"{s.topic_name} writer (ATS)" for s in self.dep_subs
                        if s.get_publisher_count() == 0]
        if self.sensors.fleet_pub.get_subscription_count() == 0:
            missing.append(f"a {self.sensors.fleet_pub.topic_name} reader (brake_diagnostic)")
        return missing

    def _recorded_pubs(self) -> list[Any]:
        """The publishers a recorder (``wait_for_subscribers``) must read."""
        gate = [self.gate_pub] if self.gate_pub is not None else []
        return [self.fleet.clock_pub, self.event_pub, self.status_pub, *self.fleet.state_pubs,
                self.sensors.fleet_pub, self.desk.pub, *gate]

    def wait_acked(self, timeout_s: float = 5.0) -> None:
        """Wait until every reliable reader acknowledged what was published (a recorder).

        With ``wait_for_subscribers`` the lockstep calls this once after the last step, so
        the last messages reach the recorder before the process exits (a reliable writer
        that exits cannot resend). During the run the writers' histories (1 000 clock
        ticks, 500 states) cover a recorder that falls behind by less than that; the lockstep
        waits here every ``RECORDER_SYNC_STEPS`` steps so it never falls further
        (acknowledgements come with the DDS heartbeat, ~1 s: not every step).
        """
        wait_acked(self._recorded_pubs(), timeout_s, self.get_logger())

    def publish_step(self) -> np.ndarray:
        """Publish /clock and the states of step k; return the active mask.

        After a resume, the journaled departure commands of step k are applied first.
        :meth:`publish_clock` then :meth:`publish_lockstep` (the lockstep loop mostly calls
        them apart: :meth:`step_and_publish`).
        """
        self.publish_clock()
        return self.publish_lockstep()

    def publish_clock(self) -> None:
        """Publish /clock at the time of step k (every ``clock_every`` steps)."""
        self.fleet.publish_clock(self.k)

    def publish_lockstep(self) -> np.ndarray:
        """Publish what the ATOs answer at step k: the fleet state, the per-train states.

        After a resume, the journaled departure commands of step k are applied first (the
        states carry the departure times). Returns the active mask.
        """
        if self.checkpoints.replay:
            self._replay_departures()
        if self.day is not None:
            self.day.begin()  # pull-outs, routes and authorities: what the states carry
        return self.fleet.publish(self.k, self.fleet_driven)

    def commands_complete(self, active: np.ndarray) -> bool:
        """Check the lockstep barrier of step k.

        True when all active trains sent their command for step k and the ATS has decided
        the departure of every train dwelling at a station (lockstep on the ATS as well).
        """
        fleet = self.fleet
        idx = fleet.active_idx if fleet.active_idx_k == self.k else np.flatnonzero(active)
        return (idx.size == 0 or int(self.cmd_step[idx].min()) >= self.k) \
            and not self.pending_departures()

    def waited_trains(self) -> np.ndarray:
        """Active trains whose per-train command the lockstep waits on (no fleet answer yet)."""
        return self.fleet.active & ~self.fleet_driven

    def pending_departures(self) -> list[tuple[int, int]]:
        """(train, station) pairs dwelling without an ATS departure command yet.

        None in a service day: the day plant commands its departures.
        """
        return [] if self.day is not None else self.departures.pending(self.k, self.sim)

    def advance(self, active: np.ndarray, timed_out: bool) -> None:
        """Apply the commands, step the core and publish its outputs."""
        res, done = self.step_plant(active, timed_out)
        self.publish_outputs(res, done)

    def step_and_publish(self, active: np.ndarray, timed_out: bool) -> np.ndarray | None:
        """Lockstep: :meth:`advance`, then :meth:`publish_step` of the new step k.

        The fleet state and per-train states of step k (what the ATOs wait for) go out right
        after the plant step, before the step's events, sensor samples, ``/line/status``,
        progress line and ``/clock`` (in that order, as in :meth:`advance` then
        :meth:`publish_step`): those are made while the ATOs compute.  Every message and its
        content are the same; only the fleet and per-train states move ahead of the others
        of the same step (publishing them changes no state a checkpoint holds).  At the
        last step, at a checkpoint with journaled departure commands of step k to replay
        (the checkpoint describes the state before them) and at a recorder sync step the
        order is that of :meth:`advance` then the caller's :meth:`publish_step`.  Returns
        the active mask of step k, or None when step k's states were not published here
        (the caller publishes them, unless finished).
        """
        res, done = self.step_plant(active, timed_out)
        ck = self.checkpoints
        if done or (ck.replay and ck.replay_due(self.k) and ck.due(self.k)) or (
                self.params.wait_for_subscribers and self.k % RECORDER_SYNC_STEPS == 0):
            self.publish_outputs(res, done)
            return None
        nxt = self.publish_lockstep()
        self.publish_outputs(res, done)
        self.fleet.publish_clock(self.k)
        return nxt

    def step_plant(self, active: np.ndarray, timed_out: bool) -> tuple[Any, bool]:
        """Apply the commands of step k and step the core (k -> k + 1).

        Returns the core's step result and whether the run is done (scenario end or
        ``max_sim_time_s``).
        """
        if timed_out:
            self._check_not_silent(active)
            missing = [self.ids[i] for i in np.flatnonzero(active & (self.cmd_step < self.k))]
            if self.day is None:
                for i, j in self.departures.give_up_pending(self.k, self.sim):
                    missing.append(f"ATS for {self.ids[i]} at station {j} (timetable used)")
            self.lockstep_misses += 1
            self._warn_rate_limited(
                "lockstep", f"lockstep step {self.k}: no command from {', '.join(missing[:5])}"
                f"{' ...' if len(missing) > 5 else ''}; applying the last command")
        else:
            self.silence.answered()
        self.desk.take_requests()
        self.desk.apply(self.k)
        effort, wd_events = self.watchdog.apply(self.k, active, self.cmd_step >= self.k,
                                                self.cmd_effort)
        for e in wd_events:
            self._log_watchdog(e)
        res = self.sim.step(effort) if self.day is None else self.day.step(effort)
        self.k += 1
        t = float(self.sim.t)
        end = self.params.max_sim_time_s
        cut = end > 0 and t - self._t0 >= end
        done = bool(self.sim.done if self.day is None else self.day.done) or cut
        return res, done

    def _check_not_silent(self, active: np.ndarray) -> None:
        """Give up (:class:`GraphNotReady`) when no ATO answered for ``ato_absent_timeout_s``.

        Called at a timed-out step: a step in which no active train's ATO answered starts
        (or continues) a silence; one answer ends it.  A simulator whose ATOs never appeared
        would otherwise step once per ``step_timeout_s`` until the scenario's end.
        """
        answered = bool(active.any()) and bool((self.cmd_step[active] >= self.k).any())
        if answered or not active.any():
            self.silence.answered()
            return
        silent_s = self.silence.timed_out(time.monotonic(), self.params.step_timeout_s)
        limit = self.params.ato_absent_timeout_s
        if silent_s >= limit:
            missing = self.graph_missing()
            raise GraphNotReady(
                f"no ATO answered for {silent_s:.0f} s of wall time "
                f"(ato_absent_timeout_s {limit:g} s; step {self.k}, t={float(self.sim.t):.1f} "
                f"s); missing: {', '.join(missing[:6]) or 'no endpoint (commands lost)'}"
                f"{' ...' if len(missing) > 6 else ''}; giving up")

    def publish_outputs(self, res: Any, done: bool) -> None:
        """Publish the outputs of the step that led to step k (:meth:`step_plant`).

        Its events, brake sensor samples, progress line, ``/line/status``; at the end the
        last sensor batch, else the batch and checkpoint when due.
        """
        for ev in res.events:
            self.event_seq[ev.train_idx] += 1
            self.event_pub.publish(conv.event_msg(ev, self.ids, self.sim.station_names,
                                                  int(self.event_seq[ev.train_idx])))
        self.sensors.take(res.sensor_arrays)
        t = float(self.sim.t)
        if t >= self._next_progress_t:
            self._next_progress_t += self.params.progress_period_s
            wall = time.monotonic() - self.wall0
            self.get_logger().info(
                f"t={t:.0f} s: {int(np.count_nonzero(self.sim.active_mask()))} trains in "
                f"service, {self.lockstep_misses} lockstep misses, "
                f"{(t - self._t0) / wall if wall > 0 else 0.0:.1f}x real time")
        if t >= self._next_status_t or done:
            self._next_status_t = t + self.params.status_period_s
            self.status_pub.publish(conv.line_status_msg(self.kpis(), self.k, t, done))
        if done:
            self.finished = True
            self.sensors.flush(t, force=True)
        else:
            due = self.checkpoints.due(self.k)
            self.sensors.flush(t, force=due)
            if due:
                self.checkpoints.save(self.k, t, self.sim, self._node_state())

    def _log_watchdog(self, e: Any) -> None:
        """Log a lost ATO (error) or its return (warning)."""
        t = f"{self.ids[e.train]} at t={float(self.sim.t):.2f} s (step {e.step})"
        if e.kind == "lost":
            self.get_logger().error(f"ATO of {t} lost: no command for {e.missed} steps; "
                                    "braking the train to a stop")
        else:
            self.get_logger().warning(f"ATO of {t} back after {e.missed} missed steps; "
                                      "handing the train back")

    def announce_finished(self) -> None:
        """Write ``finished_file`` (if set): the run is over (:func:`write_finished_file`)."""
        wall, sim_s = self.loop_span if self.loop_span is not None else (None, 0.0)
        write_finished_file(self.params.finished_file, wall, sim_s,
                            self.get_logger())

    def kpis(self) -> dict[str, Any]:
        """The core's KPIs plus the node's lockstep/rejection counters."""
        k = dict(self.sim.kpis())
        k["lockstep_misses"] = int(self.lockstep_misses)
        k["rejected_messages"] = int(self.rejected)
        k["rejected_by_kind"] = self.rejections.as_dict()
        k["ats_timeouts"] = int(self.departures.ats_misses)
        k["ato_losses"] = int(self.watchdog.losses)
        k["ato_stop_steps"] = int(self.watchdog.stop_steps)
        k["steps"] = int(self.k)
        k["scenario"] = self.params.scenario_name
        k["lockstep"] = bool(self.params.lockstep)
        k["regulators_seen"] = dict(sorted(self.departures.regulators.items()))
        k["planners_seen"] = sorted(self.planners)  # names only: latched, depth-1 reader
        k["regulator"] = regulator_label(k["regulators_seen"])
        k["planner"] = ",".join(k["planners_seen"]) or "none"
        k["dispatcher"] = dict(self.desk.dispatcher.counters(),
                               replay=self.desk.dispatcher.replay
                               is not None)
        k["brake_assessed"] = dict(zip(self.ids, self.sensors.assessed))
        k["brake_trains_not_assessed"] = [t for t, a in zip(self.ids, self.sensors.assessed)
                                          if not a]
        if self.day is not None:
            k["day"] = self.day.kpis()
            k["sim_start_s"] = self._t0
            k["regulator"] = self.day.regulator
        return k

    def _cut_at_s(self) -> float | None:
        """Simulated time [s] at which ``max_sim_time_s`` (``--duration``) cut the run.

        None when it was not cut (the plant's own end came first, or no cut was set).
        """
        end, t = self.params.max_sim_time_s, float(self.sim.t)
        done = self.sim.done if self.day is None else self.day.done
        return t if end > 0 and t - self._t0 >= end and not done else None

    @property
    def _t0(self) -> float:
        """Simulated time of step 0 [s]: 0, or the first step of a service day."""
        return 0.0 if self.day is None else self.day.dp.t_start

    def final_kpis(self) -> dict[str, Any]:
        """:meth:`kpis` with whether the whole service ran (:func:`service_end`)."""
        k = self.kpis()
        if self.day is not None:
            k.update(self.day.end(self.finished, float(self.sim.t), self._cut_at_s()))
            return k
        k.update(service_end(int(k["trains"]), int(k["completed_trains"]), float(self.sim.t),
                             self.finished, self._cut_at_s(), float(self.sim.duration_s),
                             int(k.get("withdrawn_trains", 0))))
        return k

    def exit_code(self) -> int:
        """The process's exit code once the run ended (:func:`metro_atc.exit_codes.outcome`).

        Logs the reason of a run that did not complete (one error line).
        """
        code, why = outcome(self.final_kpis())
        if code != Exit.OK:
            self.get_logger().error(f"run not complete ({code.name}, exit {int(code)}): {why}")
        return int(code)

    def close(self) -> None:
        """Write the run's outputs (events CSV, plots, KPIs JSON) if an out_dir is set.

        At the end of a finished run, then wait (:func:`linger`, at most ``LINGER_S``) until
        the readers acknowledged the last samples (a reliable reader acknowledges on the
        writer's heartbeat: waited for before the outputs, that was most of ``LINGER_S`` at
        the end of every run).
        """
        self.checkpoints.wait()
        try:
            self._write_outputs()
        finally:
            if self.finished:
                linger(self, LINGER_S)

    def _write_outputs(self) -> None:
        """The outputs of :meth:`close` (:func:`write_outputs`)."""
        if not self.params.out_dir:
            return
        k = self.final_kpis()
        if self.day is not None:
            write_outputs(self.params.out_dir, self.sim, k, False, self.planned,
                          self.get_logger(), events=False)  # kpis.json
            try:
                self.day.write_outputs(self.params.out_dir)
            except Exception as exc:  # noqa: BLE001 - the KPIs are written: say what is not
                raise OSError(f"outputs not written: the day's KPI tables and pictures in "
                              f"{self.params.out_dir}: {exc}") from None
            return
        write_outputs(self.params.out_dir, self.sim, k, self.params.plots, self.planned,
                      self.get_logger(), dispatched=[
                          (a, self.desk.dispatcher.station_of(a))
                          for a in self.desk.dispatcher.log])


def main(args: Sequence[str] | None = None) -> int:
    """Entry point of the ``line_simulator`` executable."""
    def loop(executor: SingleThreadedExecutor, nodes: Sequence[Node]) -> int | None:
        node = nodes[0]
        assert isinstance(node, LineSimulator)
        lockstep_loop(executor, node)
        if not node.params.exit_on_finish:
            spin_until_stopped(executor)
        return node.exit_code() if node.finished else None

    return run_nodes(lambda: [LineSimulator()], loop, args)


if __name__ == "__main__":
    raise SystemExit(main())
