"""A run tells the truth: exit 0 only when the whole service ran, everything else stated.

One test (or a few) per way a run used to succeed silently: a service the scenario's end
truncated, a ``--duration`` cut, unknown parameters, a simulator whose ATOs never come,
regulator weights worse than the timetable, outputs that could not be written, and the
small untruths (message comments, the KPIs' regulator, the licence, a refused run's
checkpoints folder).  ROS-free and in-process where the behaviour allows; node processes
only where the real executable is the thing under test (each a few seconds).
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
import textwrap
import time
from pathlib import Path
from typing import Any

import pytest

from metro_atc import launcher
from metro_atc.core.plant.kpi import service_end
from metro_atc.exit_codes import NO_RESPAWN, NORMAL_END, Exit, outcome

ROOT = Path(__file__).resolve().parents[1]
MINI = ROOT / "metro_atc" / "scenarios" / "mini.yaml"


def short_mini(tmp_path: Path, duration_s: float) -> Path:
    """The mini scenario with its ``sim.duration_s`` set to ``duration_s`` [s]."""
    text = MINI.read_text()
    assert "  duration_s: 1200\n" in text
    f = tmp_path / "mini_short.yaml"
    f.write_text(text.replace("  duration_s: 1200\n", f"  duration_s: {duration_s:g}\n"))
    return f


# ----------------------------------------------------------------- exit codes, end of service
def test_exit_codes_are_distinct_and_classified() -> None:
    """Every code has one meaning; the simulator's normal ends are never restarted."""
    codes = [int(e) for e in Exit]
    assert len(codes) == len(set(codes)) and Exit.OK == 0 and Exit.TIMEOUT == 124
    assert NORMAL_END == {Exit.OK, Exit.SERVICE_INCOMPLETE, Exit.CUT}
    assert not NORMAL_END & NO_RESPAWN and Exit.REFUSED in NO_RESPAWN


def test_service_end_known_answers() -> None:
    """finished only when every train completed; the cut and the scenario end are told apart."""
    done = service_end(2, 2, 900.0, True, None, 1200.0)
    assert done["finished"] and done["incomplete_trains"] == 0 and done["cut_at_s"] is None
    assert outcome(done)[0] == Exit.OK
    short = service_end(60, 22, 600.0, True, None, 600.0)
    assert not short["finished"] and short["incomplete_trains"] == 38
    assert short["cut_at_s"] is None and "38 of 60" in short["end"]
    assert outcome(short) == (Exit.SERVICE_INCOMPLETE, short["end"])
    cut = service_end(60, 22, 300.0, True, 300.0, 3600.0)
    assert cut["cut_at_s"] == 300.0 and not cut["finished"]
    assert outcome(cut)[0] == Exit.CUT and "cut at t=300.0 s" in outcome(cut)[1]
    # a cut that lands after every train completed is a complete service
    assert service_end(2, 2, 900.0, True, 900.0, 1200.0)["cut_at_s"] is None
    stopped = service_end(2, 0, 10.0, False, None, 1200.0)
    assert not stopped["finished"] and outcome(stopped)[0] == Exit.SERVICE_INCOMPLETE
    # KPIs without the fields (an older kpis.json) are not a complete service
    assert outcome({})[0] == Exit.SERVICE_INCOMPLETE


def _stub_graph(monkeypatch: pytest.MonkeyPatch, kpis: dict[str, Any] | None,
                code: int = 0) -> None:
    """Replace the graph by a stub that writes ``kpis`` (None: nothing) and returns code."""
    def fake(a: Any, train_ids: Any, out_dir: Path, *args: Any, **kw: Any) -> int:
        if kpis is not None:
            (out_dir / "kpis.json").write_text(json.dumps(kpis))
        return code

    monkeypatch.setattr(launcher, "_run_processes", fake)
    monkeypatch.setattr(launcher, "start_zygote", lambda names: None)


def _said(capsys: pytest.CaptureFixture[str]) -> list[str]:
    """The launcher's stderr lines but its start line naming the resolved rolling stock."""
    return [ln for ln in capsys.readouterr().err.strip().splitlines()
            if not ln.startswith("metro_atc run: rolling stock ")]


def test_launcher_exit_code_follows_the_kpis(monkeypatch: pytest.MonkeyPatch,
                                             tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    """A truncated service exits 5 with one line naming how many trains and why; a cut 6;
    missing KPIs 4 (it was 1, or 0 with ``finished: true`` for a truncated service)."""
    base = ["--scenario", "mini", "--no-plots", "--json"]
    k = {"trains": 60, "completed_trains": 22, "sim_time_s": 600.0,
         **service_end(60, 22, 600.0, True, None, 600.0)}
    _stub_graph(monkeypatch, k)
    assert launcher.main(base + ["--out", str(tmp_path / "a")]) == Exit.SERVICE_INCOMPLETE
    err = _said(capsys)
    assert len(err) == 1 and "SERVICE_INCOMPLETE (exit 5)" in err[0] and "38 of 60" in err[0]
    k = {"trains": 2, "completed_trains": 0, "sim_time_s": 120.0,
         **service_end(2, 0, 120.0, True, 120.0, 1200.0)}
    _stub_graph(monkeypatch, k)
    assert launcher.main(base + ["--out", str(tmp_path / "b"), "--duration", "120"]) == \
        Exit.CUT
    out = capsys.readouterr()
    assert json.loads(out.out)["cut_at_s"] == 120.0 and "CUT (exit 6)" in out.err
    _stub_graph(monkeypatch, None)
    assert launcher.main(base + ["--out", str(tmp_path / "c")]) == Exit.OUTPUTS_NOT_WRITTEN
    err = _said(capsys)
    assert len(err) == 1 and "kpis.json" in err[0]
    k = {"trains": 2, "completed_trains": 2, "sim_time_s": 900.0,
         **service_end(2, 2, 900.0, True, None, 1200.0)}
    _stub_graph(monkeypatch, k)
    assert launcher.main(base + ["--out", str(tmp_path / "d")]) == Exit.OK
    assert _said(capsys) == []


def test_graph_reports_a_truncated_and_a_cut_service(ros_env: dict[str, str],
                                                     tmp_path: Path) -> None:
    """The real simulator (single-process graph): mini cut short by its own duration_s
    exits 5 with ``finished: false`` and both trains counted; ``--duration`` exits 6 with
    ``cut_at_s``; kpis.json names the regulator the report prints (it had no such key)."""
    f = short_mini(tmp_path, 300.0)
    run = [sys.executable, "-m", "metro_atc", "run", "--single-process", "--no-plots",
           "--json", "--scenario", str(f), "--regulator", "lqr"]
    r = subprocess.run(run + ["--out", str(tmp_path / "a")], env=ros_env, cwd=tmp_path,
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == Exit.SERVICE_INCOMPLETE, r.stderr[-2000:]
    k = json.loads((tmp_path / "a" / "kpis.json").read_text())
    assert k["finished"] is False and k["incomplete_trains"] == k["trains"] - \
        k["completed_trains"] > 0 and k["cut_at_s"] is None
    assert "scenario duration 300.0 s reached" in r.stderr
    printed = json.loads(r.stdout.strip().splitlines()[-1])
    assert k["regulator"] == printed["regulator"] and k["regulator"] not in (None, "")
    r = subprocess.run(run + ["--out", str(tmp_path / "b"), "--duration", "60"], env=ros_env,
                       cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert r.returncode == Exit.CUT, r.stderr[-2000:]
    k = json.loads((tmp_path / "b" / "kpis.json").read_text())
    assert k["finished"] is False and k["cut_at_s"] == pytest.approx(60.0)


@pytest.mark.parametrize("sim_rc, want, restarted", [
    (Exit.SERVICE_INCOMPLETE, Exit.OK, False),   # a normal end: the KPIs decide (after)
    (Exit.CUT, Exit.OK, False),
    (Exit.OUTPUTS_NOT_WRITTEN, Exit.OUTPUTS_NOT_WRITTEN, False),
    (Exit.GRAPH_NOT_READY, Exit.GRAPH_NOT_READY, False),
    (Exit.ERROR, Exit.NODE_FAILED, True),
])
def test_launcher_keeps_the_simulators_verdict(monkeypatch: pytest.MonkeyPatch,
                                               tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str],
                                               sim_rc: int, want: int,
                                               restarted: bool) -> None:
    """The simulator's own ends are not restarted: an incomplete or cut service ends the
    graph normally (its KPIs give the code), unwritten outputs (4) and a graph that never
    answered (7) are the run's code; a crash is restarted, then NODE_FAILED."""
    sim = [sys.executable, "-c", f"import time; time.sleep(1.0); raise SystemExit({sim_rc})"]
    other = [sys.executable, "-c", "import time; time.sleep(30)"]
    monkeypatch.setattr(launcher, "build_commands",
                        lambda a, ids, out, plans="", finished="": [
                            ("line_simulator", sim), ("ats_regulator", other)])
    a = launcher._parser().parse_args(["--out", str(tmp_path), "--respawn-limit", "1",
                                       "--timeout", "60"])
    code = launcher._run_processes(a, ["train_01"], tmp_path)
    err = capsys.readouterr().err
    assert code == want, err
    assert ("restarting it" in err) == restarted, err


# ----------------------------------------------------------------- refuse instead of ignore
def test_unknown_parameters_are_refused() -> None:
    """``-p no_such:=1``, ``-p node:no_such:=1``, ``-p other_node:x:=1`` and a params file
    whose sections name no node of the process: one line each; known ones pass."""
    from metro_atc.nodes.param_check import cli_params, unknown_problem
    nodes = [("line_simulator", "/", lambda n: n in ("seed", "scenario"))]
    argv = ["sim", "--ros-args", "-p", "seed:=3", "-p", "line_simulator:scenario:=mini"]
    assert cli_params(argv) == [(None, "seed", "seed:=3"),
                                ("line_simulator", "scenario", "line_simulator:scenario:=mini")]
    assert unknown_problem(nodes, argv) is None
    p = unknown_problem(nodes, ["sim", "--ros-args", "-p", "no_such_param:=1"])
    assert p is not None and "no_such_param" in p and "\n" not in p
    p = unknown_problem(nodes, ["sim", "--ros-args", "-p", "line_simulator:no_such:=1"])
    assert p is not None and "no_such" in p
    p = unknown_problem(nodes, ["sim", "--ros-args", "-p", "ats_regulator:seed:=1"])
    assert p is not None and "no node 'ats_regulator'" in p
    # arguments outside --ros-args are the program's, not parameters
    assert unknown_problem(nodes, ["sim", "-p", "x:=1"]) is None


def test_params_file_naming_no_node_is_refused(tmp_path: Path) -> None:
    """A params file under a wrong node name is refused; ``/**`` and the right name pass."""
    from metro_atc.nodes.param_check import unknown_problem
    nodes = [("line_simulator", "/", lambda n: n == "seed")]
    for key, ok in (("line_simulatr", False), ("ats_regulator", False), ("line_simulator", True),
                    ("/**", True)):
        f = tmp_path / f"p{ok}{len(key)}.yaml"
        f.write_text(f"{key}:\n  ros__parameters:\n    seed: 3\n")
        p = unknown_problem(nodes, ["sim", "--ros-args", "--params-file", str(f)])
        assert (p is None) == ok, (key, p)
        if not ok:
            assert "name no node" in p and key in p


@pytest.mark.parametrize("args, needle", [
    (["-p", "no_such_param:=1"], "no_such_param"),
    (["--params-file", "WRONG"], "line_simulatr"),
])
def test_node_refuses_unknown_parameters(installed: Path, ros_env: dict[str, str],
                                         tmp_path: Path, args: list[str], needle: str) -> None:
    """The installed simulator exits 2 at once with one line (it ignored them and waited)."""
    if "WRONG" in args:
        f = tmp_path / "wrong.yaml"
        f.write_text("line_simulatr:\n  ros__parameters:\n    scenario: mini\n")
        args = [str(f) if a == "WRONG" else a for a in args]
    r = subprocess.run([str(installed / "line_simulator"), "--ros-args", "-p",
                        "scenario:=mini", *args], env=ros_env, capture_output=True,
                       text=True, timeout=60)
    err = [ln for ln in (r.stderr + r.stdout).splitlines() if "error" in ln]
    assert r.returncode == Exit.REFUSED, r.stderr[-2000:]
    assert len(err) == 1 and needle in err[0], r.stderr[-2000:]


def test_simulator_gives_up_when_no_ato_ever_answers(installed: Path, ros_env: dict[str, str],
                                                     tmp_path: Path) -> None:
    """Alone on its domain, the simulator gives up after ato_absent_timeout_s of timed-out
    steps without any ATO answer: exit 7, one line naming the missing endpoints (it used to
    step once per step_timeout_s until the scenario's end)."""
    t0 = time.monotonic()
    r = subprocess.run([str(installed / "line_simulator"), "--ros-args", "-p", "scenario:=mini",
                        "-p", "startup_timeout_s:=1.0", "-p", "step_timeout_s:=0.2",
                        "-p", "ato_absent_timeout_s:=2.0", "-p", f"out_dir:={tmp_path}",
                        "-p", "plots:=false"], env=ros_env, capture_output=True,
                       text=True, timeout=90)
    wall = time.monotonic() - t0
    out = r.stderr + r.stdout
    assert r.returncode == Exit.GRAPH_NOT_READY, out[-2000:]
    err = [ln for ln in out.splitlines() if "line_simulator: error" in ln]
    assert len(err) == 1 and "no ATO answered" in err[0] and "/train_01/command" in err[0], out
    assert wall < 60.0
    print(f"\nsimulator without ATOs gave up after {wall:.1f} s wall: {err[0][:160]}")


# ----------------------------------------------------------------- regulator weights
@pytest.fixture()
def worse_weights(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> tuple[Path, Any]:
    """A generated line whose aoc weights, trained into a private cache (3 epochs: the
    bookkeeping, not the policy), carry a validation 20 % worse than the timetable (figures
    fixed here)."""
    pytest.importorskip("torch")
    from metro_atc.core.atr import weights_store as store
    from metro_atc.core.linegen import generate_line, scenario_yaml
    monkeypatch.setenv(store.CACHE_ENV, str(tmp_path / "cache"))
    monkeypatch.setattr(store, "validate", lambda line, reg, w: {
        "cost": 120.0, "cost_none": 100.0, "ratio_to_none": 1.2, "episodes": 8,
        "delay_s": 180.0})
    real = store.train_weights

    def quick(kind: str, line: Any, out: Path, **kw: Any) -> Any:
        return real(kind, line, out, **dict(kw, epochs=3))

    monkeypatch.setattr(store, "train_weights", quick)
    f = tmp_path / "gen.yaml"
    f.write_text(scenario_yaml(generate_line(7, n_stations=5)))
    return f, store


def test_worse_than_timetable_weights_are_refused(worse_weights: tuple[Path, Any],
                                                  tmp_path: Path,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    """Auto-trained weights worse than the timetable: refused with the figures and no node
    started (they were used without a word); ``--accept-worse-regulator`` runs them with the
    figures as a warning; the cache path is stated; a refused run leaves no checkpoints."""
    from metro_atc.core.atr.lines import atr_line_for
    from metro_atc.core.line.scenario import load_scenario
    f, store = worse_weights
    scn = load_scenario(str(f))
    a = launcher.parse_args(["--scenario", str(f), "--regulator", "aoc"])
    problem = launcher.prepare_regulator(a, scn)
    err = capsys.readouterr().err
    assert problem is not None and "120.0" in problem and "100.0" in problem and \
        "--accept-worse-regulator" in problem, problem
    cached = store.cached_path("aoc", atr_line_for(scn))
    assert cached.is_file() and f"{cached} (trained)" in err, err
    a = launcher.parse_args(["--scenario", str(f), "--regulator", "aoc",
                             "--accept-worse-regulator"])
    assert launcher.prepare_regulator(a, scn) is None
    err = capsys.readouterr().err
    assert a.weights_file == str(cached) and f"{cached} (cached)" in err and "warning" in err
    out = tmp_path / "o"
    code = launcher.main(["--scenario", str(f), "--regulator", "aoc", "--out", str(out),
                          "--no-plots", "--train-regulator", "never"])
    assert code == Exit.REFUSED and not (out / "logs").exists()
    assert not (out / "checkpoints").exists()


def test_training_time_is_in_the_wall_time(worse_weights: tuple[Path, Any], tmp_path: Path,
                                           monkeypatch: pytest.MonkeyPatch,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    """A run that trains its regulator reports the training in ``regulator_training_s`` and
    counts it in ``wall_time_s``; the weights file is in the report."""
    f, store = worse_weights
    k = {"trains": 3, "completed_trains": 3, "sim_time_s": 100.0,
         **service_end(3, 3, 100.0, True, None, 1200.0)}
    real = store.train_weights

    def slow(kind: str, line: Any, out: Path, **kw: Any) -> Any:
        time.sleep(1.0)  # a known lower bound on the training's wall time
        return real(kind, line, out, **kw)

    monkeypatch.setattr(store, "train_weights", slow)
    _stub_graph(monkeypatch, k)
    code = launcher.main(["--scenario", str(f), "--regulator", "aoc", "--json", "--no-plots",
                          "--accept-worse-regulator", "--out", str(tmp_path / "o")])
    assert code == Exit.OK, capsys.readouterr().err
    rep = json.loads(capsys.readouterr().out)
    assert rep["regulator_training_s"] >= 1.0
    assert rep["wall_time_s"] >= rep["regulator_training_s"]
    from metro_atc.core.atr.lines import atr_line_for
    from metro_atc.core.line.scenario import load_scenario
    assert rep["weights"] == str(store.cached_path("aoc", atr_line_for(load_scenario(str(f)))))


def test_shipped_weights_state_their_validation(capsys: pytest.CaptureFixture[str]) -> None:
    """The shipped weights are used; if their own validation is worse than the timetable
    the run says so with the figures (never silently)."""
    pytest.importorskip("torch")
    from metro_atc.core.atr import weights_store as store
    from metro_atc.core.line.scenario import load_scenario
    scn = load_scenario("taipei_blue")
    for kind in ("aoc", "dhp"):
        a = launcher.parse_args(["--scenario", "taipei_blue", "--regulator", kind])
        assert launcher.prepare_regulator(a, scn) is None
        err = capsys.readouterr().err
        assert "(shipped)" in err and a.weights_source == "shipped"
        worse = store.validation_problem(Path(a.weights_file))
        assert (worse is not None) == ("warning" in err), err
        if worse is not None:
            assert worse in err


# ----------------------------------------------------------------- outputs not written
def test_failed_outputs_raise_after_the_kpis(tmp_path: Path,
                                             monkeypatch: pytest.MonkeyPatch) -> None:
    """events.csv that cannot be written: kpis.json is written, then an OSError names the
    missing file (it was logged and the run exited 0)."""
    from metro_atc import plots
    from metro_atc.nodes.sim_outputs import write_outputs

    def fail(*_: Any, **__: Any) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(plots, "write_events_csv", fail)
    logged: list[str] = []
    log = type("L", (), {"error": lambda self, m: logged.append(m)})()
    with pytest.raises(OSError, match="outputs not written: events.csv"):
        write_outputs(str(tmp_path), None, {"a": 1}, False, {}, log)
    assert json.loads((tmp_path / "kpis.json").read_text()) == {"a": 1} and logged
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(OSError, match="outputs not written"):
        write_outputs(str(blocker / "out"), None, {"a": 1}, False, {}, log)


def test_node_process_exits_4_when_close_fails(ros_env: dict[str, str], tmp_path: Path) -> None:
    """run_nodes: a node whose close (its outputs) fails makes the process exit 4 with one
    line (it printed "shutdown: ..." and exited 0)."""
    code = textwrap.dedent("""
        import sys
        from rclpy.node import Node
        from metro_atc.nodes.common import run_nodes

        class Writer(Node):
            def __init__(self):
                super().__init__("writer")

            def close(self):
                raise FileNotFoundError(2, "No such file or directory", "/gone/kpis.json")

        sys.exit(run_nodes(lambda: [Writer()], lambda ex, nodes: None, ["writer"]))
    """)
    r = subprocess.run([sys.executable, "-c", code], env=ros_env, capture_output=True,
                       text=True, timeout=60, cwd=tmp_path)
    assert r.returncode == Exit.OUTPUTS_NOT_WRITTEN, r.stderr[-2000:]
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "outputs not written" in lines[0] and "/gone/kpis.json" in \
        lines[0], lines


# ----------------------------------------------------------------- small untruths
def test_message_comments_say_what_the_nodes_do() -> None:
    """LineStatus comes every status_period_s (default 10 s), not once per simulated second;
    brake_diagnostic reads the fleet batches, not BrakeSensorData."""
    msg = ROOT / "msg_defs" / "msg"
    status = (msg / "LineStatus.msg").read_text()
    assert "once per simulated second" not in status and "status_period_s" in status
    period = re.search(r'"status_period_s", ([0-9.]+)',
                       (ROOT / "metro_atc" / "nodes" / "sim_params.py").read_text())
    assert period is not None and f"default {float(period[1]):g} s" in status
    sensor = (msg / "BrakeSensorData.msg").read_text().split("\n\n")[0]
    assert "-> brake_diagnostic)" not in sensor and "FleetBrakeSensorData" in sensor
    from metro_atc.nodes.common import FLEET_SENSOR_TOPIC
    assert FLEET_SENSOR_TOPIC in sensor


def test_license_is_the_apache_text() -> None:
    """package.xml says Apache-2.0 and points at LICENSE, which holds that licence's text."""
    text = (ROOT / "LICENSE").read_text()
    assert "Apache License" in text and "Version 2.0, January 2004" in text
    assert "TERMS AND CONDITIONS FOR USE, REPRODUCTION, AND DISTRIBUTION" in text
    assert '<license file="LICENSE">Apache-2.0</license>' in (ROOT / "package.xml").read_text()
