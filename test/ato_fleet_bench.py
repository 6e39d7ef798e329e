"""Offline bench of one ATO process's lockstep path.

Builds the ATO nodes of one process as ``ato_controller`` does (journal on), and feeds
their :class:`FleetLink` the fleet states of a run, rebuilt from a checkpoint directory's
journals (``ato_<train>.jsonl``: every state each ATO acted on), as serialised CDR bytes,
without DDS in between.  Prints the CPU time of the whole callback path (decoding,
validation, tracking, journal, command encoding) per fleet state, and writes every
command sent (step, train, effort bits, mode) so two code versions compare byte for byte::

    PYTHONPATH=<code> python test/ato_fleet_bench.py OUT/checkpoints cmds.txt [--odd]
        [--profile prof.out]

``--odd``: host train_01, 03, ... (the launcher's first process); else the even ones.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, Sequence


def fleet_messages(ck_dir: Path) -> list[bytes]:
    """One serialised FleetState per step of the journals (trains in id order)."""
    import math

    from metro_atc_msgs.msg import FleetState
    from rclpy.serialization import serialize_message

    from metro_atc.nodes import conversions as conv

    per_step: dict[int, list[tuple[str, dict[str, Any]]]] = {}
    for p in sorted(ck_dir.glob("ato_*.jsonl")):
        tid = p.name[len("ato_"):-len(".jsonl")]
        for line in p.read_text().splitlines():
            if line.strip():
                s = json.loads(line)
                per_step.setdefault(int(s["step"]), []).append((tid, s))
    out = []
    for k in sorted(per_step):
        rows = sorted(per_step[k], key=lambda r: r[0])
        m = FleetState()
        t = float(rows[0][1]["t_s"])
        m.header.stamp = conv.to_time(t)
        m.header.frame_id = "line"
        m.step = k
        m.train_id = [tid for tid, _ in rows]
        for field, key in (("position_m", "x_m"), ("speed_mps", "v_mps"),
                           ("acceleration_mps2", "a_mps2"),
                           ("departure_time_s", "departure_time_s"),
                           ("target_running_time_s", "target_running_time_s"),
                           ("supervision_speed_mps", "supervision_speed_mps"),
                           ("movement_authority_m", "movement_authority_m")):
            setattr(m, field, [float(s[key]) if s[key] is not None else math.nan
                               for _, s in rows])
        m.current_station = [int(s["current_station"]) for _, s in rows]
        m.next_station = [int(s["next_station"]) for _, s in rows]
        m.mode = [int(s["mode"]) for _, s in rows]
        m.echo = [k % 40 == 0] * len(rows)
        out.append(bytes(serialize_message(m)))
    return out


def main(argv: Sequence[str] | None = None) -> int:
    """Run the bench (see the module docstring)."""
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("checkpoints", type=Path)
    p.add_argument("output", type=Path)
    p.add_argument("--odd", action="store_true")
    p.add_argument("--profile", type=Path, default=None)
    a = p.parse_args(argv)

    import rclpy
    from metro_atc_msgs.msg import FleetCommand, FleetState
    from rclpy.parameter import Parameter
    from rclpy.serialization import deserialize_message, serialize_message

    from metro_atc.core.bridge import timetable_for
    from metro_atc.core.line.scenario import load_scenario
    from metro_atc.nodes.ato_controller import AtoController, FleetLink

    msgs = fleet_messages(a.checkpoints)
    rclpy.init()
    scn = load_scenario("taipei_blue")
    tt = timetable_for(scn)
    ids = list(tt.train_ids)[0 if a.odd else 1::2]
    shared: dict[str, Any] = {}
    tmp = tempfile.mkdtemp(prefix="ato_bench_")
    nodes = [AtoController(t, scenario=scn, timetable=tt, shared=shared,
                           parameter_overrides=[Parameter("checkpoint_dir", value=tmp),
                                                Parameter("train_ids", value=ids)])
             for t in ids]
    link = FleetLink(nodes)
    sent: list[Any] = []

    def publish(m: Any) -> None:  # what rclpy's publish converts, without DDS
        sent.append(m if isinstance(m, (bytes, bytearray)) else serialize_message(m))

    link.pub.publish = publish  # type: ignore[method-assign]
    raw = bool(getattr(link.sub, "raw", False))

    def on_state(b: bytes) -> None:
        # a message-object subscription: rclpy deserialises each (as take does)
        link.on_fleet_state(b if raw else deserialize_message(b, FleetState))
    feed = msgs
    prof = None
    if a.profile is not None:
        import cProfile
        prof = cProfile.Profile(time.process_time)
        prof.enable()
    t0 = time.process_time()
    for m in feed:
        on_state(m)
    cpu = time.process_time() - t0
    if prof is not None:
        prof.disable()
        prof.dump_stats(str(a.profile))
    lines = []
    for c in sent:
        if isinstance(c, (bytes, bytearray)):
            c = deserialize_message(bytes(c), FleetCommand)
        for tid, u, md in zip(c.train_id, c.effort, c.mode):
            lines.append(f"{c.step} {c.header.stamp.sec}.{c.header.stamp.nanosec} {tid} "
                         f"{float(u).hex()} {int(md)}")
    a.output.write_text("\n".join(lines) + "\n")
    train_steps = sum(1 for _ in lines)
    print(json.dumps({"fleet_states": len(feed), "commands": len(sent),
                      "train_steps": train_steps, "cpu_s": round(cpu, 3),
                      "us_per_fleet_state": round(1e6 * cpu / max(len(feed), 1), 1),
                      "us_per_train_step": round(1e6 * cpu / max(train_steps, 1), 1)}))
    for n in nodes:
        n.destroy_node()
    rclpy.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
