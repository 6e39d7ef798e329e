"""Kill-and-restart of every node kind: ``run`` respawns it and the run ends as if uninterrupted.

Two ``python -m metro_atc run --scenario mini`` graphs side by side, each on its own DDS
domain: one where the **line_simulator** is killed (SIGKILL) before its first checkpoint,
then the **ato_controller** process, then the simulator again (later), and one where the
**ats_regulator** and then, near the end of the run, the **brake_diagnostic** are killed,
each at a seeded random simulated time (printed): the ~200x mini graph finishes before the
brake node is back, so the simulator must wait at the end until every train's diagnosis
acknowledged its last sample (seen failing on a loaded CI before that wait existed). The
uninterrupted reference is the session's clean run of the mini graph
(``conftest.mini_graph_runs``, run 1, shared with ``test_graph``).
The launcher restarts each dead process (one line on stderr); the simulator starts again
from step 0 (no checkpoint yet) and later resumes from its last checkpoint, the ATO replays
its state journal (and follows the simulator back), the ATS replays the event history, the
brake diagnosis replays its sample journal and catches up on the samples the simulator
sends again. events.csv and kpis.json must equal the reference's exactly; the restarted
brake diagnosis must end with a complete sample stream and the reference's per-train
summary (verdict, mu_b, used/braked updates) where the reference's own best-effort stream
was complete.
Every kill of a run hits its graph while it runs; each comes after the previous restart was
taken up (simulated time past the previous kill again).
"""

from __future__ import annotations

import json
import os
import random
import re
import signal
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from background import job
from harness import DomainAllocator, NodeProcess, TopicProbe

pytestmark = pytest.mark.integration

SCENARIO = "mini"
SEED = 20261123
"""Seed of the kill times (the times are printed)."""
STEP_TIMEOUT_S = 180.0
"""Lockstep step timeout [s]: a respawned ATO (a new Python process, its planners' start-up
work, the journal replay) must answer within it; a lockstep miss would change the KPIs.
Measured: 5-15 s on a lightly loaded 2-core machine, 61 s at a load average of 30 (a miss
with a 60 s timeout)."""
RUN_TIMEOUT_S = 900.0
"""Wall-clock limit of a run [s]."""
KILLS = {"sim_ato_sim": ("line_simulator", "ato_train_01", "line_simulator"),
         "brake_ats": ("ats_regulator", "brake_diagnostic")}
"""Runs with kills: the processes killed, in order."""
WINDOWS = {"sim_ato_sim": ((10.0, 30.0), (60.0, 250.0), (280.0, 420.0)),
           "brake_ats": ((40.0, 120.0), (160.0, 260.0))}
"""Simulated-time windows of the kills [s]. ``sim_ato_sim`` (checkpoints every 200 s): the
simulator killed before its first checkpoint (it starts again from step 0 and re-applies
the departure journal), the ATO of train_01 while both trains run, the simulator again
later (it resumes from a checkpoint; the respawned ATO follows it back). Every last kill
comes before the last train's final run ends (~500 s), so the lockstep needs the restarted
node. The brake_diagnostic's window ends 360 s before the run (623 s): the kill loop reads
the simulated time from a probe of /clock, which lags the graph by ~1 s of wall time under
load, and the mini graph runs at up to ~250x: a kill drawn at 445 s once came after the
run's end with three suites on the 2 cores, and one drawn in 300-420 s after it on a quiet
machine (no respawn to test)."""
CHECKPOINT_PERIOD_S = {"sim_ato_sim": 200.0, "brake_ats": 30.0}
"""``--checkpoint-period`` of each run [s]. The kill loop reads the simulated time from a
probe in the test process, which lags the graph (the mini graph runs at ~200x real time,
0.1 s of lag is 20 simulated s, more with the faster simulator and the fleet sensor topic):
the first checkpoint of ``sim_ato_sim`` comes 170 s after the end of its first kill window
so that "killed before the first checkpoint" holds (with 120 s a loaded run once killed it
after the first checkpoint); the second checkpoint (400 s) may come before the third kill
(280-420 s): it resumes from one or the other."""


def _clock_s(probe_list: list[Any]) -> float:
    if not probe_list:
        return -1.0
    c = probe_list[-1].clock
    return c.sec + 1e-9 * c.nanosec


class Graph:
    """One ``run`` of the scenario on its own domain (a launcher process)."""

    def __init__(self, name: str, out: Path, dom: int, checkpoint_period_s: float = 30.0
                 ) -> None:
        """Start the launcher and a probe of /clock."""
        from rosgraph_msgs.msg import Clock

        from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

        from metro_atc.nodes.common import QOS_CLOCK

        self.name, self.out = name, out
        env = dict(os.environ, ROS_DOMAIN_ID=str(dom))
        out.mkdir(parents=True, exist_ok=True)
        self.proc = NodeProcess([sys.executable, "-m", "metro_atc", "run", "--scenario",
                                 SCENARIO, "--no-plots", "--json", "--out", str(out),
                                 "--checkpoint-period", str(checkpoint_period_s),
                                 "--respawn-limit", "2",
                                 "--step-timeout", str(STEP_TIMEOUT_S), "--timeout",
                                 str(RUN_TIMEOUT_S), "--progress", "never"], env,
                                out / "run.log")
        self.probe = TopicProbe(dom, name=f"resume_probe_{name}")
        # the latest clock only (best effort, depth 1): a reliable deep reader of a graph at
        # ~400x (1 600 clocks a wall second) fell behind by more than the 200 s to the first
        # checkpoint, so a kill drawn in 10-30 s landed after it (seen on a quiet machine)
        self.clock = self.probe.subscribe(Clock, "/clock", QoSProfile(
            history=HistoryPolicy.KEEP_LAST, depth=1,
            reliability=ReliabilityPolicy.BEST_EFFORT, durability=QOS_CLOCK.durability))

    def sim_time(self) -> float:
        """Latest simulated time seen on /clock [s] (-1 before the first)."""
        with self.probe.lock:
            return _clock_s(self.clock)

    def kill(self, label: str) -> float:
        """SIGKILL process ``label`` now; return the simulated time."""
        t = self.sim_time()
        pids = json.loads((self.out / "logs" / "pids.json").read_text())
        os.kill(int(pids[label]), signal.SIGKILL)
        return t

    def finish(self) -> dict[str, Any]:
        """Wait for the launcher; exit code, stdout/stderr text, kpis.json, events.csv."""
        code = self.proc.wait(RUN_TIMEOUT_S + 60.0)
        self.probe.close()
        res: dict[str, Any] = {"code": code, "log": self.proc.log()}
        kpi = self.out / "kpis.json"
        res["kpis"] = json.loads(kpi.read_text()) if kpi.is_file() else None
        ev = self.out / "events.csv"
        res["events"] = ev.read_text() if ev.is_file() else None
        res["logs"] = {p.stem: p.read_text(errors="replace")
                       for p in (self.out / "logs").glob("*.log")}
        return res


def _reference(clean: dict[str, Any]) -> dict[str, Any]:
    """The session's clean run 1 in the form of :meth:`Graph.finish`."""
    out = Path(clean["out"][1])
    return {"code": 0, "log": clean["stderr"][1],
            "kpis": json.loads((out / "kpis.json").read_text()),
            "events": (out / "events.csv").read_text(),
            "logs": {p.stem: p.read_text(errors="replace")
                     for p in (out / "logs").glob("*.log")}}


@job("resume_kill_runs")
def _kill_runs(tmp: Path) -> dict[str, Any]:
    """The runs with kills (kill times seeded), a background job started with the session:
    their results, the kills done (label, drawn time, actual time) and lines to print."""
    rng = random.Random(SEED)
    domains = DomainAllocator()
    graphs: dict[str, Graph] = {}
    with domains.allocate() as d1, domains.allocate() as d2:
        try:
            t0 = time.monotonic()
            for name, dom in zip(KILLS, (d1, d2)):
                graphs[name] = Graph(name, tmp / name, dom, CHECKPOINT_PERIOD_S[name])
            plan: dict[str, list[tuple[str, float, float]]] = {n: [] for n in KILLS}
            todo = {n: [(label, rng.uniform(*WINDOWS[n][k])) for k, label in enumerate(labels)]
                    for n, labels in KILLS.items()}
            deadline = time.monotonic() + RUN_TIMEOUT_S
            while any(todo.values()) and time.monotonic() < deadline:
                for name, left in todo.items():
                    if left and graphs[name].sim_time() >= left[0][1]:
                        label, at = left.pop(0)
                        plan[name].append((label, at, graphs[name].kill(label)))
                time.sleep(0.02)
            assert not any(todo.values()), f"kills not done: {todo}"
            results = {name: g.finish() for name, g in graphs.items()}
            notes = ["; ".join(f"{name}: {lab} killed at t={got:.2f} s (drawn {at:.2f} s)"
                               for lab, at, got in kills) for name, kills in plan.items()]
            notes.append(f"{len(graphs)} runs done after {time.monotonic() - t0:.0f} s wall")
            return {"results": results, "plan": plan, "notes": notes}
        finally:
            for g in graphs.values():
                g.proc.stop(signal.SIGTERM)
                g.probe.close()


@pytest.fixture(scope="module")
def resume_kill_runs(installed: Path, background_jobs: Any) -> dict[str, Any]:
    """The result of the job :func:`_kill_runs`."""
    return dict(background_jobs.result("resume_kill_runs"))


@pytest.fixture(scope="module")
def runs(resume_kill_runs: dict[str, Any], mini_graph_runs: dict[str, Any]
         ) -> dict[str, Any]:
    """The runs with kills (kill times seeded, printed) and the shared reference run."""
    done = resume_kill_runs
    print("\n" + "\n".join(done["notes"]))
    results = dict(done["results"], reference=_reference(mini_graph_runs))
    return {"results": results, "plan": done["plan"]}


def _brake_summary(text: str) -> dict[str, str]:
    """The last shutdown summary line of each train in a brake_diagnostic log."""
    out = {}
    for m in re.finditer(r"\[brake_diagnostic\]: (train_\w+): (.*)", text):
        out[m[1]] = m[2].strip()
    return out


def _comparable(kpis: dict[str, Any]) -> dict[str, Any]:
    """KPIs without wall-clock fields."""
    return {k: v for k, v in kpis.items() if "wall" not in k and "real_time" not in k}


def test_reference_run_completes(runs: dict[str, Any]) -> None:
    """The uninterrupted run ends normally with KPIs and events."""
    ref = runs["results"]["reference"]
    assert ref["code"] == 0, ref["log"]
    assert ref["kpis"] is not None and ref["kpis"]["finished"] is True
    assert ref["kpis"]["lockstep_misses"] == 0
    assert ref["events"] and ref["events"].count("\n") > 10


@pytest.mark.parametrize("name", sorted(KILLS))
def test_killed_nodes_were_respawned(runs: dict[str, Any], name: str) -> None:
    """``run`` restarted each killed process once (one line each) and exited 0."""
    res = runs["results"][name]
    assert res["code"] == 0, res["log"]
    for label in KILLS[name]:
        assert f"{label} exited with -9" in res["log"], res["log"]
        assert res["log"].count(f"{label} exited") == KILLS[name].count(label), res["log"]
    assert "(1 of 2)" in res["log"], res["log"]
    for label, text in res["logs"].items():
        assert "Traceback" not in text, f"{name}/{label}:\n{text}"


def test_simulator_restarted_from_scratch_then_resumed(runs: dict[str, Any]) -> None:
    """Killed before its first checkpoint the simulator started again at step 0; killed
    again later, it resumed from a checkpoint (once); the ATOs followed it back."""
    logs = runs["results"]["sim_ato_sim"]["logs"]
    assert logs["line_simulator"].count("resuming from the checkpoint of step") == 1, \
        logs["line_simulator"]
    assert logs["line_simulator"].count("graph ready after") == 3, logs["line_simulator"]
    assert "went back from step" in logs["ato_train_01"], logs["ato_train_01"]


def test_simulator_resumed_and_ato_replayed(runs: dict[str, Any]) -> None:
    """The respawned simulator resumed from a checkpoint; the respawned ATO replayed its
    journal; the ATOs that lived through the simulator's restarts followed it back."""
    logs = runs["results"]["sim_ato_sim"]["logs"]
    assert "resuming from the checkpoint of step" in logs["line_simulator"], \
        logs["line_simulator"]
    ato = logs["ato_train_01"]
    assert "went back from step" in ato, ato
    assert "restarted: replayed" in ato, ato


@pytest.mark.parametrize("name", sorted(KILLS))
def test_events_and_kpis_equal_the_uninterrupted_run(runs: dict[str, Any], name: str) -> None:
    """events.csv byte for byte, kpis.json field for field (wall-clock fields aside)."""
    ref, res = runs["results"]["reference"], runs["results"][name]
    assert res["events"] == ref["events"]
    assert res["kpis"] is not None
    assert _comparable(res["kpis"]) == _comparable(ref["kpis"])


def _diagnosis(line: str) -> str:
    """A summary line without what best-effort sample loss changes in any run.

    The sensor topic is best effort: uninterrupted runs of this test lost 0-60 standstill
    samples per train (``received``/``paused`` differ between two references; a paused
    sample never reaches the filter) and with them the ``longest gap`` figure.
    """
    keep = [p for p in line.split("; ") if not p.startswith("longest gap")]
    return re.sub(r"(received|paused) \d+, ", "", "; ".join(keep))


def _longest_gap_s(line: str) -> float:
    """The ``longest gap`` of a summary line [s] (1 s: the idle heartbeat, nothing lost)."""
    m = re.search(r"longest gap ([0-9.]+) s", line)
    assert m is not None, line
    return float(m[1])


def test_brake_diagnosis_equals_the_uninterrupted_run(runs: dict[str, Any]) -> None:
    """The respawned brake_diagnostic replayed its journal and caught up on the samples
    published while it was down (the simulator's re-send; no sample out of order), and it
    ends with the uninterrupted run's verdicts, mu_b judgement and counters, train by train
    -- compared for the trains whose streams were complete in both runs: on a loaded
    machine the best-effort sensor topic loses samples in any run (seen: gaps of 3.75 and
    10 s, 16 fewer updates, in uninterrupted runs and after the catch-up)."""
    ref = _brake_summary(runs["results"]["reference"]["logs"]["brake_diagnostic"])
    text = runs["results"]["brake_ats"]["logs"]["brake_diagnostic"]
    assert "restarted: replayed" in text, text
    # the simulator sent its kept samples again to the new reader, also when the node came
    # back in the run's last wall second (CI saw none then, twice: the live stream came first
    # and was acknowledged; now the node acknowledges its journal until the re-send reaches
    # back).  Whether the re-send reaches into what the killed node had journaled (then
    # "observer rebuilt from the journal") depends on where the kill fell between a journal
    # write and its acknowledgement: the rebuild is proven in process,
    # test_brake_journal::test_a_resend_overlapping_the_journal_rebuilds_to_the_same_state
    sim = runs["results"]["brake_ats"]["logs"]["line_simulator"]
    assert "kept brake sensor samples again to a new reader" in sim, sim
    assert "out of order" not in text, text
    got = _brake_summary(text)
    assert ref and set(ref) == set(got), (ref, got)
    complete = [t for t in ref if _longest_gap_s(ref[t]) <= 1.0 + 1e-6
                and _longest_gap_s(got[t]) <= 1.0 + 1e-6]
    print(f"\nbrake diagnosis compared with the reference for {complete} (streams with "
          f"losses: {sorted(set(ref) - set(complete))})")
    assert {t: _diagnosis(got[t]) for t in complete} == \
        {t: _diagnosis(ref[t]) for t in complete}, (got, ref)
