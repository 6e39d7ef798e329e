"""Node processes do not outlive a killed launcher (:mod:`metro_atc.process_watch`).

A launcher killed with SIGKILL cannot stop its children; they are re-parented and, before
this watch, spun on for ever on the test's or the user's DDS domain. First with stand-in
processes (ROS-free, a few seconds), then with the real graph of ``python -m metro_atc run``.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from metro_atc import process_watch

ROOT = Path(__file__).resolve().parent.parent


def _alive(pid: int) -> bool:
    """True while ``pid`` runs (a zombie counts as gone)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"


def _wait_gone(pids: list[int], timeout_s: float) -> list[int]:
    """Poll until every pid is gone or the timeout; return the ones still alive."""
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        left = [p for p in pids if _alive(p)]
        if not left:
            return []
        time.sleep(0.1)
    return [p for p in pids if _alive(p)]


CHILD = """
import os, signal, sys, time, pathlib
from metro_atc import process_watch
process_watch.ORPHAN_GRACE_S = {grace}
out = pathlib.Path(sys.argv[1])
stop = []
signal.signal(signal.SIGTERM, {handler})
assert process_watch.watch_parent()
out.write_text("running")
while not stop:
    time.sleep(0.05)
out.write_text("stopped cleanly")
"""

PARENT = """
import os, subprocess, sys, time
env = dict(os.environ, METRO_ATC_PARENT_PID=str(os.getpid()))
child = subprocess.Popen([sys.executable, "-c", sys.argv[1], sys.argv[2]], env=env,
                         start_new_session=True)
print(child.pid, flush=True)
time.sleep(60)
"""


def _orphan(tmp_path: Path, handler: str, grace: float) -> tuple[int, Path]:
    """Start parent -> child, wait until the child watches, SIGKILL the parent."""
    out = tmp_path / "child_state"
    child_src = CHILD.format(grace=grace, handler=handler)
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    parent = subprocess.Popen([sys.executable, "-c", PARENT, child_src, str(out)],
                              stdout=subprocess.PIPE, env=env)
    assert parent.stdout is not None
    child = int(parent.stdout.readline())
    end = time.monotonic() + 30.0
    while not out.exists() and time.monotonic() < end:
        time.sleep(0.05)
    assert out.exists(), "the child did not start"
    parent.kill()
    parent.wait()
    return child, out


def test_an_orphan_stops_cleanly(tmp_path: Path) -> None:
    """SIGKILL the parent: the child gets SIGTERM within a second and ends its loop."""
    child, out = _orphan(tmp_path, "lambda *_: stop.append(1)", 30.0)
    assert _wait_gone([child], 10.0) == []
    assert out.read_text() == "stopped cleanly"


def test_an_orphan_that_ignores_sigterm_exits_hard(tmp_path: Path) -> None:
    """A child whose loop never ends (SIGTERM ignored) still exits after the grace time."""
    child, out = _orphan(tmp_path, "signal.SIG_IGN", 1.0)
    assert _wait_gone([child], 10.0) == []
    assert out.read_text() == "running"


@pytest.mark.parametrize("raw", ["", "abc", "1", "0", "-5"])
def test_no_watch_without_a_launcher_pid(raw: str) -> None:
    """Started by hand or by ``ros2 launch`` (no or an implausible pid): not watched."""
    assert not process_watch.watch_parent({process_watch.PARENT_PID_ENV: raw})


def test_parent_gone() -> None:
    """The check compares the current parent with the expected one."""
    assert not process_watch.parent_gone(os.getppid())
    assert process_watch.parent_gone(os.getppid() + 1)


@pytest.mark.parametrize("kill_after_s", [1.0])
def test_graph_nodes_stop_when_the_launcher_is_killed(installed: Path, ros_env: dict[str, str],
                                                      tmp_path: Path,
                                                      kill_after_s: float) -> None:
    """``run`` SIGKILLed while its nodes start: every node process is gone within 30 s."""
    out = tmp_path / "out"
    launcher = subprocess.Popen([sys.executable, "-m", "metro_atc", "run", "--scenario", "mini",
                                 "--out", str(out)], env=ros_env, cwd=str(ROOT),
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    pids_file = out / "logs" / "pids.json"
    end = time.monotonic() + 60.0
    while not pids_file.exists() and time.monotonic() < end and launcher.poll() is None:
        time.sleep(0.05)
    assert pids_file.exists(), "the launcher did not start the graph"
    time.sleep(kill_after_s)
    pids = [int(p) for p in json.loads(pids_file.read_text()).values()]
    launcher.send_signal(signal.SIGKILL)
    launcher.wait()
    left = _wait_gone(pids, 30.0)
    for p in left:  # do not leave them to the next test
        os.kill(p, signal.SIGKILL)
    assert left == [], f"node processes still running after the launcher died: {left}"
