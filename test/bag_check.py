"""What a recorded run's bag must hold: every message of the run exactly once from its first
step (shared by ``test_graph::test_recorded_bag_reads_back`` and ``scripts`` runs under load).

Read back with ``rosbags`` (an independent reader): every topic of the graph's topic map with
its publishers' QoS and type definition; one ``/clock`` and one ``/line/fleet_state`` per
lockstep step from step 0; one ``/line/fleet_command`` entry per fleet-state entry (the
(step, train) pairs equal, none twice); per train one ``/<train>/state`` for each step its
fleet-state entry says was echoed (``echo``: from the train's first step in service) and a
``/<train>/command`` for each of them; the fleet brake sensor samples of every train in
stamp order, none twice; health from each node kind.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path
from typing import Any


def check_bag(kpis: dict[str, Any]) -> dict[str, Any]:
    """Assert the bag of a recorded run (its KPIs: ``bag``, ``steps``, ``per_train``);
    return a few counts of what it holds."""
    from rosbags.highlevel import AnyReader

    from metro_atc.nodes.bag_recorder import graph_topics

    bag = Path(kpis["bag"])
    assert (bag / "metadata.yaml").is_file()
    steps = int(kpis["steps"])
    ids = [t["train_id"] for t in kpis["per_train"]]
    clock: list[float] = []
    fleet_state: list[int] = []
    echoed: dict[str, list[int]] = {t: [] for t in ids}
    fs_pairs: list[tuple[int, str]] = []
    fc_pairs: list[tuple[int, str]] = []
    state: dict[str, list[int]] = {t: [] for t in ids}
    command: dict[str, list[int]] = {t: [] for t in ids}
    diag_names: set[str] = set()
    sensor_samples: dict[str, list[int]] = {t: [] for t in ids}
    with AnyReader([bag]) as r:
        topics = {c.topic: c for c in r.connections}
        assert set(topics) >= {t for t, _, _ in graph_topics(ids)}
        assert all(c.ext.offered_qos_profiles for c in r.connections)
        assert all(c.msgdef.data for c in r.connections)
        for con, _, raw in r.messages():
            m = r.deserialize(raw, con.msgtype)
            tid = con.topic.split("/")[1]
            if con.topic == "/clock":
                clock.append(m.clock.sec + 1e-9 * m.clock.nanosec)
            elif con.topic == "/line/fleet_state":
                fleet_state.append(int(m.step))
                for t, e in zip(m.train_id, m.echo):
                    fs_pairs.append((int(m.step), t))
                    if e:
                        echoed[t].append(int(m.step))
            elif con.topic == "/line/fleet_command":
                fc_pairs += [(int(m.step), t) for t in m.train_id]
            elif con.topic.endswith("/state"):
                state[tid].append(int(m.step))
            elif con.topic.endswith("/command"):
                command[tid].append(int(m.step))
            elif con.topic == "/diagnostics":
                diag_names.update(s.name.split(":")[0] for s in m.status)
            elif con.topic == "/line/brake_sensors":
                assert len(m.stamp_ns) == len(m.sample_train) and all(m.axle_count == 4)
                for j, ns in zip(m.sample_train, m.stamp_ns):
                    sensor_samples[m.train_id[j]].append(int(ns))
    dt = clock[1] - clock[0]
    # the fleet brake sensor samples of every train, in order, no duplicate
    for t in ids:
        ns = sensor_samples[t]
        assert len(ns) > 50 and all(b > a for a, b in zip(ns, ns[1:])), t
    assert len(clock) == steps and clock[0] == 0.0, (len(clock), steps, clock[:3])
    assert all(abs((b - a) - dt) < 1e-6 for a, b in zip(clock, clock[1:]))
    twice = sorted(k for k, n in Counter(fleet_state).items() if n > 1)
    assert not twice, f"/line/fleet_state twice: steps {twice[:10]}"
    assert fleet_state == list(range(steps)), \
        f"/line/fleet_state: steps {fleet_state[:3]}..{fleet_state[-3:]} of {steps}"
    twice_fc = sorted(k for k, n in Counter(fc_pairs).items() if n > 1)
    assert not twice_fc, f"/line/fleet_command twice: {twice_fc[:10]}"
    missing = sorted(set(fs_pairs) - set(fc_pairs))
    assert not missing, f"/line/fleet_command missing (step, train): {missing[:10]}"
    assert set(fc_pairs) == set(fs_pairs)
    for t in ids:
        s = state[t]
        assert echoed[t], f"{t}: no state echoed in the fleet state"
        assert s == echoed[t], (f"{t}: a state per echoed step: states {s[:2]}..{s[-2:]} "
                                f"({len(s)}), echoed {echoed[t][:2]}..{echoed[t][-2:]} "
                                f"({len(echoed[t])})")
        assert command[t] == s, (f"{t}: a command per state: commands from "
                                 f"{command[t][:1]} ({len(command[t])}), states from "
                                 f"{s[:1]} ({len(s)})")
    # health from each of the four node kinds (and the recorder)
    assert {"line_simulator", "ats_regulator", "ato_controller", "brake_diagnostic",
            "bag_recorder"} <= diag_names, diag_names
    return {"steps": steps, "states": {t: len(state[t]) for t in ids},
            "fleet_commands": len(fc_pairs)}
