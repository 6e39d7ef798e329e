"""The line_simulator's parameters: declared on the node, their values in one object.

:class:`SimParams` declares every parameter of the ``line_simulator`` node (names, defaults,
ranges and descriptions: the node's ROS interface) and holds their values; the dynamic ones
(``step_timeout_s``, ``status_period_s``, ``sensor_idle_period_s``, ``progress_period_s``,
``min_real_time_factor``) are updated in place when set at runtime (:class:`RuntimeParams`).
Units are in the names and descriptions: ``_s`` seconds (simulated unless "wall"),
``real_time_factor`` simulated seconds per wall second.
"""

from __future__ import annotations

from functools import partial
from typing import Any, Callable

from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.node import Node

from metro_atc.nodes.common import RuntimeParams, static


class SimParams:
    """The parameters of the ``line_simulator`` node (declared on ``node``, in this order).

    ``health()``: the node's /diagnostics statuses (the :class:`RuntimeParams` timer);
    ``on_progress_period(value)``: applies a runtime change of ``progress_period_s`` [s]
    (the node moves its next progress line; it sets :attr:`progress_period_s`).
    """

    def __init__(self, node: Node, health: Callable[[], list[DiagnosticStatus]],
                 on_progress_period: Callable[[Any], None]) -> None:
        """Declare the parameters on ``node`` and take their start values."""
        self.scenario_name = static(node, "scenario", "taipei_blue",
                                    "embedded scenario name or path to a scenario YAML")
        self.seed = static(node, "seed", 0, "random seed of disturbances and noise",
                           0, 2**31 - 1)
        from metro_atc.core.atr.registry import REGULATORS
        self.day_regulator = static(
            node, "day_regulator", "none",
            "a service day's ATS regulator of both directions (the day plant's DayAts; "
            "unused for a one-way scenario, whose ATS is the ats_regulator node): "
            + REGULATORS.help(),
            choices=REGULATORS.names)
        self.lockstep = static(node, "lockstep", True,
                               "deterministic lockstep (true) or free-run at real_time_factor")
        self.rtf = static(node, "real_time_factor", 10.0,
                          "free-run pacing: simulated seconds per wall second", 0.01, 10000.0)
        self.startup_timeout_s = static(
            node, "startup_timeout_s", 60.0,
            "wall time to wait for every ATO/ATS/brake-diagnosis endpoint before step 0 [s]; "
            "then the simulator starts with the endpoints found (logged) and "
            "ato_absent_timeout_s bounds a wait for ATOs that never answer", 0.0, 3600.0)
        self.ato_absent_timeout_s = static(
            node, "ato_absent_timeout_s", 60.0,
            "lockstep: wall time [s] of consecutive timed-out steps in which no active "
            "train's ATO answered, after which the simulator gives up (exit code 7, "
            "GRAPH_NOT_READY, one line naming the missing endpoints) instead of stepping "
            "once per step_timeout_s", 0.1, 86400.0)
        self.wait_for_subscribers = [x for x in static(
            node, "wait_for_subscribers", [""],
            "node names (e.g. a recorder) that must subscribe to every topic of the "
            "simulator before step 0") if x]
        self.max_sim_time_s = static(node, "max_sim_time_s", 0.0,
                                     "stop after this simulated time [s] (a service day: "
                                     "from its first step); 0: scenario end",
                                     0.0, 1e7)
        self.out_dir = static(node, "out_dir", "",
                              "directory for kpis.json, events.csv and plots ('' : none)")
        self.plots = static(node, "plots", True, "write PNG plots into out_dir")
        self.exit_on_finish = static(node, "exit_on_finish", True,
                                     "shut the node down when the scenario ends")
        self.finished_file = static(
            node, "finished_file", "",
            "a file created once the run finished and its last samples were delivered, "
            "before the outputs are written ('' : none; python -m metro_atc run then stops "
            "the other nodes while this one writes its outputs)")
        self.train_state_period_s = static(
            node, "train_state_period_s", 1.0,
            "simulated time between the per-train /<train>/state messages of trains whose "
            "ATO answers /line/fleet_state (the lockstep carrier, every step); 0: every step",
            0.0, 3600.0)
        self.clock_period_s = static(
            node, "clock_period_s", 0.0,
            "simulated time between /clock messages [s] (0: every step; -1: "
            "train_state_period_s); nothing in the graph steps on /clock (the lockstep "
            "carries the time), but outside tools see a lockstep hold on it", -1.0, 3600.0)
        self.dispatch_queue_max = static(
            node, "dispatch_queue_max", 64,
            "dispatcher commands (/line/dispatch) accepted and waiting for the next step at "
            "most; more are refused (queue full) and counted on /diagnostics", 1, 100_000)
        self.replay_commands = static(
            node, "replay_commands", "",
            "a recorded run's bag directory: its /line/dispatcher_commands are applied at "
            "their steps and live /line/dispatch requests are refused ('' : none)")
        self.rt = RuntimeParams(node, health)
        self.step_timeout_s = self.rt.dynamic(
            "step_timeout_s", 10.0, "lockstep: wall time to wait for all commands [s]",
            partial(setattr, self, "step_timeout_s"), 0.01, 600.0)
        self.status_period_s = self.rt.dynamic(
            "status_period_s", 10.0,
            "simulated time between /line/status messages [s] (each computes the run's "
            "KPIs so far: ~3 ms on the Blue line peak, more than a physics step)",
            partial(setattr, self, "status_period_s"), 0.01, 3600.0)
        self.sensor_idle_period_s = self.rt.dynamic(
            "sensor_idle_period_s", 1.0,
            "brake sensors: samples are published at the scenario rate while the instrumented "
            "car brakes, and every this many simulated seconds otherwise (0: every sample)",
            partial(setattr, self, "sensor_idle_period_s"), 0.0, 3600.0)
        self.progress_period_s = self.rt.dynamic(
            "progress_period_s", 600.0, "simulated time between progress log lines [s]",
            on_progress_period, 1.0, 1e6)
        self.min_rtf = self.rt.dynamic(
            "min_real_time_factor", 1.0,
            "/diagnostics: WARN when the simulated seconds per wall second over the last "
            "diagnostics period fall below this", partial(setattr, self, "min_rtf"),
            0.0, 1e6)
        self.ato_lost_steps = static(
            node, "ato_lost_steps", 8,
            "a train whose ATO misses this many consecutive steps is braked to a stop "
            "(CBTC fault) until its ATO answers again", 1, 1_000_000)
        self.checkpoint_dir = static(
            node, "checkpoint_dir", "",
            "directory of the resume checkpoint and departure journal ('' : none); a "
            "checkpoint found there at start-up is resumed from")
        self.sensor_resend_s = static(
            node, "sensor_resend_s", 120.0,
            "brake sensors: the samples of this many simulated seconds are kept and sent "
            "again when a new reader matches (a restarted brake_diagnostic catches up)",
            0.0, 1e5)
        self.sensor_keep_max = static(
            node, "sensor_keep_max", 200_000,
            "brake sensors: at most this many samples are kept for a re-send (the oldest "
            "beyond it are dropped, counted and logged)", 0, 100_000_000)
        self.sensor_drain_timeout_s = static(
            node, "sensor_drain_timeout_s", 60.0,
            "end of a run: wall seconds to wait until every train's brake diagnosis "
            "acknowledged its last sensor sample (a restarted brake_diagnostic catching up; "
            "0: no wait)", 0.0, 3600.0)
        self.checkpoint_period_s = static(
            node, "checkpoint_period_s", 60.0,
            "simulated time between checkpoints [s] (0: none)", 0.0, 1e7)
        self.sensor_batch_period_s = static(
            node, "sensor_batch_period_s", 1.0,
            "brake sensors: simulated time whose samples go out in one FleetBrakeSensorData "
            "on /line/brake_sensors (0: one message per step with samples; the last batch "
            "goes out at a checkpoint and at the end of the run)", 0.0, 3600.0)
