"""``run`` respawns dead node processes up to ``--respawn-limit`` (ROS-free: stand-in processes).

The graph's commands are replaced by small Python processes: a "simulator" that ends
normally after a while, and nodes that die (SIGKILL, crash) or fail configuration.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import pytest

from metro_atc import launcher
from metro_atc.exit_codes import Exit

SIM = [sys.executable, "-c", "import time; time.sleep(4.0)"]
"""A simulator that runs 4 s and ends normally."""


def _node(script: str) -> list[str]:
    return [sys.executable, "-c", script]


def _run(monkeypatch: pytest.MonkeyPatch, tmp_path: Path, node: list[str],
         limit: int, capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    """Run the stand-in graph; (exit code, stderr)."""
    monkeypatch.setattr(launcher, "build_commands",
                        lambda a, ids, out, plans="", finished="": [
                            ("line_simulator", SIM), ("ats_regulator", node)])
    a = launcher._parser().parse_args(["--out", str(tmp_path), "--respawn-limit", str(limit),
                                       "--timeout", "60"])
    code = launcher._run_processes(a, ["train_01"], tmp_path)
    return code, capsys.readouterr().err


def test_a_killed_node_is_restarted_once(monkeypatch: pytest.MonkeyPatch, tmp_path: Path,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    """Killed on its first start (SIGKILL), the node runs on after one restart: exit 0."""
    marker = tmp_path / "started_once"
    node = _node(f"import os, signal, time, pathlib\n"
                 f"m = pathlib.Path({str(marker)!r})\n"
                 f"if not m.exists():\n"
                 f"    m.write_text('x'); os.kill(os.getpid(), signal.SIGKILL)\n"
                 f"time.sleep(30)\n")
    cleans: list[int] = []
    monkeypatch.setattr(launcher, "clean_killed_shm", lambda: cleans.append(1) or 3)
    code, err = _run(monkeypatch, tmp_path, node, 2, capsys)
    assert code == 0, err
    assert err.count("restarting it") == 1, err
    assert "ats_regulator exited with -9 (killed by SIGKILL); restarting it (1 of 2)" in err
    # the killed process's DDS shared memory is cleaned once, at the end
    assert cleans == [1] and "removed 3 Fast DDS shared-memory segments" in err, err
    pids: dict[str, Any] = json.loads((tmp_path / "logs" / "pids.json").read_text())
    assert set(pids) == {"line_simulator", "ats_regulator"}


def test_beyond_the_limit_the_run_fails(monkeypatch: pytest.MonkeyPatch, tmp_path: Path,
                                        capsys: pytest.CaptureFixture[str]) -> None:
    """A node that always crashes is restarted ``limit`` times, then the run exits 3."""
    node = _node("print('error: boom'); raise SystemExit(1)")
    monkeypatch.setattr(launcher, "clean_killed_shm", lambda: pytest.fail("nothing killed"))
    code, err = _run(monkeypatch, tmp_path, node, 2, capsys)
    assert code == Exit.NODE_FAILED, err
    assert "(1 of 2)" in err and "(2 of 2)" in err and "(3 of 2)" not in err, err
    assert "ats_regulator exited with 1 (respawn limit reached): error: boom" in err, err
    # each start appended to the same log
    assert (tmp_path / "logs" / "ats_regulator.log").read_text().count("error: boom") == 3


@pytest.mark.parametrize("limit", [0, 3])
def test_no_respawn_for_configuration_errors_or_limit_0(
        monkeypatch: pytest.MonkeyPatch, tmp_path: Path, capsys: pytest.CaptureFixture[str],
        limit: int) -> None:
    """Exit 2 (a configuration error: a restart cannot fix it) and ``--respawn-limit 0``
    end the run at the first death."""
    node = _node("raise SystemExit(2)" if limit else "raise SystemExit(1)")
    code, err = _run(monkeypatch, tmp_path, node, limit, capsys)
    assert code == Exit.NODE_FAILED, err
    assert "restarting" not in err, err


def test_a_simulator_crash_is_respawned_too(monkeypatch: pytest.MonkeyPatch, tmp_path: Path,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    """The simulator dying (not its normal exit 0) is a death like any other."""
    marker = tmp_path / "sim_started"
    sim = _node(f"import pathlib, time\n"
                f"m = pathlib.Path({str(marker)!r})\n"
                f"if not m.exists():\n"
                f"    m.write_text('x'); raise SystemExit(1)\n"
                f"time.sleep(2.0)\n")
    monkeypatch.setattr(launcher, "build_commands", lambda a, ids, out, plans="", finished="": [
        ("line_simulator", sim), ("ats_regulator", _node("import time; time.sleep(30)"))])
    a = launcher._parser().parse_args(["--out", str(tmp_path), "--timeout", "60"])
    code = launcher._run_processes(a, ["train_01"], tmp_path)
    err = capsys.readouterr().err
    assert code == 0, err
    assert "line_simulator exited with 1" in err and "(1 of 3)" in err, err


def test_the_other_nodes_stop_when_the_simulator_finished(
        monkeypatch: pytest.MonkeyPatch, tmp_path: Path,
        capsys: pytest.CaptureFixture[str]) -> None:
    """Once the simulator created its ``finished_file`` the other nodes get SIGTERM while it
    still runs (writing its outputs); their ends then are no failure and no respawn."""
    stopped = tmp_path / "ats_stopped"
    seen = tmp_path / "seen_by_sim"
    ats = _node(f"import pathlib, signal, sys, time\n"
                f"def bye(*_):\n"
                f"    pathlib.Path({str(stopped)!r}).write_text('x'); sys.exit(0)\n"
                f"signal.signal(signal.SIGTERM, bye)\n"
                f"time.sleep(30)\n")

    def commands(a: Any, ids: Any, out: Any, plans: str = "",
                 finished: str = "") -> list[tuple[str, list[str]]]:
        assert finished, "run passes the simulator a finished_file"
        sim = _node(f"import pathlib, time\n"
                    f"time.sleep(1.0)\n"
                    f"pathlib.Path({finished!r}).touch()\n"
                    f"t0 = time.monotonic()\n"
                    f"while time.monotonic() - t0 < 5.0 and not pathlib.Path("
                    f"{str(stopped)!r}).exists():\n"
                    f"    time.sleep(0.02)\n"
                    f"pathlib.Path({str(seen)!r}).write_text(str(pathlib.Path("
                    f"{str(stopped)!r}).exists()))\n")
        return [("line_simulator", sim), ("ats_regulator", ats)]

    monkeypatch.setattr(launcher, "build_commands", commands)
    a = launcher._parser().parse_args(["--out", str(tmp_path), "--timeout", "60"])
    code = launcher._run_processes(a, ["train_01"], tmp_path)
    err = capsys.readouterr().err
    assert code == 0, err
    assert seen.read_text() == "True", "the ATS was stopped while the simulator still ran"
    assert "restarting" not in err, err


@pytest.mark.parametrize("text, expected", [
    ('{"loop_wall_s": 10.5, "loop_sim_s": 1800.0}', {"loop_wall_s": 10.5, "loop_sim_s": 1800.0}),
    ("", {}), ("[1, 2]", {}), ('{"loop_wall_s": 0.0, "loop_sim_s": 1800.0}', {}),
    ('{"loop_wall_s": "x", "loop_sim_s": 1}', {}), ('{"loop_wall_s": NaN, "loop_sim_s": 1}', {}),
    ('{"loop_wall_s": 1.0}', {}), ('{"loop_wall_s": 1.0, "loop_sim_s": -5}', {})])
def test_read_finished_takes_only_the_simulators_figures(tmp_path: Path, text: str,
                                                         expected: dict[str, float]) -> None:
    """The finished file's loop figures, or nothing (no loop real-time factor reported)."""
    f = tmp_path / "line_simulator.finished"
    f.write_text(text)
    assert launcher.read_finished(f) == expected
    assert launcher.read_finished(tmp_path / "missing") == {}
