"""The fork server of ``python -m metro_atc run`` (:mod:`metro_atc.zygote`).

That a graph whose nodes the zygote forked gives the run of exec'd nodes (events, KPIs,
journals, logs) is asserted on the session's shared runs (``test_graph``: run 0 forked,
run 1 exec'd).  Here: the fork-safety refusals, the fast exit of a forked node, and a real
node executable forked, re-parented to the caller, in its own session, stopped by SIGTERM.
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

from metro_atc import launcher
from metro_atc.process_watch import PARENT_PID_ENV


def _py(code: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120)


def test_fork_safety_refuses_a_thread_and_an_rclpy_context() -> None:
    """No fork with a second Python thread running or an initialised rclpy context."""
    r = _py("import threading, json\n"
            "from metro_atc.zygote import fork_safety\n"
            "import rclpy\n"
            "out = [fork_safety()]\n"
            "ev = threading.Event(); t = threading.Thread(target=ev.wait); t.start()\n"
            "out.append(fork_safety()); ev.set(); t.join()\n"
            "rclpy.init(); out.append(fork_safety()); rclpy.shutdown()\n"
            "print(json.dumps(out))")
    assert r.returncode == 0, r.stderr
    alone, thread, context = json.loads(r.stdout.strip().splitlines()[-1])
    assert alone is None
    assert thread is not None and "2 Python threads" in thread
    assert context is not None and "rclpy context" in context


def test_exit_process_flushes_files_and_waits_for_other_threads(tmp_path: Path) -> None:
    """The fast exit keeps what was written (unflushed buffers, atexit handlers) and the
    exit code; with a non-daemon thread running it leaves the exit to the interpreter."""
    out = tmp_path / "journal.txt"
    mark = tmp_path / "atexit.txt"
    r = _py(f"import atexit, pathlib\n"
            f"from metro_atc.zygote import exit_process\n"
            f"fh = open({str(out)!r}, 'w', buffering=1 << 20)\n"
            f"fh.write('last line\\n')\n"
            f"atexit.register(lambda: pathlib.Path({str(mark)!r}).write_text('ran'))\n"
            f"exit_process(7)\n"
            f"print('not reached')\n")
    assert r.returncode == 7, r.stderr
    assert "not reached" not in r.stdout
    assert out.read_text() == "last line\n" and mark.read_text() == "ran"
    r = _py("import threading, time\n"
            "from metro_atc.zygote import exit_process\n"
            "t = threading.Thread(target=time.sleep, args=(0.5,)); t.start()\n"
            "print('returned', exit_process(5))\n")
    assert r.returncode == 0 and "returned 5" in r.stdout, r.stderr


def _ppid(pid: int) -> int:
    with open(f"/proc/{pid}/status") as fh:
        return int(next(ln for ln in fh if ln.startswith("PPid:")).split()[1])


def test_a_forked_node_runs_the_installed_executable(installed: Path, ros_env: dict[str, str],
                                                     tmp_path: Path) -> None:
    """The zygote forks ``ats_regulator`` from its installed entry point: a child of this
    process (re-parented), in its own session, logging to its log, ending on SIGTERM with
    exit 0 and its shutdown line; a bad request is refused and the zygote serves on."""
    env = dict(ros_env, **{PARENT_PID_ENV: str(os.getpid())})
    argv = [str(installed / "ats_regulator"), "--ros-args", "-p", "scenario:=mini",
            "-p", "diagnostics_period_s:=0.2"]
    assert launcher.forkable(argv)
    assert not launcher.forkable([sys.executable, "-c", "pass"])
    from metro_atc.zygote import Client

    z = Client(["ats_regulator"], env)
    try:
        assert z.ready(), z.error
        assert Path(z.info["package"]).is_relative_to(installed.parent.parent), z.info
        assert z.info["modules"] == ["metro_atc.nodes.ats_regulator"]
        for bad in ({"argv": "not a list", "log": "x", "parent": 1}, [1, 2], "x"):
            assert "bad request" in str((z.send(bad) or {}).get("error")), bad
        log = tmp_path / "ats.log"
        p = z.spawn(argv, str(log))
        assert p is not None, z.error
        assert log.exists()  # before the answer, as an exec'd node's log (a race under load)
        try:
            assert _ppid(p.pid) == os.getpid()
            assert os.getsid(p.pid) == p.pid
            end = time.monotonic() + 60.0
            while "regulator 'none'" not in log.read_text() and time.monotonic() < end:
                assert p.poll() is None, log.read_text()
                time.sleep(0.1)
            assert "regulator 'none' on 'mini'" in log.read_text()
        finally:
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGTERM)
        assert p.wait(timeout=60.0) == 0, log.read_text()
    finally:
        z.close()
    assert z.proc is None


@pytest.mark.parametrize("value, expect", [("0", False), ("1", True)])
def test_zygote_switch(monkeypatch: pytest.MonkeyPatch, value: str, expect: bool) -> None:
    """``METRO_ATC_ZYGOTE=0`` execs every node (no fork server started)."""
    started: list[list[str]] = []

    class Fake:
        def __init__(self, names: list[str], env: dict[str, str]) -> None:
            started.append(names)

    monkeypatch.setenv(launcher.ZYGOTE_ENV, value)
    monkeypatch.setattr(launcher, "Zygote", Fake)
    z = launcher.start_zygote(["line_simulator"])
    assert (z is not None) == expect and len(started) == int(expect)


@pytest.mark.parametrize("warm", [True, False])
def test_caller_lookup_is_warmed_for_the_children(warm: bool) -> None:
    """After :func:`zygote.warm_caller_lookup` a caller lookup (rclpy's first log call in a
    forked node) resolves no module path again; without it, one per loaded module."""
    code = (
        "import inspect, os.path, sys\n"
        "import numpy, metro_atc.zygote as z\n"
        f"if {warm}: z.warm_caller_lookup()\n"
        "n = [0]\n"
        "real = os.path.realpath\n"
        "def counted(*a, **k):\n"
        "    n[0] += 1\n"
        "    return real(*a, **k)\n"
        "os.path.realpath = counted\n"
        "inspect.getframeinfo(sys._getframe())\n"
        "print(n[0], len(sys.modules))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.split()
    lookups, modules = int(out[0]), int(out[1])
    if warm:
        assert lookups <= 2, lookups
    else:
        assert lookups >= modules // 2, (lookups, modules)
