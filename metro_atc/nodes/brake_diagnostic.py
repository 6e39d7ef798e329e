"""brake_diagnostic node: brake-by-wire active safety diagnosis for every train.

One node watches all trains: subscribes to ``/<train>/brake_sensors`` (best effort),
validates each sample (axle count, finite channels, increasing stamps) and publishes
``/<train>/brake_diagnosis`` and ``diagnostic_msgs/DiagnosticArray`` on ``/diagnostics``
(OK / WARN / ERROR per train with key-values) every ``diagnostics_period_s`` of
simulated time.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from functools import partial
from typing import Any, Sequence

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from metro_atc_msgs.msg import BrakeDiagnosis, BrakeSensorData
from rclpy.node import Node

from metro_atc.core.plant.scenario import ScenarioError, load_scenario
from metro_atc.nodes import conversions as conv
from metro_atc.nodes.common import (QOS_LATCHED, QOS_RELIABLE, QOS_SENSOR, NodeConfigError,
                                    bulk_publisher, bulk_subscription, declare, run_nodes)

N_AXLES = 4


@dataclass
class _TrainWatch:
    """Per-train bookkeeping."""

    used: int = 0
    rejected: int = 0
    last_t_s: float = -math.inf
    last_reason: str = ""
    last: dict[str, Any] = field(default_factory=dict)


class BrakeDiagnostic(Node):
    """The brake diagnosis node (see module docstring)."""

    def __init__(self, **kwargs: Any) -> None:
        """Declare parameters, subscribe to every train's brake sensors."""
        super().__init__("brake_diagnostic", **kwargs)
        self.scenario_name = declare(self, "scenario", "taipei_blue",
                                     "embedded scenario name or path to a scenario YAML")
        self.period_s = declare(self, "diagnostics_period_s", 1.0,
                                "/diagnostics period in simulated time [s]", 0.05, 3600.0)
        try:
            scn = load_scenario(self.scenario_name)
        except ScenarioError as exc:
            raise NodeConfigError(str(exc)) from None
        self.ids = list(scn.train_ids)
        self.watch = {t: _TrainWatch() for t in self.ids}
        self._last_warn = 0.0
        self.diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", QOS_RELIABLE)
        self.pubs = {t: bulk_publisher(self, BrakeDiagnosis, f"/{t}/brake_diagnosis",
                                       QOS_LATCHED) for t in self.ids}
        for t in self.ids:
            bulk_subscription(self, BrakeSensorData, f"/{t}/brake_sensors",
                              partial(self._on_sample, t), QOS_SENSOR)
        self.create_timer(self.period_s, self._publish_diagnostics)

    def _warn(self, text: str) -> None:
        now = time.monotonic()
        if now - self._last_warn > 1.0:
            self._last_warn = now
            self.get_logger().warning(text)

    def _on_sample(self, train_id: str, msg: BrakeSensorData) -> None:
        w = self.watch[train_id]
        topic = f"/{train_id}/brake_sensors"
        try:
            if msg.train_id != train_id:
                raise conv.MessageRejected(f"{topic}: train_id '{msg.train_id}' does not "
                                           f"match the topic")
            s = conv.sensor_from_msg(msg, topic, N_AXLES)
            if s["t_s"] <= w.last_t_s:
                raise conv.MessageRejected(f"{topic}: stamp {s['t_s']:.3f} s is not after "
                                           f"{w.last_t_s:.3f} s (out of order)")
            finite = all(math.isfinite(float(x)) for x in (*s["omega"], *s["clamp"],
                                                             s["accel"], s["ref_speed"]))
            if not finite:
                raise conv.MessageRejected(f"{topic}: non-finite channel (dropout)")
        except conv.MessageRejected as exc:
            w.rejected += 1
            w.last_reason = str(exc)
            self._warn(f"skipped sample: {exc}")
            return
        w.used += 1
        w.last_t_s = s["t_s"]
        w.last = s

    def _publish_diagnostics(self) -> None:
        arr = DiagnosticArray()
        arr.header.stamp = self.get_clock().now().to_msg()
        for t in self.ids:
            w = self.watch[t]
            level = DiagnosticStatus.OK
            text = "receiving brake sensor data" if w.used else "no brake sensor data yet"
            if w.rejected and w.rejected >= max(1, w.used // 10):
                level, text = DiagnosticStatus.WARN, f"many rejected samples: {w.last_reason}"
            st = DiagnosticStatus(level=level, name=f"brake_diagnostic: {t}", message=text,
                                  hardware_id=t)
            st.values = [KeyValue(key="samples_used", value=str(w.used)),
                         KeyValue(key="samples_rejected", value=str(w.rejected))]
            arr.status.append(st)
            d = BrakeDiagnosis(train_id=t, friction_coefficient=math.nan,
                               friction_coefficient_std=math.nan, level=_level_int(level),
                               message=text, measurements_used=w.used,
                               measurements_rejected=w.rejected)
            d.header.stamp = arr.header.stamp
            self.pubs[t].publish(d)
        self.diag_pub.publish(arr)


def _level_int(level: Any) -> int:
    """DiagnosticStatus levels are ``byte`` (bytes in Python); BrakeDiagnosis uses uint8."""
    return level[0] if isinstance(level, (bytes, bytearray)) else int(level)


def main(args: Sequence[str] | None = None) -> int:
    """Entry point of the ``brake_diagnostic`` executable."""
    return run_nodes(lambda: [BrakeDiagnostic()], None, args)


if __name__ == "__main__":
    raise SystemExit(main())
