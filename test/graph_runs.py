"""Clean ``python -m metro_atc run`` graphs of the mini scenario, shared by test modules.

Starting a multi-process graph is the dearest thing the suite does (~20 s of both cores per
mini run), so the uninterrupted reference runs are made once per session
(``conftest.mini_graph_runs``) and asserted on by every module that needs a clean run:
``test_graph`` (topics, determinism, bag, logs, single-process and fuzz comparisons) and
``test_resume`` (the reference the runs with killed nodes must equal).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from background import job
from harness import DomainAllocator, TopicProbe

SCENARIO = "mini"
"""The scenario of the shared runs."""
STEP_TIMEOUT_S = 180.0
"""Lockstep step timeout of the shared runs [s] (default 10 s): the two run side by side,
and a lockstep miss on a loaded machine would change their KPIs (a miss seen with 60 s at a
load average of 27, three runs side by side)."""
RUN_TIMEOUT_S = 900.0
"""Wall-clock limit of each shared run [s] (~20-40 s each on a quiet 2-core machine; 282 s
seen at a load average of 27)."""


def graph_argv(out: Path, *extra: str) -> list[str]:
    """``python -m metro_atc run --json`` of the mini scenario into ``out``."""
    return [sys.executable, "-m", "metro_atc", "run", "--scenario", SCENARIO, "--json",
            "--no-plots", "--out", str(out), *extra]


def start_graph(env: dict[str, str], out: Path, *extra: str) -> subprocess.Popen[str]:
    """Start a run in ``out`` (so the installed package, which the executables use, is
    imported); :func:`finish_graph` collects it."""
    return subprocess.Popen(graph_argv(out, *extra), env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, cwd=out)


def finish_graph(p: subprocess.Popen[str], timeout: float = RUN_TIMEOUT_S
                 ) -> tuple[dict[str, Any], str]:
    """Wait for a run; assert exit 0 and exactly one stdout line; its KPIs and its stderr."""
    try:
        stdout, stderr = p.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        p.kill()
        stdout, stderr = p.communicate()
        pytest.fail(f"run did not finish in {timeout:g} s\n{stderr[-3000:]}")
    assert p.returncode == 0, stderr[-3000:]
    lines = [ln for ln in stdout.splitlines() if ln.strip()]
    assert len(lines) == 1, f"--json must print exactly one line, got {stdout!r}"
    return json.loads(lines[0]), stderr


def run_graph(env: dict[str, str], out: Path, *extra: str) -> dict[str, Any]:
    """One run (:func:`start_graph` + :func:`finish_graph`); its KPIs."""
    return finish_graph(start_graph(env, out, *extra))[0]


@job("mini_graph_runs")
def mini_graph_runs(tmp: Path) -> dict[str, Any]:
    """Run the mini scenario twice through the multi-process graph, side by side on two
    domains, probing the topics of each.

    One ATO process per train (``--ato-per-process 1``): each train is followed by its own
    ATO node in its own OS process. Run 0 is recorded (``--record``: the recorder must not
    change the run), its nodes forked by the launcher's zygote; run 1 is not recorded and
    execs its nodes (``METRO_ATC_ZYGOTE=0``): forked and exec'd nodes must give one run.
    Lists indexed by run: ``kpis``, ``stderr``, ``out``
    (the ``--out`` directory: kpis.json, events.csv, logs/), and what the probes received:
    ``events`` (tuples), ``clock`` (s), ``profiles``, ``states``, ``sensors``.
    """
    from metro_atc_msgs.msg import BrakeSensorData, SpeedProfile, TrainEvent, TrainState
    from rosgraph_msgs.msg import Clock

    from metro_atc.nodes.common import (QOS_CLOCK, QOS_EVENTS, QOS_LATCHED, QOS_RELIABLE,
                                        QOS_SENSOR)

    results: dict[str, Any] = {"kpis": [], "stderr": [], "events": [], "clock": [],
                               "profiles": [], "states": [], "sensors": [], "out": []}
    domains = DomainAllocator()
    probes: list[TopicProbe] = []
    procs: list[subprocess.Popen[str]] = []
    with domains.allocate() as d0, domains.allocate() as d1:
        try:
            subs = []
            for k, dom in enumerate((d0, d1)):
                probe = TopicProbe(dom, name=f"probe_{k}")
                probes.append(probe)
                subs.append({
                    "events": probe.subscribe(TrainEvent, "/line/events", QOS_EVENTS),
                    "clock": probe.subscribe(Clock, "/clock", QOS_CLOCK),
                    "profiles": probe.subscribe(SpeedProfile, "/train_02/speed_profile",
                                                QOS_LATCHED),
                    "states": probe.subscribe(TrainState, "/train_01/state", QOS_RELIABLE),
                    "sensors": probe.subscribe(BrakeSensorData, "/train_01/brake_sensors",
                                               QOS_SENSOR)})
                out = tmp / f"run{k}"
                out.mkdir()
                results["out"].append(out)
                env = dict(os.environ, ROS_DOMAIN_ID=str(dom),
                           METRO_ATC_ZYGOTE=str(1 - k))
                procs.append(start_graph(env, out, "--ato-per-process", "1",
                                         "--step-timeout", str(STEP_TIMEOUT_S),
                                         *(["--record"] if k == 0 else [])))
            for p in procs:
                kpis, stderr = finish_graph(p)
                results["kpis"].append(kpis)
                results["stderr"].append(stderr)
            for probe, sub, kpis in zip(probes, subs, results["kpis"]):
                n_ev = sum(int(t["departures"]) for t in kpis["per_train"])
                probe.wait_for(lambda: len(sub["events"]) >= n_ev, timeout=10.0)
                with probe.lock:
                    results["events"].append([(e.train_id, e.kind, e.station_index,
                                               round(e.actual_time_s, 6), e.sequence)
                                              for e in sub["events"]])
                    results["clock"].append([c.clock.sec + 1e-9 * c.clock.nanosec
                                             for c in sub["clock"]])
                    for key in ("profiles", "states", "sensors"):
                        results[key].append(list(sub[key]))
        finally:
            for p in procs:
                if p.poll() is None:
                    p.kill()
                    p.communicate()
            for probe in probes:
                probe.close()
    return results


DAY = "taipei_blue_day"
"""The service day of the day run."""
DAY_REGULATOR = "lqr"
"""The day run's ATS regulator (the day plant's, both directions)."""
DAY_DURATION_S = 4300.0
"""Simulated time of the day run from its first step [s]: the first pull-outs, the first
trips of both directions to their termini (a trip takes ~44 min) and the first four
turnbacks (their next trips leave 3 954-4 201 s after the first step), cut before the day
ends."""


@job("day_graph_run")
def day_graph_run(tmp: Path) -> dict[str, Any]:
    """The first ``DAY_DURATION_S`` of the Taipei day through the multi-process graph.

    Cut by ``--duration``: the run exits 6 (CUT). Returns its exit code, KPIs, stderr and
    the ``--out`` directory (``day_calls.csv``, ``day_turnbacks.csv``, ``day_depot.csv``).
    """
    domains = DomainAllocator()
    out = tmp / "day"
    out.mkdir()
    with domains.allocate() as dom:
        env = dict(os.environ, ROS_DOMAIN_ID=str(dom))
        p = subprocess.Popen(
            [sys.executable, "-m", "metro_atc", "run", "--scenario", DAY, "--json",
             "--regulator", DAY_REGULATOR,
             "--duration", str(DAY_DURATION_S), "--step-timeout", str(STEP_TIMEOUT_S),
             "--out", str(out)], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
            text=True, cwd=out)
        try:
            stdout, stderr = p.communicate(timeout=RUN_TIMEOUT_S)
        finally:
            if p.poll() is None:
                p.kill()
                p.communicate()
    lines = [ln for ln in stdout.splitlines() if ln.strip()]
    return {"code": p.returncode, "kpis": json.loads(lines[-1]) if lines else {},
            "stderr": stderr, "out": out}
