"""Topic-level integration tests of the node graph (separate OS processes over DDS)."""

from __future__ import annotations

import json
import math
import os
import re
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from background import job
from bag_check import check_bag
from graph_runs import SCENARIO, run_graph
from harness import ROOT, DomainAllocator, NodeProcess, TopicProbe

pytestmark = pytest.mark.integration


@pytest.fixture(scope="module")
def two_runs(mini_graph_runs: dict[str, Any]) -> dict[str, Any]:
    """The session's two clean runs of the mini graph (``graph_runs.mini_graph_runs``):
    run 0 recorded, run 1 not, one ATO process per train, topics probed."""
    return mini_graph_runs


def test_every_train_completes(two_runs: dict[str, Any]) -> None:
    """All trains of the scenario complete it, with no ATP violation."""
    k = two_runs["kpis"][0]
    for key in ("trains", "completed_trains", "atp_violations", "atp_interventions",
                "min_separation_m", "energy_kwh", "max_delay_s", "sim_time_s", "wall_time_s",
                "real_time_factor", "lockstep_misses"):
        assert key in k, key
    assert k["trains"] >= 2
    assert k["completed_trains"] == k["trains"]
    assert k["atp_violations"] == 0
    assert k["energy_kwh"] > 0.0
    assert k["real_time_factor"] > 1.0


def test_events_arrive_in_order(two_runs: dict[str, Any]) -> None:
    """Per train: sequence numbers strictly increase, times never go back, stations advance."""
    events = two_runs["events"][0]
    n_st = two_runs["kpis"][0]["stations"]
    assert events, "no events received on /line/events"
    by_train: dict[str, list[tuple[Any, ...]]] = {}
    for e in events:
        by_train.setdefault(e[0], []).append(e)
    assert len(by_train) == two_runs["kpis"][0]["trains"]
    for tid, evs in by_train.items():
        seqs = [e[4] for e in evs]
        assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs), tid
        times = [e[3] for e in evs]
        assert times == sorted(times), tid
        arrivals = [e[2] for e in evs if e[1] == 1]
        departures = [e[2] for e in evs if e[1] == 2]
        # a stop at every station, in line order (entry at station 0 and the departure into
        # the terminus turnback may or may not be reported as events)
        assert departures == sorted(departures) and \
            set(range(n_st - 1)) <= set(departures), (tid, departures)
        assert arrivals == sorted(arrivals) and set(range(1, n_st)) <= set(arrivals), \
            (tid, arrivals)


def test_ato_publishes_planned_profiles(two_runs: dict[str, Any]) -> None:
    """Each departure command gets a planned speed-code profile that meets its target."""
    profiles = two_runs["profiles"][0]
    assert profiles, "no SpeedProfile on /train_02/speed_profile"
    p = profiles[-1]
    assert p.train_id == "train_02" and p.to_station == p.from_station + 1
    assert len(p.section_boundaries_m) == len(p.section_modes) + 1 >= 2
    assert all(2 <= m <= 5 for m in p.section_modes)
    assert p.predicted_energy_j > 0.0
    if p.feasible:
        assert abs(p.predicted_running_time_s - p.target_running_time_s) < 1.0


def test_states_are_consistent(two_runs: dict[str, Any]) -> None:
    """/train_01/state: one per lockstep step, position never goes back, speed is within
    the ATP supervision speed, modes are valid."""
    states = two_runs["states"][0]
    assert len(states) > 100
    steps = [s.step for s in states]
    assert steps == sorted(steps)
    xs = [s.position_m for s in states]
    assert all(b >= a - 1e-6 for a, b in zip(xs, xs[1:]))
    assert all(0.0 <= s.speed_mps <= s.supervision_speed_mps + 0.05 for s in states)
    assert all(0 <= s.mode <= 6 for s in states)
    assert any(s.mode == 1 for s in states) and any(s.mode == 2 for s in states)


def test_per_train_states_are_decimated_unless_recording(two_runs: dict[str, Any]) -> None:
    """/train_01/state: every step in the recorded run, every ``train_state_period_s``
    (1 s: 4 steps of 0.25 s) in the other, where the fleet state carries the lockstep; the
    values are the simulator's either way (the same steps carry the same states)."""
    rec, dec = two_runs["states"]
    dt = two_runs["clock"][0][1] - two_runs["clock"][0][0]
    every = round(1.0 / dt)
    assert every >= 2
    s_rec = [s.step for s in rec]
    s_dec = [s.step for s in dec]
    assert s_rec == list(range(s_rec[0], s_rec[-1] + 1))
    gaps = [b - a for a, b in zip(s_dec, s_dec[1:])]
    assert gaps and max(gaps) == every and sorted(gaps)[len(gaps) // 2] == every, gaps[:20]
    assert all(k % every == 0 for k in s_dec[2:]), s_dec[:10]
    by_step = {s.step: s for s in rec}
    for s in dec:
        r = by_step[s.step]
        assert (s.position_m, s.speed_mps, s.mode) == (r.position_m, r.speed_mps, r.mode)


def test_sensor_data_at_the_configured_rate(two_runs: dict[str, Any]) -> None:
    """/train_01/brake_sensors: 20 Hz (mini) while braking, a 1 s heartbeat otherwise."""
    samples = two_runs["sensors"][0]
    assert len(samples) > 50
    t = [x.header.stamp.sec + 1e-9 * x.header.stamp.nanosec for x in samples]
    assert all(b > a for a, b in zip(t, t[1:]))
    braking = [max(x.clamp_force_n) > 1000.0 for x in samples]
    gaps = [b - a for a, b, br in zip(t, t[1:], braking[1:]) if br]
    assert gaps and min(gaps) >= 0.05 - 1e-6
    assert sorted(gaps)[len(gaps) // 2] == pytest.approx(0.05, abs=1e-3)
    assert all(len(x.wheel_angular_speed_radps) == 4 and len(x.clamp_force_n) == 4
               for x in samples)


def test_per_train_sensor_topic_carries_the_fleet_samples(two_runs: dict[str, Any]) -> None:
    """An outside reader of /train_01/brake_sensors (the probe) gets the samples of the fleet
    topic (/line/brake_sensors, from the recorded bag), value for value, until the end of the
    run: the per-train topic is published while it has a reader, although no node of the
    graph reads it."""
    import numpy as np
    from rosbags.highlevel import AnyReader

    bag = Path(two_runs["kpis"][0]["bag"])
    fleet: dict[int, np.ndarray] = {}
    with AnyReader([bag]) as r:
        cons = [c for c in r.connections if c.topic == "/line/brake_sensors"]
        for con, _, raw in r.messages(connections=cons):
            m = r.deserialize(raw, con.msgtype)
            n = len(m.axle_count)
            w = np.asarray(m.wheel_angular_speed_radps).reshape(n, -1)
            c = np.asarray(m.clamp_force_n).reshape(n, -1)
            for s in range(n):
                if m.train_id[m.sample_train[s]] == "train_01":
                    fleet[int(m.stamp_ns[s])] = np.concatenate((w[s], c[s], [
                        m.longitudinal_acceleration_mps2[s], m.reference_speed_mps[s],
                        m.car_mass_kg[s]]))
    got = two_runs["sensors"][0]
    # best effort to a Python reader, and the simulator looks for per-train readers once a
    # wall second: not every sample arrives, but what arrives is a fleet sample, to the end
    last = max(fleet)
    assert len(fleet) > 50 and len(got) > 50, (len(got), len(fleet))
    assert max(x.header.stamp.sec for x in got) >= 0.9e-9 * last, (len(got), last)
    for x in got:
        ns = x.header.stamp.sec * 1_000_000_000 + x.header.stamp.nanosec
        assert ns in fleet, ns
        one = np.concatenate((x.wheel_angular_speed_radps, x.clamp_force_n, [
            x.longitudinal_acceleration_mps2, x.reference_speed_mps, x.car_mass_kg]))
        assert np.array_equal(fleet[ns], one, equal_nan=True), ns


def test_clock_is_monotonic(two_runs: dict[str, Any]) -> None:
    """/clock never goes backwards and covers the run."""
    clock = two_runs["clock"][0]
    assert len(clock) > 100
    assert all(b >= a for a, b in zip(clock, clock[1:]))
    assert clock[-1] >= two_runs["kpis"][0]["sim_time_s"] - 1.0


def test_lockstep_is_deterministic(two_runs: dict[str, Any]) -> None:
    """Two lockstep runs of the same scenario give identical events and KPIs.

    The runs' own ``events.csv`` are compared byte for byte, and the events an outside
    reader received on ``/line/events`` in the recorded run equal its file.  Run 1 waits for
    no reader: an outside probe that DDS discovery matched late in its 2.5 s run got 1 of
    16 events (the simulator lingers 0.3 s for its readers; ``--wait-for-subscribers`` and
    ``--record`` are what make it wait for a reader).
    """
    a, b = two_runs["kpis"]
    skip = {"wall_time_s", "real_time_factor", "out_dir", "bag", "node_peak_rss_mb", "node_cpu_s",
            "loop_wall_s", "loop_real_time_factor"}
    assert {k: v for k, v in a.items() if k not in skip} == \
        {k: v for k, v in b.items() if k not in skip}
    out0, out1 = two_runs["out"]
    csv0 = (out0 / "events.csv").read_bytes()
    assert csv0 == (out1 / "events.csv").read_bytes()
    kinds = {"arrival": 1, "departure": 2}
    rows = [ln.split(",") for ln in csv0.decode().splitlines()[1:]]
    from_file = [(r[0], int(r[1]), r[3], round(float(r[4]), 2)) for r in rows
                 if r[3] in kinds]
    name = {v: k for k, v in kinds.items()}
    got = [(e[0], e[2], name[e[1]], round(e[3], 2)) for e in two_runs["events"][0]
           if e[1] in name]
    assert len(got) == len(two_runs["events"][0])  # the topic carries these two kinds
    assert sorted(got) == sorted(from_file)


def _log_shape(text: str) -> list[str]:
    """A node log's lines without their stamps and figures (what must not vary by run)."""
    return [re.sub(r"[0-9]+(\.[0-9]+)?", "#", ln) for ln in text.splitlines()]


def test_forked_nodes_end_like_execd_ones(two_runs: dict[str, Any]) -> None:
    """Run 0's nodes were forked by the zygote, run 1's exec'd: the zygote is reported only
    in run 0, and both runs leave the same journals and logs of the same shape, complete to
    their shutdown lines (a forked node ends with ``os._exit`` after its clean-up)."""
    k0, k1 = two_runs["kpis"]
    assert "zygote" in k0["node_cpu_s"] and "zygote" in k0["node_peak_rss_mb"]
    assert "zygote" not in k1["node_cpu_s"]
    out0, out1 = two_runs["out"]
    journals = sorted(p.name for p in (out1 / "checkpoints").glob("*.jsonl"))
    assert len(journals) >= 2 * k1["trains"]
    assert journals == sorted(p.name for p in (out0 / "checkpoints").glob("*.jsonl"))
    for name in journals:
        a, b = ((o / "checkpoints" / name).read_text() for o in (out0, out1))
        if name == "line_simulator_departures.jsonl":
            # "k", the step a departure command was taken at, is the wall clock's: run 0
            # waits for its recorder before step 0, so the ATS's first commands come earlier.
            # The journal is written ahead, in arrival order: commands to different trains
            # come on different topics, whose relative order DDS does not keep (CI saw trains
            # 0 and 1 swapped); the same commands must be there, each train's in its order
            a, b = (sorted(re.sub(r'"k": [0-9]+', '"k"', x).splitlines(keepends=True),
                           key=lambda ln: json.loads(ln.replace('"k"', '"k": 0'))["i"])
                    for x in (a, b))
        assert a == b, name
    logs = sorted(p.name for p in (out1 / "logs").glob("*.log"))
    for name in logs:
        if name == "line_simulator.log":
            continue  # run 0 waits for its recorder
        a, b = ((o / "logs" / name).read_text(errors="replace") for o in (out0, out1))
        assert _log_shape(a) == _log_shape(b), name
    brake = (out0 / "logs" / "brake_diagnostic.log").read_text().splitlines()
    assert brake and all(f"train_{n:02d}: " in "\n".join(brake[-k0["trains"]:])
                         for n in range(1, k0["trains"] + 1)), brake[-5:]


def test_recorded_bag_reads_back(two_runs: dict[str, Any]) -> None:
    """The rosbag2 MCAP of the recorded run, read by ``rosbags``: every message of the run
    exactly once from its first step (:func:`bag_check.check_bag`: one /clock and one fleet
    state per step from step 0, a fleet command entry per fleet state entry, per train a
    state per echoed step and a command per state, none twice); QoS and type definitions
    stored with the topics."""
    check_bag(two_runs["kpis"][0])


def test_logs_of_normal_runs_are_clean(two_runs: dict[str, Any]) -> None:
    """No traceback, rcl error or invalid-context message in any node log of the runs."""
    bad = ("Traceback", "RCLError", "context is invalid", "context is not valid",
           "never awaited", "Exception")
    for out in two_runs["out"]:
        logs = sorted((out / "logs").glob("*.log"))
        assert len(logs) >= 5, logs
        for log in logs:
            text = log.read_text(errors="replace")
            hits = [b for b in bad if b in text]
            assert not hits, f"{log}: {hits}\n{text[-2000:]}"


@job("failing_starts")
def _failing_starts(tmp_path: Path) -> dict[str, Any]:
    """``run`` of AOC without weights, then the same with the launcher's pre-check skipped
    (a background job on its own domain): both processes' results and wall times."""
    import time

    with DomainAllocator().allocate() as dom:
        env = dict(os.environ, ROS_DOMAIN_ID=str(dom),
                   METRO_ATC_ATR_CACHE=str(tmp_path / "empty_cache"))
        args = ["--scenario", SCENARIO, "--regulator", "aoc", "--no-plots", "--out",
                str(tmp_path / "o")]
        t0 = time.monotonic()
        pre = subprocess.run([sys.executable, "-m", "metro_atc", "run", *args,
                              "--train-regulator", "never"],
                             env=env, capture_output=True, text=True, timeout=120, cwd=tmp_path)
        pre_wall = time.monotonic() - t0
        logs_after_pre = (tmp_path / "o" / "logs").exists()
        # the ATS node's own refusal (defence in depth): skip the launcher's pre-check
        code = ("import sys; import metro_atc.launcher as L; "
                "L.prepare_regulator = lambda a, s: None; sys.exit(L.main(sys.argv[1:]))")
        t0 = time.monotonic()
        node = subprocess.run([sys.executable, "-c", code, *args], env=env,
                              capture_output=True, text=True, timeout=120, cwd=tmp_path)
        node_wall = time.monotonic() - t0
    return {"pre": pre, "pre_wall": pre_wall, "logs_after_pre": logs_after_pre,
            "node": node, "node_wall": node_wall}


@pytest.fixture
def failing_starts(installed: Path, background_jobs: Any) -> dict[str, Any]:
    """The result of the job :func:`_failing_starts`."""
    return dict(background_jobs.result("failing_starts"))


def test_run_fails_fast_when_a_node_cannot_start(failing_starts: dict[str, Any]) -> None:
    """AOC without weights trained on the line: ``run`` refuses before any node (exit 2);
    with that check bypassed the ATS itself refuses and ``run`` stops (exit 3), naming it."""
    r = failing_starts["pre"]
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert r.returncode == 2, r.stderr
    assert len(lines) == 1 and "aoc" in lines[0] and "hash" in lines[0], lines
    assert not failing_starts["logs_after_pre"]
    print(f"\nrun refused after {failing_starts['pre_wall']:.1f} s: {lines[0]}")
    r = failing_starts["node"]
    assert r.returncode == 3, r.stderr
    # the run's start line names the resolved rolling stock; then the one error line
    lines = [ln for ln in r.stderr.splitlines()
             if ln.strip() and not ln.startswith("metro_atc run: rolling stock ")]
    assert len(lines) == 1 and "ats_regulator" in lines[0] and "weights" in lines[0], lines
    print(f"run with a failing ATS exited {r.returncode} after "
          f"{failing_starts['node_wall']:.1f} s: {lines[0]}")


def test_run_timeout_and_bad_out_dir_exit_nonzero(ros_env: dict[str, str],
                                                  tmp_path: Path) -> None:
    """``--timeout`` exits 124; an --out that cannot be a directory exits 2 before any node."""
    run = [sys.executable, "-m", "metro_atc", "run", "--scenario", SCENARIO, "--no-plots"]
    # the whole Blue line: minutes of wall time, never done within the 2 s (mini can be)
    long_run = [sys.executable, "-m", "metro_atc", "run", "--scenario", "taipei_blue",
                "--no-plots"]
    r = subprocess.run(long_run + ["--timeout", "2", "--out", str(tmp_path / "o")],
                       env=ros_env, capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert r.returncode == 124 and "timeout" in r.stderr, r.stderr
    assert not [p for p in (tmp_path / "o" / "logs").glob("*.log")
                if "Traceback" in p.read_text(errors="replace")]
    blocker = tmp_path / "file"
    blocker.write_text("x")
    r = subprocess.run(run + ["--out", str(blocker)], env=ros_env, capture_output=True,
                       text=True, timeout=60, cwd=tmp_path)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert not (tmp_path / "file" / "logs").exists()


@job("two_graphs_one_domain")
def _two_graphs_one_domain(tmp_path: Path) -> dict[str, Any]:
    """Two ``run`` started together on one domain (a background job on its own domain):
    the domain, each run's exit code and stderr."""
    run = [sys.executable, "-m", "metro_atc", "run", "--scenario", SCENARIO, "--no-plots",
           "--duration", "600", "--timeout", "240"]
    with DomainAllocator().allocate() as dom:
        env = dict(os.environ, ROS_DOMAIN_ID=str(dom))
        procs = [subprocess.Popen(run + ["--out", str(tmp_path / f"o{n}")], env=env,
                                  stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                  cwd=tmp_path) for n in range(2)]
        try:
            outs = [p.communicate(timeout=300) for p in procs]
        finally:
            for p in procs:
                if p.poll() is None:
                    p.kill()
                    p.communicate()
    return {"domain": dom, "codes": [p.returncode for p in procs],
            "stderr": [err for _, err in outs]}


@pytest.fixture
def two_graphs_one_domain(installed: Path, background_jobs: Any) -> dict[str, Any]:
    """The result of the job :func:`_two_graphs_one_domain`."""
    return dict(background_jobs.result("two_graphs_one_domain"))


def test_two_graphs_on_one_domain_are_refused(two_graphs_one_domain: dict[str, Any]) -> None:
    """Two ``run`` on one ROS domain would answer each other's lockstep (seen: ATOs following
    the other simulator's steps, 63 534 rejected commands, exit 0): a simulator that finds
    another one on its domain stops its graph with one line naming the domain; it says so on
    ``/line/simulator_refused`` and stays on the domain until the other has refused too
    (seen once: the other run did not see it within a fixed 2 s and ran to the end)."""
    codes, errs = two_graphs_one_domain["codes"], two_graphs_one_domain["stderr"]
    dom = two_graphs_one_domain["domain"]
    refused = [n for n, err in enumerate(errs) if "another line_simulator" in err
               and f"ROS_DOMAIN_ID={dom}" in err]
    print(f"\nexit codes {codes}; refused: {refused}")
    assert refused == [0, 1] and codes == [3, 3], [err[-1500:] for err in errs]


FAKE_REFUSAL = """
import time
import rclpy
from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile
rclpy.init()
node = Node("line_simulator")
pub = node.create_publisher(DiagnosticStatus, "/line/simulator_refused", QoSProfile(
    depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL))
pub.publish(DiagnosticStatus(level=DiagnosticStatus.ERROR, name="line_simulator"))
end = time.monotonic() + 60.0
while time.monotonic() < end:
    rclpy.spin_once(node, timeout_sec=0.1)
"""
"""A second ``line_simulator`` that announces its refusal (the handshake's topic) and stays."""


def test_a_late_refusal_stops_the_run(installed: Path, ros_env: dict[str, str],
                                      tmp_path: Path) -> None:
    """A simulator past its first 10 s (its own look for another one over) still stops its
    graph when another simulator of the domain refuses because of it: seen in CI, the other
    run refused and this one ran to the end."""
    dom = ros_env["ROS_DOMAIN_ID"]
    out = tmp_path / "o"
    run = [sys.executable, "-m", "metro_atc", "run", "--scenario", SCENARIO, "--no-plots",
           "--free-run", "--rtf", "20", "--timeout", "120", "--out", str(out)]
    p = subprocess.Popen(run, env=ros_env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                         text=True, cwd=tmp_path)
    fake = None
    try:
        log = out / "logs" / "line_simulator.log"
        deadline = time.monotonic() + 90.0
        while time.monotonic() < deadline and p.poll() is None and \
                not (log.is_file() and "graph ready" in log.read_text(errors="replace")):
            time.sleep(0.2)
        assert p.poll() is None, p.communicate()
        time.sleep(11.0)  # past ALONE_CHECK_S (10 s from the simulator's start)
        assert p.poll() is None, "the run ended before the refusal (mini at 20x: ~30 s)"
        fake = subprocess.Popen([sys.executable, "-c", FAKE_REFUSAL], env=ros_env)
        _, err = p.communicate(timeout=60)
    finally:
        for q in (p, fake):
            if q is not None and q.poll() is None:
                q.kill()
                q.communicate()
    assert p.returncode == 3, err[-1500:]
    assert "refused to run beside this one" in err and f"ROS_DOMAIN_ID={dom}" in err, err


@job("single_process_kpis")
def _single_process_run(tmp: Path) -> dict[str, Any]:
    """KPIs of a ``--single-process`` run of the scenario (background job, own domain)."""
    with DomainAllocator().allocate() as dom:
        return run_graph(dict(os.environ, ROS_DOMAIN_ID=str(dom)), tmp, "--single-process")


@pytest.fixture
def single_process_kpis(installed: Path, background_jobs: Any) -> dict[str, Any]:
    """The result of the job :func:`_single_process_run`."""
    return dict(background_jobs.result("single_process_kpis"))


def test_single_process_matches(two_runs: dict[str, Any], single_process_kpis: dict[str, Any]
                                ) -> None:
    """``--single-process`` runs the same nodes and gives the same KPIs as the graph."""
    k = single_process_kpis
    skip = {"wall_time_s", "real_time_factor", "out_dir", "mode", "bag", "node_peak_rss_mb",
            "node_cpu_s", "loop_wall_s", "loop_real_time_factor"}
    assert {x: v for x, v in k.items() if x not in skip} == \
        {x: v for x, v in two_runs["kpis"][0].items() if x not in skip}


def test_node_starts_without_sim_time(installed: Path, ros_env: dict[str, str],
                                      tmp_path: Path) -> None:
    """The installed line_simulator starts with use_sim_time:=false and stops on SIGINT."""
    p = NodeProcess.installed("line_simulator", ["-p", "use_sim_time:=false",
                                                 "-p", f"scenario:={SCENARIO}"],
                              ros_env, tmp_path)
    try:
        assert p.wait_for_log(f"scenario '{SCENARIO}'", timeout=30), p.log()
        assert p.alive()
    finally:
        code = p.stop()
    assert code == 0, p.log()
    assert "Traceback" not in p.log()


@pytest.mark.parametrize("content,expect", [
    ("line_simulator: [unclosed\n", "not valid YAML"),
    ("line_simulator:\n  seed: 3\n", "ros__parameters"),
])
def test_bad_params_file_exits_with_one_line(installed: Path, ros_env: dict[str, str],
                                             tmp_path: Path, content: str, expect: str) -> None:
    """A malformed params file: non-zero exit, one stderr line naming the file."""
    f = tmp_path / "bad.yaml"
    f.write_text(content)
    r = subprocess.run([str(installed / "line_simulator"), "--ros-args", "--params-file",
                        str(f)], env=ros_env, capture_output=True, text=True, timeout=60)
    assert r.returncode != 0
    err = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(err) == 1 and str(f) in err[0] and expect in err[0], r.stderr


def test_out_of_range_parameter_exits_with_one_line(installed: Path, ros_env: dict[str, str]
                                                    ) -> None:
    """An out-of-range parameter names the parameter and exits non-zero."""
    r = subprocess.run([str(installed / "line_simulator"), "--ros-args", "-p",
                        "real_time_factor:=-5.0"], env=ros_env, capture_output=True, text=True,
                       timeout=60)
    assert r.returncode != 0
    err = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(err) == 1 and "real_time_factor" in err[0], r.stderr


def test_unknown_scenario_exits_with_one_line(installed: Path, ros_env: dict[str, str]) -> None:
    """An unknown scenario name: the node and ``run`` exit non-zero with one clear line."""
    r = subprocess.run([str(installed / "line_simulator"), "--ros-args", "-p",
                        "scenario:=no_such_line"], env=ros_env, capture_output=True, text=True,
                       timeout=60)
    assert r.returncode != 0
    err = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(err) == 1 and "no_such_line" in err[0], r.stderr
    r = subprocess.run([sys.executable, "-m", "metro_atc", "run", "--scenario", "no_such_line"],
                       env=ros_env, capture_output=True, text=True, timeout=60)
    assert r.returncode == 2
    err = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(err) == 1 and "no_such_line" in err[0], r.stderr


def test_bad_commands_are_rejected_node_stays_alive(installed: Path, ros_env: dict[str, str],
                                                    probe: TopicProbe, tmp_path: Path) -> None:
    """NaN effort and a wrong train id on a command topic: logged, dropped, node alive."""
    from metro_atc_msgs.msg import TractionCommand, TrainState

    from metro_atc.nodes.common import QOS_RELIABLE

    states = probe.subscribe(TrainState, "/train_01/state", QOS_RELIABLE)
    pub = probe.publisher(TractionCommand, "/train_01/command", QOS_RELIABLE)
    p = NodeProcess.installed("line_simulator", ["-p", f"scenario:={SCENARIO}",
                                                 "-p", "startup_timeout_s:=0.0",
                                                 "-p", "step_timeout_s:=0.05"],
                              ros_env, tmp_path)
    try:
        assert probe.wait_for(lambda: pub.get_subscription_count() > 0, timeout=30)
        pub.publish(TractionCommand(train_id="train_01", step=0, effort=math.nan))
        assert p.wait_for_log("effort is not finite", timeout=20), p.log()
        pub.publish(TractionCommand(train_id="train_99", step=1, effort=0.5))
        assert p.wait_for_log("train_99", timeout=20), p.log()
        assert p.alive()
        assert probe.wait_for(lambda: len(states) > 0, timeout=30)
    finally:
        code = p.stop()
    assert code == 0
    assert "Traceback" not in p.log()


def test_generated_messages_import() -> None:
    """The generated metro_atc_msgs interfaces import and carry their constants."""
    from metro_atc_msgs.msg import (BrakeDiagnosis, BrakeSensorData, DepartureCommand,
                                    LineStatus, SpeedProfile, TractionCommand, TrainEvent,
                                    TrainState)
    assert TrainState.MODE_DWELL == 1 and TrainEvent.KIND_DEPARTURE == 2
    assert DepartureCommand.REGULATOR_AOC == 3 and BrakeDiagnosis.ERROR == 2
    for t in (BrakeSensorData, LineStatus, SpeedProfile, TractionCommand):
        assert t().header is not None


def test_install_layout() -> None:
    """Executables are where ``ros2 run`` looks; config and launch are in share/."""
    lib = ROOT / "install" / "metro_atc" / "lib" / "metro_atc"
    for exe in ("ats_regulator", "ato_controller", "line_simulator", "brake_diagnostic"):
        assert os.access(lib / exe, os.X_OK), exe
    share = ROOT / "install" / "metro_atc" / "share" / "metro_atc"
    assert (share / "launch" / "metro_line.launch.py").is_file()
    assert (share / "config" / "line_simulator.yaml").is_file()
    assert (share / "package.xml").is_file()


# ------------------------------------------------------------------ fuzz

_U64 = 2 ** 64 - 1


def _pick(rng: Any, values: list[Any]) -> Any:
    """One of ``values`` as the Python object (rng.choice would make 2**64-1 a float)."""
    return values[int(rng.integers(0, len(values)))]


_FUZZ_MESSAGES = 3000


def _fuzz_value(rng: Any, kind: str, train: str) -> Any:
    """A random value of a field type, extremes of the type included."""
    if kind == "f64":
        return float(rng.choice([math.nan, math.inf, -math.inf, 0.0, -0.0, 1.7e308, -1.7e308,
                                 5e-324, rng.normal(0.0, 1e3), rng.uniform(0.0, 3000.0)]))
    if kind == "u64":
        return int(_pick(rng, [0, 1, _U64, int(rng.integers(0, 3000)),
                               int(rng.integers(0, 2 ** 63))]))
    if kind == "i32":
        return int(_pick(rng, [-2 ** 31, 2 ** 31 - 1, -1, 0, 1, 2, int(rng.integers(-5, 10))]))
    if kind == "u32":
        return int(_pick(rng, [0, 1, 2 ** 32 - 1, int(rng.integers(0, 2 ** 32))]))
    if kind == "i64":
        return int(_pick(rng, [-2 ** 63, 2 ** 63 - 1, -1, 0, int(rng.integers(0, 3 * 10 ** 12))]))
    if kind == "u8":
        return int(rng.choice([0, 1, 2, 255, int(rng.integers(0, 256))]))
    if kind == "bool":
        return bool(rng.integers(0, 2))
    if kind == "train":
        return str(rng.choice([train, train, "", "train_99", "x" * 1000,
                               "\u00e9\u4e2d\U0001f600"]))
    if kind == "f64[]":
        n = int(rng.choice([0, 1, 3, 4, 4, 4, 5, 100]))
        return [_fuzz_value(rng, "f64", train) for _ in range(n)]
    if kind.endswith("[2]"):  # fleet arrays: mostly two trains (the mini line), some not
        n = int(rng.choice([0, 1, 2, 2, 2, 2, 3]))
        if kind == "train[2]":
            return [str(rng.choice(["train_01", "train_02", "train_01", "train_99", ""]))
                    for _ in range(n)]
        return [_fuzz_value(rng, kind[:-3], train) for _ in range(n)]
    raise AssertionError(kind)


_GRID_NS = 250_000_000
"""The mini line's control period [ns]: every lockstep time is a multiple of it."""


def _off_grid_ns(rng: Any) -> int:
    """A random nanosecond field at least 5 ms away from every multiple of 0.25 s.

    A fuzz message is hostile input: it must break a rule the nodes check.  With a stamp on
    the step grid (once: stamp 0, step 0, a valid train, mode and effort) a fuzzed command
    was a valid command for step 0 -- which the simulator cannot tell from its ATO's (DDS
    does not authenticate writers), and the last stop's CI run took it (energy and
    separation changed at round-off).  A command or fleet state carries its time twice (the
    stamp and the step, agreeing to 1e-6 relative: 3 ms at the largest random second, 3 000
    s), so an off-grid stamp breaks that rule whatever the other fields draw; a departure or
    event must agree with its own time field, drawn continuously (a match: < 1e-7 per
    message).  The other fields stay fully random.
    """
    while True:
        ns = int(rng.integers(0, 10 ** 9))
        if min(ns % _GRID_NS, _GRID_NS - ns % _GRID_NS) >= 5_000_000:
            return ns


def _fuzz_msg(rng: Any, msg_type: Any, fields: dict[str, str], train: str) -> Any:
    from builtin_interfaces.msg import Time

    m = msg_type()
    sec = int(_pick(rng, [0, 1, -2 ** 31, 2 ** 31 - 1, int(rng.integers(0, 3000))]))
    nsec = int(_pick(rng, [2 ** 32 - 1, _off_grid_ns(rng)]))
    m.header.stamp = Time(sec=sec, nanosec=nsec)
    for name, kind in fields.items():
        setattr(m, name, _fuzz_value(rng, kind, train))
    return m


@job("fuzzed_run")
def _fuzzed_run(tmp_path: Path) -> dict[str, Any]:
    """A run of the graph under fuzzing (background job, own domain): what
    :func:`test_fuzz_every_subscribed_topic` asserts on."""
    with DomainAllocator().allocate() as dom:
        return _fuzz_graph(dict(os.environ, ROS_DOMAIN_ID=str(dom)), tmp_path)


@pytest.fixture
def fuzzed_run(installed: Path, background_jobs: Any) -> dict[str, Any]:
    """The result of the job :func:`_fuzzed_run`."""
    return dict(background_jobs.result("fuzzed_run"))


def _fuzz_graph(ros_env: dict[str, str], tmp_path: Path) -> dict[str, Any]:
    """Run the graph while a probe publishes fuzz messages (see the test below)."""
    import threading
    import time

    import numpy as np
    from metro_atc_msgs.msg import (DepartureCommand, FleetBrakeSensorData, FleetCommand,
                                    FleetState, TractionCommand, TrainEvent)

    from metro_atc.nodes.common import (FLEET_SENSOR_TOPIC, QOS_EVENTS, QOS_FLEET_SENSOR,
                                        QOS_LATCHED, QOS_RELIABLE)

    specs: list[tuple[Any, str, Any, dict[str, str], str]] = []
    for t in ("train_01", "train_02"):
        specs += [
            (TractionCommand, f"/{t}/command", QOS_RELIABLE,
             {"train_id": "train", "step": "u64", "effort": "f64", "mode": "u8"}, t),
            (DepartureCommand, f"/{t}/departure_command", QOS_LATCHED,
             {"train_id": "train", "station_index": "i32", "departure_time_s": "f64",
              "target_running_time_s": "f64", "dwell_limit_s": "f64", "regulator": "u8",
              "sequence": "u64"}, t),
            (TrainEvent, "/line/events", QOS_EVENTS,
             {"train_id": "train", "kind": "u8", "station_index": "i32",
              "actual_time_s": "f64", "scheduled_time_s": "f64", "passengers_boarded": "u32",
              "passengers_alighted": "u32", "dwell_s": "f64", "sequence": "u64"}, t)]
    specs += [
        (FleetState, "/line/fleet_state", QOS_RELIABLE,
         {"train_id": "train[2]", "step": "u64", "position_m": "f64[2]", "speed_mps": "f64[2]",
          "acceleration_mps2": "f64[2]", "current_station": "i32[2]", "next_station": "i32[2]",
          "mode": "u8[2]", "departure_time_s": "f64[2]", "target_running_time_s": "f64[2]",
          "supervision_speed_mps": "f64[2]", "movement_authority_m": "f64[2]",
          "echo": "bool[2]"}, ""),
        (FleetCommand, "/line/fleet_command", QOS_RELIABLE,
         {"train_id": "train[2]", "step": "u64", "effort": "f64[2]", "mode": "u8[2]"}, ""),
        (FleetBrakeSensorData, FLEET_SENSOR_TOPIC, QOS_FLEET_SENSOR,
         {"train_id": "train[2]", "sample_train": "u32[2]", "stamp_ns": "i64[2]",
          "axle_count": "u32[2]", "wheel_angular_speed_radps": "f64[]",
          "clamp_force_n": "f64[]", "longitudinal_acceleration_mps2": "f64[2]",
          "reference_speed_mps": "f64[2]", "car_mass_kg": "f64[2]"}, "")]
    probe = TopicProbe(int(ros_env["ROS_DOMAIN_ID"]), name="fuzzer")
    pubs = [probe.publisher(s[0], s[1], s[2]) for s in specs]
    rng = np.random.default_rng(15)
    sent = [0] * len(specs)
    stop = threading.Event()
    errors: list[BaseException] = []

    def fuzz() -> None:
        # each topic is fuzzed as soon as its subscriber (the node) is up
        try:
            while not stop.is_set() and sum(sent) < _FUZZ_MESSAGES - len(specs):
                cap = _FUZZ_MESSAGES // len(specs)
                ready = [j for j, p in enumerate(pubs)
                         if sent[j] < cap and p.get_subscription_count() > 0]
                if not ready:
                    time.sleep(0.05)
                    continue
                # bursts: the mini graph runs in a few seconds of wall time now
                for _ in range(50):
                    j = ready[int(rng.integers(0, len(ready)))]
                    if sent[j] < cap:
                        pubs[j].publish(_fuzz_msg(rng, specs[j][0], specs[j][3], specs[j][4]))
                        sent[j] += 1
                time.sleep(0.002)
        except BaseException as exc:  # noqa: BLE001 - reported by the test
            errors.append(exc)

    th = threading.Thread(target=fuzz, daemon=True)
    th.start()
    out = tmp_path / "fuzzed"
    out.mkdir()
    # the scenario by a path YAML would misread (passed to nodes safely)
    scn_dir = tmp_path / "a: b #c"
    scn_dir.mkdir()
    scn_path = scn_dir / f"{SCENARIO}.yaml"
    scn_path.write_text((ROOT / "metro_atc" / "scenarios" / f"{SCENARIO}.yaml").read_text())
    try:
        r = subprocess.run([sys.executable, "-m", "metro_atc", "run", "--scenario", str(scn_path),
                            "--json", "--no-plots", "--out", str(out), "--ato-per-process", "1"],
                           env=ros_env, capture_output=True, text=True, timeout=300, cwd=out)
    finally:
        stop.set()
        th.join(timeout=5.0)
        probe.close()
    return {"r": r, "errors": errors, "sent": sent, "out": out, "scn_path": scn_path}


def test_fuzz_every_subscribed_topic(two_runs: dict[str, Any], fuzzed_run: dict[str, Any]
                                     ) -> None:
    """Random messages on every topic a node subscribes to: rejected, counted, harmless.

    During a lockstep run of the graph, a probe publishes ``_FUZZ_MESSAGES`` messages with
    random field values (NaN, +-inf, +-1.7e308, integer extremes, empty and 1000-character
    train ids, arrays of wrong lengths, random stamps) on the command, departure command and
    event topics of both trains and on the fleet state, fleet command and fleet brake sensor
    topics (the per-train state topics have no subscriber in the graph: the ATOs take their
    states from the fleet state) (the scenario given by a path
    containing ``": "`` and ``#``).  No node dies, the run completes,
    its KPIs and events are those of the unfuzzed run, and the rejections are counted (KPIs
    of the simulator, each node's log).
    """
    r, errors, sent = fuzzed_run["r"], fuzzed_run["errors"], fuzzed_run["sent"]
    out, scn_path = fuzzed_run["out"], fuzzed_run["scn_path"]
    assert r.returncode == 0, r.stderr[-3000:]
    assert "exited with" not in r.stderr, r.stderr[-3000:]
    assert not errors, errors
    assert sum(sent) >= 1000 and min(sent) >= 50, f"fuzz messages per topic: {sent}"
    fuzzed = json.loads(r.stdout.strip().splitlines()[-1])
    clean = two_runs["kpis"][0]
    skip = {"wall_time_s", "real_time_factor", "out_dir", "rejected_messages", "node_peak_rss_mb",
            "node_cpu_s", "rejected_by_kind", "scenario", "bag", "loop_wall_s",
            "loop_real_time_factor"}
    assert fuzzed["scenario"] == str(scn_path)
    assert {k: v for k, v in fuzzed.items() if k not in skip} == \
        {k: v for k, v in clean.items() if k not in skip}
    assert (out / "events.csv").read_text() == \
        (Path(clean["out_dir"]) / "events.csv").read_text()
    assert clean["rejected_messages"] == 0
    assert fuzzed["rejected_messages"] > 0 and sum(fuzzed["rejected_by_kind"].values()) == \
        fuzzed["rejected_messages"]
    logs = {p.name: p.read_text(errors="replace") for p in (out / "logs").glob("*.log")}
    for name, text in logs.items():
        assert "Traceback" not in text, (name, text[-3000:])
    for name in ("line_simulator.log", "ats_regulator.log", "brake_diagnostic.log",
                 "ato_train_01.log", "ato_train_02.log"):
        assert "rejected" in logs[name] or "skipped sample" in logs[name], name
