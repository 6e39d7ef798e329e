"""DDS stays on loopback by default: no UDP socket off 127.0.0.1.

A node started the way users start it (``source env.sh``, nothing else set) is inspected
through ``/proc``: every UDP socket it owns is bound to 127.0.0.1 (``ss -uanp`` shows the
same; /proc needs no extra tool).  The multi-host switch is checked to open it.
"""

from __future__ import annotations

import os
import subprocess
import time
from pathlib import Path

import pytest

from harness import ROOT

pytestmark = pytest.mark.integration


def _udp_sockets(pid: int) -> list[str]:
    """Local ``address:port`` of every UDP socket owned by ``pid`` (from /proc)."""
    inodes = set()
    fd_dir = Path(f"/proc/{pid}/fd")
    for fd in fd_dir.iterdir():
        try:
            target = os.readlink(fd)
        except OSError:
            continue
        if target.startswith("socket:["):
            inodes.add(target[8:-1])
    out = []
    for table in ("/proc/net/udp", "/proc/net/udp6"):
        try:
            lines = Path(table).read_text().splitlines()[1:]
        except OSError:
            continue
        for ln in lines:
            f = ln.split()
            if f[9] not in inodes:
                continue
            addr, port = f[1].split(":")
            if len(addr) == 8:  # IPv4, little-endian hex
                ip = ".".join(str(int(addr[i:i + 2], 16)) for i in (6, 4, 2, 0))
            else:
                ip = "ipv6:" + addr
            out.append(f"{ip}:{int(port, 16)}")
    return out


def _node_sockets(env_setup: str, ros_domain: int, tmp_path: Path) -> list[str]:
    """Start line_simulator from a shell that ran ``env_setup``; return its UDP sockets."""
    clean = {k: v for k, v in os.environ.items()
             if k not in ("FASTRTPS_DEFAULT_PROFILES_FILE", "ROS_AUTOMATIC_DISCOVERY_RANGE",
                          "METRO_ATC_DDS")}
    clean["ROS_DOMAIN_ID"] = str(ros_domain)
    cmd = (f"{env_setup} && source {ROOT}/env.sh && exec {ROOT}/install/metro_atc/lib/"
           "metro_atc/line_simulator --ros-args -p scenario:=mini -p startup_timeout_s:=60.0")
    log = open(tmp_path / "sim.log", "wb")
    p = subprocess.Popen(["bash", "-c", cmd], env=clean, stdout=log, stderr=subprocess.STDOUT,
                         start_new_session=True)
    try:
        deadline = time.monotonic() + 30.0
        socks: list[str] = []
        while time.monotonic() < deadline:
            time.sleep(0.5)
            assert p.poll() is None, (tmp_path / "sim.log").read_text()
            if "scenario 'mini'" in (tmp_path / "sim.log").read_text():
                time.sleep(1.0)  # discovery and data sockets are open by now
                socks = _udp_sockets(p.pid)
                break
        return socks
    finally:
        p.terminate()
        p.wait(timeout=10)
        log.close()


def test_default_binds_loopback_only(installed: Path, ros_domain: int, tmp_path: Path) -> None:
    """``source env.sh``: every DDS socket of a node is on 127.0.0.1."""
    socks = _node_sockets("true", ros_domain, tmp_path)
    assert socks, "no UDP socket found: the node did not start DDS?"
    off = [s for s in socks if not s.startswith("127.0.0.1:")]
    assert not off, f"DDS sockets off loopback: {off} (all: {socks})"


def test_multihost_switch_opens(installed: Path, ros_domain: int, tmp_path: Path) -> None:
    """``METRO_ATC_DDS=multihost``: the node listens beyond loopback (the switch works)."""
    socks = _node_sockets("export METRO_ATC_DDS=multihost", ros_domain, tmp_path)
    assert any(not s.startswith("127.0.0.1:") for s in socks), socks
