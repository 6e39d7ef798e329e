"""A private network of "hosts" on this machine: Linux network namespaces and a bridge.

Used by the multi-host test and ``bench hosts`` (ROS-free; needs root or CAP_NET_ADMIN and
iproute2).  :class:`Lab` makes N host namespaces, each with one veth interface
``eth0`` addressed ``10.213.S.K/24`` (K = 1..N), whose peers are ports of a bridge in a
separate hub namespace: the default namespace gets no interface, route or address, and a
host namespace has no route but its /24, so no packet can leave the lab.  IPv6 is off in
every namespace of the lab (no router solicitations).  :func:`sniff` records every frame
that crosses the bridge (an ``AF_PACKET`` socket in the hub namespace), for the proof
that the lab's traffic stayed inside it.
"""

from __future__ import annotations

import ipaddress
import json
import os
import shutil
import socket
import struct
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

SUBNET_PREFIX = "10.213"
"""The lab's addresses: ``10.213.S.0/24`` (S chosen per lab)."""
IP_TIMEOUT_S = 20.0
"""Wall-clock limit of one ``ip`` command [s]."""


def _ip(*args: str, ns: str | None = None) -> None:
    """Run ``ip ARGS`` (in namespace ``ns``); OSError with its message when it fails."""
    _run((["ip", "-n", ns] if ns else ["ip"]) + list(args))


def _run(cmd: list[str]) -> None:
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=IP_TIMEOUT_S,
                       stdin=subprocess.DEVNULL)
    if r.returncode != 0:
        raise OSError(f"{' '.join(cmd)}: {r.stderr.strip() or r.returncode}")


def unavailable() -> str | None:
    """Why namespaces cannot be made here (one line), or None when they can."""
    if shutil.which("ip") is None:
        return "no iproute2 'ip' command"
    if os.geteuid() != 0:
        return "network namespaces need root (CAP_NET_ADMIN)"
    probe = f"ma_probe_{os.getpid()}"
    try:
        _ip("netns", "add", probe)
    except (OSError, subprocess.SubprocessError) as exc:
        return f"cannot create a network namespace: {exc}"
    try:
        _ip("netns", "del", probe)
    except (OSError, subprocess.SubprocessError):
        pass
    return None


@dataclass
class Lab:
    """N host namespaces on one bridge (see the module docstring); a context manager."""

    hosts: int
    subnet: int
    tag: str = field(default_factory=lambda: f"{os.getpid() % 100000}")
    made: list[str] = field(default_factory=list)

    @property
    def hub(self) -> str:
        """The hub namespace (the bridge ``br0`` and the hosts' veth peers)."""
        return f"ma{self.tag}s{self.subnet}hub"

    def ns(self, k: int) -> str:
        """Host ``k``'s namespace (1-based)."""
        return f"ma{self.tag}s{self.subnet}h{k}"

    def address(self, k: int) -> str:
        """The address of host ``k`` (1-based)."""
        return f"{SUBNET_PREFIX}.{self.subnet}.{k}"

    @property
    def network(self) -> ipaddress.IPv4Network:
        """The lab's /24."""
        return ipaddress.IPv4Network(f"{SUBNET_PREFIX}.{self.subnet}.0/24")

    def __enter__(self) -> "Lab":
        """Create the namespaces, the bridge and the veth pairs (removed on any error)."""
        if not 1 <= self.subnet <= 254 or not 1 <= self.hosts <= 250:
            raise ValueError("subnet in 1..254, hosts in 1..250")
        try:
            self._make()
        except BaseException:
            self.close()
            raise
        return self

    def _make(self) -> None:
        for name in [self.hub] + [self.ns(k) for k in range(1, self.hosts + 1)]:
            _ip("netns", "add", name)
            self.made.append(name)
            if shutil.which("sysctl"):
                _run(["ip", "netns", "exec", name, "sysctl", "-q", "-w",
                      "net.ipv6.conf.all.disable_ipv6=1"])
            _ip("link", "set", "lo", "up", ns=name)
        _ip("link", "add", "br0", "type", "bridge", ns=self.hub)
        _ip("link", "set", "br0", "up", ns=self.hub)
        for k in range(1, self.hosts + 1):
            # the pair is born in the host namespace: nothing of it in the default one
            _ip("link", "add", "eth0", "type", "veth", "peer", "name", f"p{k}",
                ns=self.ns(k))
            _ip("link", "set", f"p{k}", "netns", self.hub, ns=self.ns(k))
            _ip("link", "set", f"p{k}", "master", "br0", ns=self.hub)
            _ip("link", "set", f"p{k}", "up", ns=self.hub)
            _ip("addr", "add", f"{self.address(k)}/24", "dev", "eth0", ns=self.ns(k))
            _ip("link", "set", "eth0", "up", ns=self.ns(k))

    def close(self) -> None:
        """Remove every namespace of the lab (its interfaces go with it)."""
        for name in reversed(self.made):
            try:
                _ip("netns", "del", name)
            except (OSError, subprocess.SubprocessError):
                pass
        self.made.clear()

    def __exit__(self, *exc: Any) -> None:
        """Remove the lab."""
        self.close()

    def exec_argv(self, k: int, argv: Sequence[str]) -> list[str]:
        """``argv`` run inside host ``k``'s namespace."""
        return ["ip", "netns", "exec", self.ns(k), *argv]

    def counters(self, k: int) -> dict[str, int]:
        """Host ``k``'s ``eth0`` statistics (rx/tx bytes and packets)."""
        out = subprocess.run(["ip", "netns", "exec", self.ns(k), "ip", "-j", "-s", "link",
                              "show", "eth0"], capture_output=True, text=True,
                             timeout=IP_TIMEOUT_S, check=True).stdout
        st = json.loads(out)[0]["stats64"]
        return {"rx_bytes": int(st["rx"]["bytes"]), "rx_packets": int(st["rx"]["packets"]),
                "tx_bytes": int(st["tx"]["bytes"]), "tx_packets": int(st["tx"]["packets"])}


ETH_P_ALL = 0x0003
SOL_PACKET, PACKET_STATISTICS = 263, 6
"""Linux ``<linux/if_packet.h>``: a packet socket's counters (received, dropped)."""


def sniff(out: Path, seconds: float = 900.0) -> None:
    """Tally the frames the lab's hosts send, until SIGTERM or ``seconds``; JSON into ``out``.

    Run in the hub namespace: every frame a host sends arrives on its bridge port ``pK``
    and is counted there once (frames the bridge sends out of a port, and the bridge
    device's own copies, are left out).  The tally: ``frames`` and ``bytes`` per key
    (``ipv4 SRC DST`` or ``ether 0xTYPE``), and the kernel's count of ``dropped`` frames.
    Written on exit (atomically); ``out`` + ``.ready`` is created once the socket listens.
    """
    import signal
    stop = [False]
    signal.signal(signal.SIGTERM, lambda *_: stop.__setitem__(0, True))
    s = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.htons(ETH_P_ALL))
    s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 16 << 20)
    s.settimeout(0.2)
    tally: dict[str, list[int]] = {}
    Path(str(out) + ".ready").write_text("")
    t_end = time.monotonic() + seconds
    while not stop[0] and time.monotonic() < t_end:
        try:
            frame, meta = s.recvfrom(65535)
        except (socket.timeout, InterruptedError):
            continue
        if meta[2] == socket.PACKET_OUTGOING or not str(meta[0]).startswith("p"):
            continue
        etype = struct.unpack("!H", frame[12:14])[0] if len(frame) >= 14 else 0
        if etype == 0x0800 and len(frame) >= 34:
            key = f"ipv4 {socket.inet_ntoa(frame[26:30])} {socket.inet_ntoa(frame[30:34])}"
        else:
            key = f"ether 0x{etype:04x}"
        n = tally.setdefault(key, [0, 0])
        n[0] += 1
        n[1] += len(frame)
    packets, dropped = struct.unpack("II", s.getsockopt(SOL_PACKET, PACKET_STATISTICS, 8))
    tmp = Path(str(out) + ".tmp")
    tmp.write_text(json.dumps({"dropped": dropped, "tally": {
        k: {"frames": v[0], "bytes": v[1]} for k, v in sorted(tally.items())}}, indent=1))
    os.replace(tmp, out)


if __name__ == "__main__":
    if len(sys.argv) == 3 and sys.argv[1] == "sniff":
        sniff(Path(sys.argv[2]))
        sys.exit(0)
    print("usage: python -m metro_atc.netns sniff OUT.json", file=sys.stderr)
    sys.exit(2)
