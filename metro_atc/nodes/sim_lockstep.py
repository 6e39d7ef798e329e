"""The line_simulator's stepping loop: lockstep on the ATOs' commands, or free-run.

:func:`lockstep_loop` drives a ``LineSimulator`` node (passed in: this module does not
import the node) through the members named by :class:`LockstepNode`, a Protocol the type
checker holds the node to: it waits for the graph, then steps the plant
whenever every command of the step arrived (or the step timed out), re-sending the fleet
state to late or restarted ATOs, and at the end drains the brake sensor outbox and announces
the finished run.  Wall times are ``time.monotonic`` seconds.
"""

from __future__ import annotations

import math
import time
from typing import Protocol

import numpy as np
from numpy.typing import NDArray
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.impl.rcutils_logger import RcutilsLogger
from rclpy.node import Node
from rclpy.subscription import Subscription

from metro_atc.core.plant.line import LineSim
from metro_atc.nodes.common import SubscriptionPoller, stop_requested
from metro_atc.nodes.sim_checkpoints import Checkpoints
from metro_atc.nodes.sim_domain import (ALONE_CHECK_S, ALONE_PERSIST_S, check_alone,
                                        check_not_refused, other_simulators)
from metro_atc.nodes.sim_fleet import FleetStatePublisher
from metro_atc.nodes.sim_params import SimParams
from metro_atc.nodes.sim_sensors import SensorOutbox

RECORDER_SYNC_STEPS = 250
"""While a recorder is waited for (``wait_for_subscribers``), every this many steps the
lockstep waits until every reliable reader acknowledged what was published: half the
500-state writer history, so a recorder slower than the graph loses no state (with the fast
tracker the graph outruns a recording node)."""
ECHO_PERIOD_S = 0.25
"""Wall period of the poll of the per-train command echoes, speed profiles, brake diagnoses
and the departure commands the lockstep does not wait for [s] (none is on the lockstep's
path: a departure command becomes waited for once its train dwells)."""
EXECUTOR_PERIOD_S = 0.25
"""Wall period of the executor spin in the node's own process (parameter services, the
/diagnostics timer) [s]."""
FLEET_RESEND_S = 2.0
"""Lockstep: wall time without every command of the step before the fleet-state entries
of the trains not answered are published again [s] (a state lost with a killed ATO)."""


class SilenceWatch:
    """Wall time for which no ATO answered the lockstep's timed-out steps [s] (ROS-free)."""

    def __init__(self) -> None:
        """No silence yet."""
        self.since: float | None = None

    def answered(self) -> None:
        """An ATO answered: the silence ends."""
        self.since = None

    def timed_out(self, now: float, step_timeout_s: float) -> float:
        """A step timed out unanswered at wall time ``now`` [s]; the silence so far [s].

        The first such step starts the silence ``step_timeout_s`` before ``now`` (the step
        waited that long).
        """
        if self.since is None:
            self.since = now - step_timeout_s
        return now - self.since


class LockstepNode(Protocol):
    """What :func:`lockstep_loop` uses of the simulator node (``LineSimulator`` has it).

    The node is also an rclpy ``Node`` (its graph is looked at by :mod:`.sim_domain`;
    checked at the start of the loop).
    """

    params: SimParams
    """startup_timeout_s, ato_absent_timeout_s, lockstep, step_timeout_s [s], rtf,
    wait_for_subscribers."""
    sim: LineSim
    """The plant (its time ``t`` [s] and ``control_period_s`` [s])."""
    fleet: FleetStatePublisher
    sensors: SensorOutbox
    checkpoints: Checkpoints
    ids: list[str]
    fleet_sub: Subscription
    cmd_subs: list[Subscription]
    dep_subs: list[Subscription]
    profile_subs: list[Subscription]
    diag_subs: list[Subscription]
    k: int
    """The lockstep step index."""
    cmd_step: NDArray[np.int64]
    """The step of each train's last command."""
    finished: bool
    started: bool
    wall0: float
    """Wall time of the first step [s] (``time.monotonic``)."""
    loop_span: tuple[float, float] | None

    @property
    def context(self) -> Context:
        """The rclpy context of the node."""

    def get_logger(self) -> RcutilsLogger:
        """The node's logger."""

    def graph_ready(self) -> bool:
        """Every ATO/ATS endpoint was discovered."""

    def graph_missing(self) -> list[str]:
        """The endpoints :meth:`graph_ready` waits for that are not there (short names)."""

    def waited_trains(self) -> NDArray[np.bool_]:
        """Trains whose per-train command the lockstep waits for."""

    def pending_departures(self) -> list[tuple[int, int]]:
        """(train, station) of the departure commands the lockstep waits for."""

    def wait_acked(self, timeout_s: float = 5.0) -> None:
        """Wait until every reliable reader acknowledged what was published."""

    def publish_step(self) -> NDArray[np.bool_]:
        """Publish the state of the step; the trains that must answer."""

    def commands_complete(self, active: NDArray[np.bool_]) -> bool:
        """Every command of the step arrived."""

    def step_and_publish(self, active: NDArray[np.bool_],
                         timed_out: bool) -> NDArray[np.bool_] | None:
        """Step the plant, publish the next state; the trains that must answer."""

    def advance(self, active: NDArray[np.bool_], timed_out: bool) -> None:
        """Step the plant (free run)."""

    def announce_finished(self) -> None:
        """Say that the run finished (the launcher's finished file)."""


def lockstep_loop(executor: SingleThreadedExecutor, node: LockstepNode,
                  fast_path: bool = True) -> None:
    """Drive the simulator: lockstep on commands, or free-run paced at the real-time factor.

    With ``fast_path`` (the node's own process) commands and departure commands are taken by
    a :class:`SubscriptionPoller`, the per-train command echoes and the speed profiles by
    another every :data:`ECHO_PERIOD_S` of wall time; everything else on ``executor``
    (parameter services, the /diagnostics timer) is spun every :data:`EXECUTOR_PERIOD_S`.
    Without it (the single-process graph, where other nodes' callbacks share the executor)
    every wait is an executor spin.
    """
    if not isinstance(node, Node):  # the domain checks look at the node's ROS graph
        raise TypeError(f"lockstep_loop drives an rclpy Node, not {type(node).__name__}")
    log = node.get_logger()
    params = node.params
    lock_pollers: dict[tuple[bytes, tuple[int, ...]], SubscriptionPoller] = {}
    echo_pollers: dict[bytes, SubscriptionPoller] = {}

    def lock_poller() -> SubscriptionPoller:
        """Return the poller of what the lockstep waits for.

        The lockstep waits on the fleet commands, on the per-train commands of active
        trains no fleet command answered yet, and on the departure commands of the trains
        dwelling without one (the barrier waits for those).  Everything else (the
        per-train commands of fleet-driven trains, echoes for outside tools that the fleet
        command carried already; those of trains not in service; the speed profiles; the
        other departure commands, sent before their train reached the station; the brake
        diagnoses) is drained every slow period: each waited-on subscription costs every
        wait, and waking for every echo cost more than the step.  Made again
        when those sets change (cached).
        """
        own = node.waited_trains()
        pend = tuple(sorted({i for i, _ in node.pending_departures()}))
        okey = own.tobytes()
        lock = lock_pollers.get((okey, pend))
        if lock is None:
            if len(lock_pollers) > 256:
                lock_pollers.clear()
            lock = lock_pollers[(okey, pend)] = SubscriptionPoller(
                node.context,
                [node.fleet_sub, *(node.cmd_subs[i] for i in np.flatnonzero(own)),
                 *(node.dep_subs[i] for i in pend)])
        return lock

    def echo_poller() -> SubscriptionPoller:
        """Return the poller of everything the lockstep does not wait on (see lock_poller)."""
        own = node.waited_trains()
        okey = own.tobytes()
        echo = echo_pollers.get(okey)
        if echo is None:
            if len(echo_pollers) > 64:
                echo_pollers.clear()
            echo = echo_pollers[okey] = SubscriptionPoller(
                node.context,
                [*(s for i, s in enumerate(node.cmd_subs) if not own[i]),
                 *node.profile_subs, *node.dep_subs, *node.diag_subs])
        return echo

    def wait(timeout_s: float) -> None:
        if fast_path:
            lock_poller().poll(timeout_s)
            slow_path()
        else:
            executor.spin_once(timeout_sec=timeout_s)

    t0 = time.monotonic()
    alone_until = t0 + ALONE_CHECK_S if node.checkpoints.first_start else t0
    other_since = math.inf  # since when another simulator is seen (wall) [s]
    next_alone = t0  # the graph query costs: once a second, as in the stepping loop
    while not node.graph_ready() and time.monotonic() - t0 < params.startup_timeout_s:
        if stop_requested():
            return
        executor.spin_once(timeout_sec=0.05)
        now = time.monotonic()
        if next_alone <= now < alone_until:
            next_alone = now + 1.0
            check_alone(node, node.fleet.fleet_pub.topic_name)
    if not node.graph_ready():
        missing = node.graph_missing()
        log.warning(f"startup: after {params.startup_timeout_s:g} s {len(missing)} endpoints "
                    f"not discovered ({', '.join(missing[:4])}{' ...' if len(missing) > 4 else ''}"
                    f"); starting anyway (no ATO answer for {params.ato_absent_timeout_s:g} s "
                    "ends the run)")
    log.info(f"graph ready after {time.monotonic() - t0:.2f} s")
    node.started = True
    node.fleet.new_subscribers(np.ones(len(node.ids), dtype=bool))
    node.sensors.resend_new_readers(float(node.sim.t), node.started)  # readers of step 0:
    # nothing kept yet, nothing sent
    next_sensor_check = time.monotonic() + 1.0
    node.fleet.new_fleet_subscribers()
    wall0, sim0 = time.monotonic(), float(node.sim.t)
    node.wall0 = wall0
    k0 = int(node.k)  # the first step of this loop (a resumed run's is not 0)
    last_slow = time.monotonic()

    last_executor = time.monotonic()

    def slow_path(force: bool = False) -> None:
        nonlocal last_slow, last_executor
        now = time.monotonic()
        if force or now - last_slow >= ECHO_PERIOD_S:
            last_slow = now
            echo_poller().poll(0.0)
            if force or now - last_executor >= EXECUTOR_PERIOD_S:
                # parameter services and the /diagnostics timer: each spin rebuilds the
                # executor's wait set from all ~100 entities of the node (~1 ms)
                last_executor = now
                executor.spin_once(timeout_sec=0.0)

    active: np.ndarray | None = None
    while not node.finished and not stop_requested():
        if time.monotonic() >= next_sensor_check:
            next_sensor_check = time.monotonic() + 1.0
            node.sensors.resend_new_readers(float(node.sim.t), node.started)
            now = time.monotonic()
            topic = node.fleet.fleet_pub.topic_name
            if now < alone_until:
                check_alone(node, topic)
            else:
                check_not_refused(node, topic)
                if other_simulators(node, topic) == 0:
                    other_since = math.inf
                else:
                    other_since = min(other_since, now)
                    if now - other_since >= ALONE_PERSIST_S:
                        check_alone(node, topic)
        if active is None:  # else published with the step before (step_and_publish)
            if params.wait_for_subscribers and node.k > 0 and node.k % RECORDER_SYNC_STEPS == 0:
                node.wait_acked(timeout_s=30.0)
            active = node.publish_step()
        if params.lockstep:
            deadline = time.monotonic() + params.step_timeout_s
            resend = time.monotonic() + 0.5
            fleet_resend = time.monotonic() + FLEET_RESEND_S
            while True:
                # the barrier (looked at once per wake: nothing arrives between two looks)
                complete = node.commands_complete(active)
                if complete or time.monotonic() >= deadline:
                    break
                if stop_requested():
                    return
                wait(0.02)
                if time.monotonic() > resend and not node.commands_complete(active):
                    # a state may have been published before a late (or restarted) ATO
                    # matched: only then, and only to that train, is it sent again
                    resend = time.monotonic() + 0.5
                    again = node.fleet.new_subscribers(active)
                    if again.any():
                        node.fleet.publish_states(node.k, again)
                    if node.fleet.new_fleet_subscribers():
                        node.fleet.publish_again(node.k, node.cmd_step)
                    elif time.monotonic() >= fleet_resend:
                        # no answer for a while: the state may have been lost with a
                        # killed ATO process whose successor matched between two checks
                        fleet_resend = time.monotonic() + FLEET_RESEND_S
                        node.fleet.publish_again(node.k, node.cmd_step, active)
            active = node.step_and_publish(active, timed_out=not complete)
        else:
            target = wall0 + (float(node.sim.t) + node.sim.control_period_s - sim0) / params.rtf
            while True:
                rest = target - time.monotonic()
                if rest <= 0:
                    break
                wait(min(rest, 0.01))
            wait(0.0)
            node.advance(active, timed_out=False)
            active = None
        if fast_path:
            slow_path()
        else:
            executor.spin_once(timeout_sec=0.0)
    node.sensors.flush(float(node.sim.t), force=True)  # stopped by a signal: what was
    # sampled goes out
    node.checkpoints.wait()
    if params.wait_for_subscribers:
        node.wait_acked()
    if not node.finished:
        log.info(f"stopped by a signal at t={node.sim.t:.1f} s, step {node.k}")
        return
    node.loop_span = (time.monotonic() - wall0, float(node.sim.t) - sim0)
    log.info(f"scenario finished at t={node.sim.t:.1f} s after {node.k} steps, "
             f"{time.monotonic() - t0:.1f} s wall ({node.loop_span[0]:.1f} s from step {k0})")
    node.sensors.drain(float(node.sim.t),
                       lambda timeout_s: executor.spin_once(timeout_sec=timeout_s))
    executor.spin_once(timeout_sec=0.0)
    # the other nodes may stop now (the launcher's finished_file), while this one writes
    # its outputs; the last samples' acknowledgements are awaited after those (close)
    node.announce_finished()
