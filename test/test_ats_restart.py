"""The ats_regulator killed and restarted mid-run: it rebuilds its state, the graph goes on.

Requirement: if the ``ats_regulator`` node is killed and restarted mid-run it rebuilds its
state from the events it gets (``/line/events`` is transient-local, depth 10000) and the
graph goes on; the run's KPIs stay complete.

The fixture brings up the ``mini`` graph as ``python -m metro_atc run`` does (the process
list of :func:`metro_atc.launcher.build_commands`: installed executables, one OS process
each), twice at the same time on two private DDS domains: the run under test and an
uninterrupted reference run with the same scenario, seed and parameters. In the run under
test, once ``train_01`` has stopped at station 1 and has its departure command, the ATS is
SIGKILLed; the next arrival at an intermediate station then has no ATS to answer it and the
lockstep waits (``/clock`` stands still). A new ``ats_regulator`` with the same parameters
is started; it knows that arrival only from the transient-local event history and must
answer it with the decision of the uninterrupted run, and the run must end complete.
Lockstep runs are deterministic, so the whole run should equal the reference run.

The node logs nothing about the replay (only its start-up line): the replay is checked on
the topics.
"""

from __future__ import annotations

import csv
import json
import os
import signal
import time
from pathlib import Path
from typing import Any

import pytest

from background import job
from harness import DomainAllocator, NodeProcess, TopicProbe

pytestmark = pytest.mark.integration

SCENARIO = "mini"

STEP_TIMEOUT_S = 30.0
"""Lockstep step timeout of both runs [s] (the parameter defaults to 10 s). A restarted ATS
answers 3-5 s after its start on a quiet 2-core machine but took up to 12 s while other
work loaded it; the margin makes a lockstep miss here mean a stalled restart, not a busy
machine."""

RUN_TIMEOUT_S = 300.0
"""Wall-clock limit for a run [s] (~20-50 s each, the two runs side by side)."""


def _graph_commands(regulator: str, out_dir: Path) -> list[tuple[str, list[str]]]:
    """The run's process list, as ``python -m metro_atc run`` builds it (+ the step timeout)."""
    from metro_atc import launcher
    from metro_atc.core.line.scenario import load_scenario

    args = launcher._parser().parse_args(["--scenario", SCENARIO, "--regulator", regulator,
                                          "--no-plots", "--out", str(out_dir)])
    ids = launcher.scenario_train_ids(load_scenario(SCENARIO))
    cmds = []
    for label, argv in launcher.build_commands(args, ids, out_dir):
        if label == "line_simulator":
            argv = [*argv, "-p", f"step_timeout_s:={STEP_TIMEOUT_S}"]
        cmds.append((label, argv))
    return cmds


def _train_ids_arg(argv: list[str]) -> list[str]:
    """The trains of an ato_controller command line (``-p train_ids:=[a,b]``)."""
    for arg in argv:
        if arg.startswith("train_ids:="):
            return [t for t in arg.split(":=", 1)[1].strip("[]").split(",") if t]
    return []


def _same(a: Any, b: Any) -> bool:
    """Two messages carry the same values (repr: every field, NaN equal to NaN)."""
    return repr(a) == repr(b)


class Run:
    """One graph on its own domain, with a probe recording events, commands and the clock."""

    def __init__(self, name: str, regulator: str, env: dict[str, str], out_dir: Path,
                 probe: TopicProbe, procs: list[NodeProcess]) -> None:
        """Subscribe the probe, then start every process of the graph (added to ``procs``)."""
        from metro_atc_msgs.msg import DepartureCommand, TrainEvent
        from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
        from rosgraph_msgs.msg import Clock

        from metro_atc.nodes.common import QOS_CLOCK, QOS_EVENTS

        self.name, self.env, self.out, self.probe = name, env, out_dir, probe
        self.log_dir = out_dir / "logs"
        self.log_dir.mkdir(parents=True, exist_ok=True)
        self.commands = _graph_commands(regulator, out_dir)
        self.train_ids = [t for label, argv in self.commands if label.startswith("ato_")
                          for t in _train_ids_arg(argv)]
        # transient-local like the publisher (a late joiner gets its latest command), with a
        # deep reader queue: no live command is dropped when several arrive at once
        qos_cmd = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=200,
                             reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.events = probe.subscribe(TrainEvent, "/line/events", QOS_EVENTS)
        self.clock = probe.subscribe(Clock, "/clock", QOS_CLOCK)
        self.cmds = {t: probe.subscribe(DepartureCommand, f"/{t}/departure_command", qos_cmd)
                     for t in self.train_ids}
        self.procs: dict[str, NodeProcess] = {}
        for label, argv in self.commands:
            self.procs[label] = NodeProcess(argv, env, self.log_dir / f"{label}.log")
            procs.append(self.procs[label])

    def argv(self, label: str) -> list[str]:
        """The command line of a process of the run."""
        return next(argv for lab, argv in self.commands if lab == label)

    def sim_time(self) -> float:
        """Latest /clock [s], -1 before the first (call under the probe lock)."""
        if not self.clock:
            return -1.0
        c = self.clock[-1].clock
        return c.sec + 1e-9 * c.nanosec

    def arrivals(self) -> list[tuple[str, int, float]]:
        """(train, station, time) of every arrival so far (call under the probe lock)."""
        return [(e.train_id, e.station_index, e.actual_time_s) for e in self.events
                if e.kind == e.KIND_ARRIVAL]

    def commanded(self, train: str, station: int) -> list[Any]:
        """Departure commands received for ``train`` at ``station`` (under the probe lock)."""
        return [c for c in self.cmds[train] if c.station_index == station]

    def finish(self) -> dict[str, Any]:
        """Wait for the simulator to exit; its exit code, kpis.json, events.csv rows, logs."""
        sim = self.procs["line_simulator"]
        code = sim.wait(RUN_TIMEOUT_S)
        assert code is not None, f"{self.name}: the simulator did not finish\n" + sim.log()
        assert (self.out / "kpis.json").is_file(), f"{self.name}: no kpis.json\n" + sim.log()
        with (self.out / "events.csv").open(newline="") as fh:
            rows = list(csv.DictReader(fh))
        return {"code": code, "kpis": json.loads((self.out / "kpis.json").read_text()),
                "rows": rows, "logs": {label: p.log() for label, p in self.procs.items()}}

    def recorded(self) -> dict[str, Any]:
        """Copies of what the probe recorded: commands per train, events (repr)."""
        with self.probe.lock:
            return {"cmds": {t: list(c) for t, c in self.cmds.items()},
                    "events": [repr(e) for e in self.events]}


REGULATOR = "lqr"
"""The regulator of both runs (stateful; "none" passes too, +25 s)."""


@job("restart")
def _restart_runs(tmp: Path) -> dict[str, Any]:
    """Run ``mini`` with an ATS kill and restart, and an uninterrupted reference run (a
    background job started with the session)."""
    from metro_atc.core.line.scenario import load_scenario

    regulator = REGULATOR
    n_st = len(load_scenario(SCENARIO).line.stations)
    procs: list[NodeProcess] = []
    domains = DomainAllocator()
    with domains.allocate() as dom, domains.allocate() as ref_dom:
        env = dict(os.environ, ROS_DOMAIN_ID=str(dom))
        ref_env = dict(os.environ, ROS_DOMAIN_ID=str(ref_dom))
        probe = TopicProbe(dom, name="restart_probe")
        ref_probe = TopicProbe(ref_dom, name="reference_probe")
        try:
            t0 = time.monotonic()
            ref = Run("reference", regulator, ref_env, tmp / "reference", ref_probe, procs)
            run = Run("restart", regulator, env, tmp / "restart", probe, procs)
            first = run.train_ids[0]
            sim = run.procs["line_simulator"]

            # 1. the first train has stopped at station 1 and has its departure command
            assert probe.wait_for(lambda: any(a[:2] == (first, 1) for a in run.arrivals())
                                  and bool(run.commanded(first, 1)), timeout=180), \
                "no stop of the first train at station 1\n" + sim.log()
            run.procs["ats_regulator"].stop(signal.SIGKILL)
            killed_at = time.monotonic()
            with probe.lock:
                t_kill = run.sim_time()
                entered = {a[0] for a in run.arrivals() if a[1] == 0}
            # trains that reach station 0 (enter the line) while the ATS is down
            entered_in_outage = [t for t in run.train_ids if t not in entered]

            # 2. a train reaches an intermediate station and nobody dispatches it: the
            # lockstep waits for the ATS (a dwelling train without departure command)
            def unanswered() -> list[tuple[str, int, float]]:
                return [a for a in run.arrivals()
                        if 0 < a[1] < n_st - 1 and not run.commanded(a[0], a[1])]
            assert probe.wait_for(lambda: bool(unanswered()), timeout=120), \
                "no arrival while the ATS was down\n" + sim.log()
            with probe.lock:
                (stalled_train, stalled_st, t_arrival), = unanswered()
            # the /clock of the step after the arrival is published after the event
            assert probe.wait_for(lambda: run.sim_time() >= t_arrival, timeout=30)
            with probe.lock:
                t_stall = run.sim_time()
            time.sleep(1.5)
            with probe.lock:
                clock_frozen = run.sim_time() == t_stall
                before_restart = {t: list(c) for t, c in run.cmds.items()}

            # 3. restart the ATS with the same parameters; it must dispatch the waiting train
            restarted_at = time.monotonic()
            new_ats = NodeProcess(run.argv("ats_regulator"), env,
                                  run.log_dir / "ats_regulator_restarted.log")
            procs.append(new_ats)
            answered = probe.wait_for(lambda: bool(run.commanded(stalled_train, stalled_st)),
                                      timeout=STEP_TIMEOUT_S)
            answer_s = time.monotonic() - restarted_at

            res = run.finish()
            ref_res = ref.finish()
            wall = time.monotonic() - t0
            time.sleep(0.3)  # late samples reach the probes before they are compared
            res.update(run.recorded())
            ref_res.update(ref.recorded())
            res["logs"]["ats_regulator_restarted"] = new_ats.log()
            note = (f"[{regulator}] ATS killed at t={t_kill:.2f} s, {killed_at - t0:.1f} s "
                    f"after start; {stalled_train} waited at station {stalled_st} "
                    f"(t={t_stall:.2f} s); new ATS started {restarted_at - killed_at:.1f} s "
                    f"after the kill, answered after {answer_s:.2f} s; both runs done "
                    f"after {wall:.1f} s")
            return {"note": note, "regulator": regulator, "n_st": n_st,
                    "train_ids": run.train_ids, "run": res, "ref": ref_res,
                    "stalled": (stalled_train, stalled_st), "clock_frozen": clock_frozen,
                    "before_restart": before_restart, "answered": answered,
                    "entered_in_outage": entered_in_outage}
        finally:
            for p in procs:
                p.stop()
            probe.close()
            ref_probe.close()


@pytest.fixture(scope="module")
def restart(installed: Path, background_jobs: Any) -> dict[str, Any]:
    """The result of the job :func:`_restart_runs` (its summary printed)."""
    res = dict(background_jobs.result("restart"))
    print("\n" + res["note"])
    return res


def test_lockstep_waits_for_the_restarted_ats(restart: dict[str, Any]) -> None:
    """While the ATS is down a train that reached a station is held: /clock stands still."""
    assert restart["clock_frozen"], "the lockstep went on without the ATS"
    assert restart["answered"], "the restarted ATS did not dispatch the waiting train\n" + \
        restart["run"]["logs"]["ats_regulator_restarted"]


def test_run_completes_after_the_restart(restart: dict[str, Any]) -> None:
    """The simulator ends normally; every train completes and departs every station.

    No ATP violation, no lockstep miss, no ATS timeout (the timetable fallback), no rejected
    message, no traceback in any log (the killed ATS aside, SIGKILL leaves none).
    """
    run, n_st = restart["run"], restart["n_st"]
    assert run["code"] == 0, run["logs"]["line_simulator"]
    for label, text in run["logs"].items():
        assert "Traceback" not in text, f"{label}:\n{text}"
    k = run["kpis"]
    assert k["finished"] is True
    assert k["completed_trains"] == k["trains"] == len(restart["train_ids"])
    assert k["atp_violations"] == 0
    assert k["lockstep_misses"] == 0, run["logs"]["line_simulator"]
    assert k["ats_timeouts"] == 0, run["logs"]["line_simulator"]
    assert k["rejected_messages"] == 0, run["logs"]["line_simulator"]
    for t in restart["train_ids"]:
        deps = {int(r["station_index"]) for r in run["rows"]
                if r["train_id"] == t and r["kind"] == "departure"}
        arrs = {int(r["station_index"]) for r in run["rows"]
                if r["train_id"] == t and r["kind"] == "arrival"}
        assert set(range(n_st - 1)) <= deps, (t, sorted(deps))
        assert set(range(1, n_st)) <= arrs, (t, sorted(arrs))
        per_train = next(p for p in k["per_train"] if p["train_id"] == t)
        assert per_train["completed"] is True and per_train["departures"] >= n_st - 1, t


def test_restarted_ats_rebuilt_its_state_from_the_events(restart: dict[str, Any]) -> None:
    """The restarted ATS decides like the uninterrupted one and never contradicts the old one.

    Its answer to the arrival it only knows from the event history is the reference run's
    command for that stop, field for field (the sequence number included: replaying the
    history it re-counts the commands of the killed ATS). Every command it republishes for
    the history repeats the killed ATS's command with the same sequence number, and no
    replayed event is rejected (out of order, duplicate).
    """
    run, ref = restart["run"], restart["ref"]
    train, st = restart["stalled"]
    before = restart["before_restart"]
    answer = [c for c in run["cmds"][train][len(before[train]):] if c.station_index == st]
    expected = [c for c in ref["cmds"][train] if c.station_index == st]
    assert len(answer) == 1 and len(expected) == 1, (answer, expected)
    assert _same(answer[0], expected[0]), (answer[0], expected[0])
    new_log = run["logs"]["ats_regulator_restarted"]
    assert "rejected" not in new_log, new_log
    # (a probe may miss a command published before it matched the ATS: a late joiner gets
    # only the latest one; the first train's command at station 1 is always seen by both)
    for t in restart["train_ids"]:
        ref_by_seq = {c.sequence: c for c in ref["cmds"][t]}
        old_by_seq = {c.sequence: c for c in before[t]}
        common = [c for c in before[t] if c.sequence in ref_by_seq]
        assert t != restart["train_ids"][0] or any(c.station_index == 1 for c in common)
        for c in common:  # the killed ATS decided like the reference run's
            assert _same(c, ref_by_seq[c.sequence]), (t, c, ref_by_seq[c.sequence])
        for c in run["cmds"][t][len(before[t]):]:
            if c.sequence in old_by_seq:
                assert _same(c, old_by_seq[c.sequence]), (t, c, old_by_seq[c.sequence])


def test_restart_run_equals_the_uninterrupted_run(restart: dict[str, Any]) -> None:
    """Lockstep determinism across the restart: the same events and KPIs as the reference run.

    A train that entered the line while the ATS was down leaves station 0 on the ATS's
    start-up command, which is the only command the ATS ever gives for station 0
    (``AtsDispatcher.on_event``), so its run is the same as without the outage.
    """
    run, ref = restart["run"], restart["ref"]
    assert ref["code"] == 0, ref["logs"]["line_simulator"]
    assert run["rows"] == ref["rows"]
    assert run["events"] == ref["events"]
    assert run["kpis"] == ref["kpis"]
