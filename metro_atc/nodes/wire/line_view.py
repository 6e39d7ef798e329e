"""The live view's two derived messages (``run --foxglove``): their one codec.

* ``/line/trains`` (``sensor_msgs/JointState``, a lockstep step the bridge reads; to viewers
  at most one per :data:`VIEW_PERIOD_S` of wall time, on ROS every one read): one
  entry per train of the scenario, always in timetable order (:func:`train_order`), so that
  a plot panel's path ``/line/trains.position[k]`` is train k for the whole run: ``name``
  the train ids, ``position`` the chainage of the train front [m], ``velocity`` the speed
  [m/s], ``effort`` the operating mode (``TrainState.MODE_*`` as a float); NaN in all three
  for a train not in service at that step (a gap in a plot).  Derived from the
  ``FleetState`` of the step (decoded by :func:`metro_atc.nodes.wire.fleet_state.decode`),
  header stamp = the step's simulation time.
* ``/line/layout`` (``metro_atc_msgs/LineLayout``, latched): the scenario's stations,
  static speed limits, gradients and line speed, and the train order of ``/line/trains``.
* ``/line/event_log`` (``rcl_interfaces/Log``, what a log panel lists): one line per
  ``/line/events`` arrival or departure (:func:`event_log_line`), ``name`` the train.

Both are laid out from the generated message classes' own field lists
(:func:`metro_atc.nodes.wire.cdr.layout`) and written with :class:`cdr.Writer`.
"""

from __future__ import annotations

import math
import struct
from typing import Any, Mapping, Sequence

import numpy as np
from metro_atc_msgs.msg import LineLayout
from sensor_msgs.msg import JointState

from metro_atc.nodes.wire import cdr

KMH = 1.0 / 3.6
"""[m/s] per km/h."""
TRAINS_TOPIC = "/line/trains"
"""Per-train chainage, speed and mode of every step (``sensor_msgs/JointState``)."""
LAYOUT_TOPIC = "/line/layout"
"""The line (``metro_atc_msgs/LineLayout``), latched."""
EVENT_LOG_TOPIC = "/line/event_log"
"""The arrivals and departures as log lines (``rcl_interfaces/Log``)."""
VIEW_PERIOD_S = 0.1
"""Default wall period of ``/line/trains`` to viewers [s] (10 Hz; the bridge's
``view_period_s``): the lockstep steps far faster than a viewer draws."""
LATE_WARN_S = 60.0
"""An event this late or later than its timetable time is logged as a warning [s]."""
LOG_INFO, LOG_WARN = 20, 30
"""rcl_interfaces/Log levels."""

JOINT_ARRAYS = cdr.split_layout(JointState, (("header", "header"), ("name", "strings")),
                                "array")
"""JointState's arrays after ``name``: position, velocity, effort (checked at load)."""
cdr.require_names(JointState, JOINT_ARRAYS, ("position", "velocity", "effort"))
FROM_FLEET = {"position": "position_m", "velocity": "speed_mps", "effort": "mode"}
"""JointState array -> the FleetState array it is taken from."""
LAYOUT_FIELDS = cdr.layout(LineLayout)
"""LineLayout's fields, in order."""


def train_order(scenario: Any) -> list[str]:
    """The trains of ``/line/trains`` in their order: the scenario's, in timetable order."""
    return list(scenario.train_ids)


class TrainsBuilder:
    """``/line/trains`` messages of one run's trains (fixed order, see module docstring)."""

    def __init__(self, order: Sequence[str]) -> None:
        """The trains in the order of the message."""
        self.order = list(order)
        self.index = {t: k for k, t in enumerate(self.order)}
        self.names = cdr.string_seq(self.order)

    def build(self, view: Any) -> bytes:
        """The JointState of one decoded FleetState view (trains not in it: NaN).

        ``view``: what :func:`metro_atc.nodes.wire.fleet_state.decode` returns.
        """
        n = len(self.order)
        rows = [self.index.get(t, -1) for t in view.train_id]
        w = cdr.Writer()
        w.raw(cdr.STAMP.pack(*view.header.stamp), 4)
        w.raw(cdr.cdr_string(view.header.frame_id), 4)
        w.strings(self.names)
        for f in JOINT_ARRAYS:
            out = np.full(n, math.nan)
            src = getattr(view, FROM_FLEET[f.name])
            for k, v in zip(rows, src):
                if k >= 0:
                    out[k] = float(v)
            w.array(out, f.dtype)
        return w.bytes()


def live_view_line(host: str, port: int, view_period_s: float = VIEW_PERIOD_S) -> str:
    """The run's line about its live view: the address, and what a viewer gets less often."""
    return (f"live view on ws://{host}:{port}; /line/trains goes to viewers at most once per "
            f"{view_period_s:g} s of wall time (the latest step; every step is in "
            "/line/fleet_state)")


def layout_values(scenario: Any, t_s: float = 0.0) -> dict[str, Any]:
    """The LineLayout fields of ``scenario`` (field name -> value; the header as ``t_s``)."""
    ln = scenario.line
    return {"header": t_s, "scenario": str(scenario.name),
            "station_name": [s.name for s in ln.stations],
            "station_code": [s.code for s in ln.stations],
            "station_position_m": [s.position_m for s in ln.stations],
            "speed_limit_start_m": [s.start_m for s in ln.speed_limits],
            "speed_limit_mps": [s.limit_kmh * KMH for s in ln.speed_limits],
            "grade_start_m": [g.start_m for g in ln.gradients],
            "grade_permille": [g.grade_permille for g in ln.gradients],
            "line_speed_mps": ln.line_speed_kmh * KMH,
            "train_id": train_order(scenario)}


def encode_layout(values: Mapping[str, Any]) -> bytes:
    """A LineLayout from :func:`layout_values` (every field of the message, in order)."""
    missing = [f.name for f in LAYOUT_FIELDS if f.name not in values]
    if missing:
        raise cdr.LayoutError(f"LineLayout fields without a value: {missing}")
    w = cdr.Writer()
    for f in LAYOUT_FIELDS:
        v = values[f.name]
        if f.kind == "header":
            w.header(float(v))
        elif f.kind == "string":
            w.raw(cdr.cdr_string(str(v)), 4)
        elif f.kind == "strings":
            w.strings(cdr.string_seq([str(x) for x in v]))
        elif f.kind == "array":
            w.array(v, f.dtype)
        elif f.kind == "scalar":
            size = np.dtype(f.dtype).itemsize
            w.raw(struct.pack("<" + f.code, v), size)
        else:
            raise cdr.LayoutError(f"LineLayout.{f.name}: no writer for a {f.kind}")
    return w.bytes()


def event_log_line(kind: int, train_id: str, station_name: str, actual_s: float,
                   scheduled_s: float, dwell_s: float, arrival_kind: int = 1
                   ) -> tuple[int, str]:
    """(level, text) of one arrival or departure for the event log.

    ``kind``: ``TrainEvent.KIND_*`` (``arrival_kind`` the arrival's code); times [s] of
    simulation.  A warning when the event is :data:`LATE_WARN_S` or more behind its
    timetable time.
    """
    late = actual_s - scheduled_s
    what = "arrives at" if kind == arrival_kind else "departs from"
    text = (f"{train_id} {what} {station_name} at {actual_s:.1f} s "
            f"({late:+.1f} s vs timetable)")
    if kind != arrival_kind:
        text += f", dwell {dwell_s:.1f} s"
    level = LOG_WARN if late >= LATE_WARN_S else LOG_INFO
    return level, text
