"""The line_simulator's stepping loop: lockstep on the ATOs' commands, or free-run.

:func:`lockstep_loop` drives a ``LineSimulator`` node (passed in: this module does not
import the node) through its public interface: it waits for the graph, then steps the plant
whenever every command of the step arrived (or the step timed out), re-sending the fleet
state to late or restarted ATOs, and at the end drains the brake sensor outbox and announces
the finished run.  Wall times are ``time.monotonic`` seconds.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
from rclpy.executors import SingleThreadedExecutor

from metro_atc.nodes.common import SubscriptionPoller, stop_requested
from metro_atc.nodes.sim_domain import ALONE_CHECK_S, check_alone, check_not_refused

RECORDER_SYNC_STEPS = 250
"""While a recorder is waited for (``wait_for_subscribers``), every this many steps the
lockstep waits until every reliable reader acknowledged what was published: half the
500-state writer history, so a recorder slower than the graph loses no state (issue 13:
with the fast tracker the graph outruns a recording node)."""
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


def lockstep_loop(executor: SingleThreadedExecutor, sim: Any,
                  fast_path: bool = True) -> None:
    """Drive the simulator: lockstep on commands, or free-run paced at the real-time factor.

    With ``fast_path`` (the node's own process) commands and departure commands are taken by
    a :class:`SubscriptionPoller`, the per-train command echoes and the speed profiles by
    another every :data:`ECHO_PERIOD_S` of wall time; everything else on ``executor``
    (parameter services, the /diagnostics timer) is spun every :data:`EXECUTOR_PERIOD_S`.
    Without it (the single-process graph, where other nodes' callbacks share the executor)
    every wait is an executor spin.
    """
    log = sim.get_logger()
    params = sim.params
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
        wait, and waking for every echo cost more than the step (issue 13).  Made again
        when those sets change (cached).
        """
        own = sim.waited_trains()
        pend = tuple(sorted({i for i, _ in sim.pending_departures()}))
        okey = own.tobytes()
        lock = lock_pollers.get((okey, pend))
        if lock is None:
            if len(lock_pollers) > 256:
                lock_pollers.clear()
            lock = lock_pollers[(okey, pend)] = SubscriptionPoller(
                sim.context, [sim.fleet_sub, *(sim.cmd_subs[i] for i in np.flatnonzero(own)),
                              *(sim.dep_subs[i] for i in pend)])
        return lock

    def echo_poller() -> SubscriptionPoller:
        """Return the poller of everything the lockstep does not wait on (see lock_poller)."""
        own = sim.waited_trains()
        okey = own.tobytes()
        echo = echo_pollers.get(okey)
        if echo is None:
            if len(echo_pollers) > 64:
                echo_pollers.clear()
            echo = echo_pollers[okey] = SubscriptionPoller(
                sim.context, [*(s for i, s in enumerate(sim.cmd_subs) if not own[i]),
                              *sim.profile_subs, *sim.dep_subs, *sim.diag_subs])
        return echo

    def wait(timeout_s: float) -> None:
        if fast_path:
            lock_poller().poll(timeout_s)
            slow_path()
        else:
            executor.spin_once(timeout_sec=timeout_s)

    t0 = time.monotonic()
    alone_until = t0 + ALONE_CHECK_S if sim.checkpoints.first_start else t0
    next_alone = t0  # the graph query costs: once a second, as in the stepping loop
    while not sim.graph_ready() and time.monotonic() - t0 < params.startup_timeout_s:
        if stop_requested():
            return
        executor.spin_once(timeout_sec=0.05)
        now = time.monotonic()
        if next_alone <= now < alone_until:
            next_alone = now + 1.0
            check_alone(sim, sim.fleet.fleet_pub.topic_name)
    if not sim.graph_ready():
        missing = sim.graph_missing()
        log.warning(f"startup: after {params.startup_timeout_s:g} s {len(missing)} endpoints "
                    f"not discovered ({', '.join(missing[:4])}{' ...' if len(missing) > 4 else ''}"
                    f"); starting anyway (no ATO answer for {params.ato_absent_timeout_s:g} s "
                    "ends the run)")
    log.info(f"graph ready after {time.monotonic() - t0:.2f} s")
    sim.started = True
    sim.fleet.new_subscribers(np.ones(len(sim.ids), dtype=bool))
    sim.sensors.resend_new_readers(float(sim.sim.t), sim.started)  # the readers of step 0:
    # nothing kept yet, nothing sent
    next_sensor_check = time.monotonic() + 1.0
    sim.fleet.new_fleet_subscribers()
    wall0, sim0 = time.monotonic(), float(sim.sim.t)
    sim.wall0 = wall0
    k0 = int(sim.k)  # the first step of this loop (a resumed run's is not 0)
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
    while not sim.finished and not stop_requested():
        if time.monotonic() >= next_sensor_check:
            next_sensor_check = time.monotonic() + 1.0
            sim.sensors.resend_new_readers(float(sim.sim.t), sim.started)
            if time.monotonic() < alone_until:
                check_alone(sim, sim.fleet.fleet_pub.topic_name)
            else:
                check_not_refused(sim, sim.fleet.fleet_pub.topic_name)
        if active is None:  # else published with the step before (step_and_publish)
            if params.wait_for_subscribers and sim.k > 0 and sim.k % RECORDER_SYNC_STEPS == 0:
                sim.wait_acked(timeout_s=30.0)
            active = sim.publish_step()
        if params.lockstep:
            deadline = time.monotonic() + params.step_timeout_s
            resend = time.monotonic() + 0.5
            fleet_resend = time.monotonic() + FLEET_RESEND_S
            while True:
                # the barrier (looked at once per wake: nothing arrives between two looks)
                complete = sim.commands_complete(active)
                if complete or time.monotonic() >= deadline:
                    break
                if stop_requested():
                    return
                wait(0.02)
                if time.monotonic() > resend and not sim.commands_complete(active):
                    # a state may have been published before a late (or restarted) ATO
                    # matched: only then, and only to that train, is it sent again
                    resend = time.monotonic() + 0.5
                    again = sim.fleet.new_subscribers(active)
                    if again.any():
                        sim.fleet.publish_states(sim.k, again)
                    if sim.fleet.new_fleet_subscribers():
                        sim.fleet.publish_again(sim.k, sim.cmd_step)
                    elif time.monotonic() >= fleet_resend:
                        # no answer for a while: the state may have been lost with a
                        # killed ATO process whose successor matched between two checks
                        fleet_resend = time.monotonic() + FLEET_RESEND_S
                        sim.fleet.publish_again(sim.k, sim.cmd_step, active)
            active = sim.step_and_publish(active, timed_out=not complete)
        else:
            target = wall0 + (float(sim.sim.t) + sim.sim.control_period_s - sim0) / params.rtf
            while True:
                rest = target - time.monotonic()
                if rest <= 0:
                    break
                wait(min(rest, 0.01))
            wait(0.0)
            sim.advance(active, timed_out=False)
            active = None
        if fast_path:
            slow_path()
        else:
            executor.spin_once(timeout_sec=0.0)
    sim.sensors.flush(float(sim.sim.t), force=True)  # stopped by a signal: what was
    # sampled goes out
    sim.checkpoints.wait()
    if params.wait_for_subscribers:
        sim.wait_acked()
    if not sim.finished:
        log.info(f"stopped by a signal at t={sim.sim.t:.1f} s, step {sim.k}")
        return
    sim.loop_wall_s, sim.loop_sim_s = time.monotonic() - wall0, float(sim.sim.t) - sim0
    log.info(f"scenario finished at t={sim.sim.t:.1f} s after {sim.k} steps, "
             f"{time.monotonic() - t0:.1f} s wall ({sim.loop_wall_s:.1f} s from step {k0})")
    sim.sensors.drain(float(sim.sim.t),
                      lambda timeout_s: executor.spin_once(timeout_sec=timeout_s))
    executor.spin_once(timeout_sec=0.0)
    # the other nodes may stop now (the launcher's finished_file), while this one writes
    # its outputs; the last samples' acknowledgements are awaited after those (close)
    sim.announce_finished()
