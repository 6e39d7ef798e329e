"""ato_controller node(s): one ATO per train, namespaced ``/<train_id>/``.

Per train: subscribes to ``state`` (every lockstep step) and ``departure_command``
(transient-local); publishes ``command`` (traction/brake for the state's step) and
``speed_profile`` (transient-local, on every new departure command).

One process may host several trains (parameter ``train_ids``), each its own node on one
SingleThreadedExecutor: rclpy shares one DDS participant per process, so composing trains
cuts discovery time and memory.
"""

from __future__ import annotations

import math
import time
from typing import Any, Sequence

from metro_atc_msgs.msg import DepartureCommand, SpeedProfile, TractionCommand, TrainState
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter

from metro_atc.core.bridge import timetable_for, track_for
from metro_atc.core.plant.scenario import ScenarioError, load_scenario
from metro_atc.core.simple_ato import FlatOutTracker
from metro_atc.nodes import conversions as conv
from metro_atc.nodes.common import (QOS_LATCHED, QOS_RELIABLE, NodeConfigError, bulk_publisher,
                                    bulk_subscription, declare, run_nodes, spin_fast)


class AtoController(Node):
    """The ATO of one train (see module docstring)."""

    def __init__(self, train_id: str, scenario: Any = None, timetable: Any = None,
                 **kwargs: Any) -> None:
        """Declare parameters, load the line, create the per-train topics."""
        # the type-description service (one more service per node in every wait set) is
        # off for the composed per-train nodes; parameter services stay on
        overrides = list(kwargs.pop("parameter_overrides", None) or [])
        overrides.append(Parameter("start_type_description_service", value=False))
        super().__init__("ato_controller", namespace=f"/{train_id}",
                         parameter_overrides=overrides, **kwargs)
        self.train_id = train_id
        self.scenario_name = declare(self, "scenario", "taipei_blue",
                                     "embedded scenario name or path to a scenario YAML")
        declare(self, "train_ids", [""], "trains hosted by this process (launcher use)")
        self.planner = declare(self, "planner", "flat_out", "speed profile planner")
        if scenario is None:
            try:
                scenario = load_scenario(self.scenario_name)
            except ScenarioError as exc:
                raise NodeConfigError(str(exc)) from None
        self.tt = timetable if timetable is not None else timetable_for(scenario)
        if train_id not in self.tt.train_ids:
            raise NodeConfigError(f"train_id '{train_id}' is not in scenario "
                                  f"'{self.scenario_name}' ({self.tt.train_ids[0]} .. "
                                  f"{self.tt.train_ids[-1]})")
        self.track = track_for(scenario)
        self.tracker = FlatOutTracker()
        self.stations = self.tt.station_positions_m
        self.departure: tuple[int, float, float, float] | None = None
        self.last_step = -1
        self.rejected = 0
        self._last_warn = 0.0
        self.cmd_pub = bulk_publisher(self, TractionCommand, "command", QOS_RELIABLE)
        self.profile_pub = bulk_publisher(self, SpeedProfile, "speed_profile", QOS_LATCHED)
        self.fast_subs = [
            bulk_subscription(self, TrainState, "state", self._on_state, QOS_RELIABLE),
            bulk_subscription(self, DepartureCommand, "departure_command", self._on_departure,
                              QOS_LATCHED)]

    def _warn(self, text: str) -> None:
        self.rejected += 1
        now = time.monotonic()
        if now - self._last_warn > 1.0:
            self._last_warn = now
            self.get_logger().warning(text)

    def _on_departure(self, msg: DepartureCommand) -> None:
        topic = f"/{self.train_id}/departure_command"
        try:
            if msg.train_id != self.train_id:
                raise conv.MessageRejected(f"{topic}: train_id '{msg.train_id}' is not "
                                           f"'{self.train_id}'")
            st, dep, run, dwell = conv.departure_from_msg(msg, topic, len(self.stations))
        except conv.MessageRejected as exc:
            self._warn(f"rejected departure command: {exc}")
            return
        self.departure = (st, dep, run, dwell)
        if st + 1 < len(self.stations):
            self.profile_pub.publish(self._flat_out_profile(st, run, msg.header.stamp))

    def _flat_out_profile(self, st: int, target_s: float, stamp: Any) -> SpeedProfile:
        """The baseline plan: one accelerate/cruise section at the line limit to the stop."""
        x0, x1 = float(self.stations[st]), float(self.stations[st + 1])
        p = SpeedProfile()
        p.header.stamp = stamp
        p.header.frame_id = "line"
        p.train_id = self.train_id
        p.from_station, p.to_station = st, st + 1
        p.section_boundaries_m = [x0, x1]
        p.section_modes = [SpeedProfile.MODE_ACCELERATE]
        p.section_speed_codes_mps = [float(self.track.limit_at(0.5 * (x0 + x1)))]
        p.coasting_point_m = math.nan
        p.target_running_time_s = float(target_s)
        p.predicted_running_time_s = float(self.tt.min_running_s[st])
        p.predicted_energy_j = math.nan
        p.feasible = bool(target_s >= self.tt.min_running_s[st] - 1e-6)
        p.planner = "flat_out"
        p.message = "baseline flat-out profile (energy not predicted)"
        return p

    def _on_state(self, msg: TrainState) -> None:
        topic = f"/{self.train_id}/state"
        try:
            if msg.train_id != self.train_id:
                raise conv.MessageRejected(f"{topic}: train_id '{msg.train_id}' is not "
                                           f"'{self.train_id}'")
            s = conv.state_from_msg(msg, topic)
        except conv.MessageRejected as exc:
            self._warn(f"rejected state: {exc}; commanding full service brake")
            self.cmd_pub.publish(conv.traction_msg(self.train_id, int(msg.step), 0.0, -1.0,
                                                   TrainState.MODE_BRAKE))
            return
        effort, mode = self.control(s)
        self.last_step = s["step"]
        self.cmd_pub.publish(conv.traction_msg(self.train_id, s["step"], s["t_s"], effort, mode))

    def control(self, s: dict[str, Any]) -> tuple[float, int]:
        """Effort in [-1, 1] and intended mode for one state."""
        if s["mode"] == TrainState.MODE_DWELL:
            return -1.0, TrainState.MODE_DWELL
        nxt = s["next_station"]
        x_stop = float(self.stations[nxt]) if 0 <= nxt < len(self.stations) else math.inf
        limit = float(self.track.limit_at(s["x_m"]))
        sup = s["supervision_speed_mps"]
        if math.isfinite(sup):
            limit = min(limit, sup)
        u = self.tracker.command(s["x_m"], s["v_mps"], x_stop, limit, s["movement_authority_m"])
        mode = TrainState.MODE_ACCELERATE if u > 0.05 else (
            TrainState.MODE_BRAKE if u < -0.05 else TrainState.MODE_COAST)
        return u, mode


def build_nodes() -> list[Node]:
    """Create one ATO node per hosted train (``train_ids`` or the namespace)."""
    probe = Node("ato_controller")
    ids = declare(probe, "train_ids", [""], "trains hosted by this process")
    name = declare(probe, "scenario", "taipei_blue", "scenario")
    ns = probe.get_namespace().strip("/")
    probe.destroy_node()
    ids = [t for t in ids if t] or ([ns] if ns else [])
    if not ids:
        raise NodeConfigError("no train: set -p train_ids:=[train_01,...] or run in a "
                              "train namespace (-r __ns:=/train_01)")
    try:
        scn = load_scenario(name)
    except ScenarioError as exc:
        raise NodeConfigError(str(exc)) from None
    tt = timetable_for(scn)
    return [AtoController(t, scenario=scn, timetable=tt) for t in ids]


def main(args: Sequence[str] | None = None) -> int:
    """Entry point of the ``ato_controller`` executable."""
    def loop(executor: SingleThreadedExecutor, nodes: Sequence[Node]) -> None:
        subs = [s for n in nodes if isinstance(n, AtoController) for s in n.fast_subs]
        spin_fast(executor, nodes, subs)

    return run_nodes(build_nodes, loop, args)


if __name__ == "__main__":
    raise SystemExit(main())
