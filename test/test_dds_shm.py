"""Killed nodes leave no Fast DDS shared memory behind (``metro_atc.dds.clean_killed_shm``).

A Fast DDS participant maps ``/dev/shm/fastrtps_<id>`` (lock file ``<id>_el``, held while
it lives); SIGKILL leaves both.  Two participants in child processes, one killed: after
the clean its files are gone, the live one's are untouched, and a second clean finds
nothing more of it.  ``run`` cleans when one of its nodes died by SIGKILL.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from metro_atc.dds import clean_killed_shm

pytestmark = pytest.mark.integration

_CHILD = """
import sys, rclpy
rclpy.init()
node = rclpy.create_node("shm_probe")
pub = node.create_publisher(__import__("std_msgs.msg", fromlist=["String"]).String, "/x", 1)
print("up", flush=True)
sys.stdin.read()  # until the test closes it: then a clean end
node.destroy_node()
rclpy.shutdown()
"""


def _segments(pid: int) -> set[Path]:
    """The Fast DDS segment files process ``pid`` maps."""
    maps = Path(f"/proc/{pid}/maps").read_text()
    return {Path(m) for m in re.findall(r"(/dev/shm/fastrtps_[0-9a-f]{16})\b", maps)}


def _start(env: dict[str, str]) -> subprocess.Popen[str]:
    p = subprocess.Popen([sys.executable, "-c", _CHILD], env=env, stdin=subprocess.PIPE,
                         stdout=subprocess.PIPE, text=True)
    assert p.stdout is not None and p.stdout.readline().strip() == "up"
    return p


@pytest.mark.skipif(not Path("/dev/shm").is_dir(), reason="no /dev/shm")
def test_clean_removes_a_killed_participants_segment_only(ros_env: dict[str, str]) -> None:
    live, dead = _start(ros_env), _start(ros_env)
    try:
        deadline = time.monotonic() + 20.0
        while not (_segments(live.pid) and _segments(dead.pid)):
            assert time.monotonic() < deadline, "no Fast DDS segment mapped (no SHM transport?)"
            time.sleep(0.1)
        keep, gone = _segments(live.pid), _segments(dead.pid)
        dead.send_signal(signal.SIGKILL)
        dead.wait(timeout=10)
        assert all(f.exists() and Path(f"{f}_el").exists() for f in gone)
        cleaned = clean_killed_shm()
        assert cleaned is not None and cleaned >= len(gone)
        assert not any(f.exists() or Path(f"{f}_el").exists() for f in gone)
        assert all(f.exists() and Path(f"{f}_el").exists() for f in keep)
        assert live.poll() is None
    finally:
        for p in (live, dead):
            if p.poll() is None:
                assert p.stdin is not None
                p.stdin.close()
            p.wait(timeout=20)
    assert live.returncode == 0
    assert not any(f.exists() for f in keep)  # a clean end removes its own


def test_no_tool_no_clean(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    """Without ``fastdds`` next to the interpreter or on PATH: None, nothing run."""
    monkeypatch.setenv("PATH", str(tmp_path))
    monkeypatch.setattr(sys, "executable", str(tmp_path / "python"))
    assert clean_killed_shm() is None
    assert os.environ["PATH"] == str(tmp_path)
