"""The dispatcher's messages: DispatcherCommand <-> :mod:`metro_atc.core.dispatcher_commands`.

* :func:`command_from_msg`: a request's command (never raises; the core validates it);
* :func:`applied_msg` / :func:`applied_from_msg`: an applied command as published on
  :data:`APPLIED_TOPIC` (step, sequence, stamp) and read back (ATOs, replay);
* :func:`recorded_commands`: the applied commands of a recorded run's bag, for
  ``run --replay-commands``.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from metro_atc_msgs.msg import DispatcherCommand

from metro_atc.core.dispatcher_commands import Applied, Command
from metro_atc.nodes import conversions as conv

SERVICE = "/line/dispatch"
"""The dispatcher's service (metro_atc_msgs/srv/Dispatch), served by line_simulator."""
APPLIED_TOPIC = "/line/dispatcher_commands"
"""The applied commands (DispatcherCommand, QOS_EVENTS: reliable, transient-local)."""
_FLOATS = ("start_m", "end_m", "speed_mps", "from_s")
_STRINGS = ("track", "tsr_id", "train_id", "station", "regulator", "weights_file")


def _float(v: Any) -> float:
    """A message float as a Python float (NaN for anything that is not one)."""
    try:
        return float(v)
    except (TypeError, ValueError):
        return math.nan


def command_from_msg(msg: Any) -> Command:
    """The core command of a DispatcherCommand (values as sent; checked by the core)."""
    f = {n: _float(getattr(msg, n)) for n in _FLOATS}
    t = {n: str(getattr(msg, n)) for n in _STRINGS}
    return Command(kind=int(msg.kind), track=t["track"], start_m=f["start_m"],
                   end_m=f["end_m"], speed_mps=f["speed_mps"], from_s=f["from_s"],
                   tsr_id=t["tsr_id"], train_id=t["train_id"], station=t["station"],
                   regulator=t["regulator"], weights_file=t["weights_file"])


def applied_msg(a: Applied) -> DispatcherCommand:
    """The DispatcherCommand of an applied command (stamp = its simulation time)."""
    m = DispatcherCommand()
    m.header.stamp = conv.to_time(a.t_s)
    m.header.frame_id = "line"
    m.step, m.sequence, m.kind = int(a.step), int(a.sequence), int(a.command.kind)
    for n in _FLOATS:
        setattr(m, n, float(getattr(a.command, n)))
    for n in _STRINGS:
        setattr(m, n, getattr(a.command, n))
    return m


def applied_from_msg(msg: Any) -> Applied:
    """An applied command as published (time from the stamp [s])."""
    return Applied(int(msg.step), conv.from_time(msg.header.stamp), int(msg.sequence),
                   command_from_msg(msg))


def recorded_commands(bag_dir: str) -> list[Applied]:
    """The applied commands a bag holds on :data:`APPLIED_TOPIC`, by sequence.

    Raises ValueError (one line) when the directory is not a readable bag.  A bag without
    the topic holds no command (an empty list).
    """
    from rclpy.serialization import deserialize_message
    from rosbags.rosbag2 import Reader
    path = Path(bag_dir)
    if not (path / "metadata.yaml").is_file():
        raise ValueError(f"{bag_dir}: not a rosbag2 directory (no metadata.yaml)")
    out: dict[int, Applied] = {}
    try:
        with Reader(path) as reader:
            conns = [c for c in reader.connections if c.topic == APPLIED_TOPIC]
            for _, _, raw in reader.messages(connections=conns):
                a = applied_from_msg(deserialize_message(bytes(raw), DispatcherCommand))
                out.setdefault(a.sequence, a)
    except Exception as exc:  # noqa: BLE001 - any reader failure is one line to the user
        raise ValueError(f"{bag_dir}: cannot read the bag ({type(exc).__name__}: {exc})") \
            from None
    return [out[k] for k in sorted(out)]
