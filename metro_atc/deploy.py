"""One run split over several hosts: ``run --only PARTS`` and ``run --dds-hosts FILE``.

Each host runs its share of the graph (:func:`share`): ``simulator``, ``ats``, ``brake``,
``recorder``, ``ato`` (every ATO process) or ``ato:K/N`` (the K-th of N shares of the
trains, dealt round-robin as :func:`metro_atc.launcher.ato_groups` deals them to processes:
share K hosts trains K, K + N, K + 2N, ... of the timetable; within a share the trains are
composed ``--ato-per-process`` to a process).  The lockstep makes the run independent of
where each node runs: ``events.csv`` and ``kpis.json`` are those of the one-host run.

DDS across hosts (``--dds-hosts FILE``, :func:`read_hosts`, :func:`profile_xml`): the
project's loopback profile (``config/fastdds_profile.xml``) with its addresses replaced:
UDP bound to this host's address of the list only (interface allowlist), unicast
discovery to every address of the list (initial peers; no multicast, no other interface),
shared memory between the processes of one host.  Without the option nothing changes
(loopback only).

A host that does not run the simulator runs a watcher in its place
(``python -m metro_atc.deploy watch``, :func:`watch_main`): it follows the simulator's
latched ``/line/status`` and ends this host's share when the simulator, having reported
the run's end, leaves the domain (exit 0; 5 when trains did not complete; 6 when
``--duration`` cut it), or gives up with exit 7 when no simulator appeared within
``--peer-timeout`` wall seconds, or with exit 3 when the simulator left the domain without
ending the run.  This module is ROS-free but for :func:`watch_main`.
"""

from __future__ import annotations

import argparse
import ipaddress
import os
import re
import socket
import sys
import tempfile
import time
import xml.etree.ElementTree as ET
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Callable, Sequence

from metro_atc.exit_codes import Exit

PARTS = {"line_simulator": "simulator", "ats_regulator": "ats",
         "brake_diagnostic": "brake", "bag_recorder": "recorder", "ato_controller": "ato"}
"""Executable of a process -> the ``--only`` name of its part."""
WATCH_LABEL = "simulator_watch"
"""Process label of the watcher a host without the simulator runs (``LOG_DIR/<label>.log``)."""
PEER_TIMEOUT_S = 60.0
"""Default ``--peer-timeout`` [s]: the simulator's own ``startup_timeout_s`` default."""
LEFT_GRACE_S = 15.0
"""Wall time [s] the simulator may be absent from the domain after it was seen before the
watcher ends the share with exit 3: longer than the profile's 10 s participant lease, so a
simulator killed and respawned on its host (its old endpoints linger until the lease ends)
is not taken for one that left."""
MAX_HOSTS = 64
"""Most addresses a peer list may name (each costs every participant unicast announcements
to 32 participant ports)."""
PORT_BASE, DOMAIN_GAIN, MAX_PARTICIPANTS = 7400, 250, 32
"""RTPS well-known port mapping (PB, DG) and the profile's ``maxInitialPeersRange``."""
NAME_RE = re.compile(r"[a-z][a-z0-9_-]{0,62}")
"""A host's optional name in the peer list."""


def add_options(p: argparse.ArgumentParser) -> None:
    """The ``run`` options of a split run (added to :func:`metro_atc.launcher._parser`)."""
    p.add_argument("--only", default="", metavar="PART[,PART]",
                   help="start only these parts of the graph (one host's share of a split "
                        "run): simulator, ats, brake, recorder, ato (every ATO process) or "
                        "ato:K/N (the K-th of N shares of the trains, round-robin); a host "
                        "without the simulator ends when the simulator reports the run's end")
    p.add_argument("--dds-hosts", default="", metavar="FILE",
                   help="DDS across hosts: FILE lists the hosts' addresses (one IPv4 address "
                        "a line, optionally followed by a name; '#' comments); DDS binds to "
                        "this host's address of the list only and discovers the others by "
                        "unicast (no multicast); default: loopback only")
    p.add_argument("--peer-timeout", type=float, default=PEER_TIMEOUT_S, metavar="S",
                   help="split run: wall time [s] to wait for the other hosts' parts before "
                        "giving up with exit 7 (the simulator's startup_timeout_s and "
                        "ato_absent_timeout_s; a host without the simulator waits as long "
                        f"for it; default {PEER_TIMEOUT_S:g})")


def split(a: argparse.Namespace) -> bool:
    """True for a split run (``--only`` or ``--dds-hosts`` given)."""
    return bool(getattr(a, "only", "") or getattr(a, "dds_hosts", ""))


@dataclass(frozen=True)
class Share:
    """The parts one host runs: whole parts and ATO shares ``(k, n)`` (1-based k)."""

    parts: frozenset[str]
    ato_shares: tuple[tuple[int, int], ...] = ()

    def runs(self, part: str) -> bool:
        """True if this host runs ``part`` (``ato`` also for a share of the trains)."""
        return part in self.parts or (part == "ato" and bool(self.ato_shares))


def parse_only(text: str) -> Share:
    """The ``--only`` value as a :class:`Share` (ValueError: one line naming the problem)."""
    parts: set[str] = set()
    shares: set[tuple[int, int]] = set()
    names = sorted(set(PARTS.values()))
    items = [x.strip() for x in text.split(",")]
    if not text.strip() or any(not x for x in items):
        raise ValueError(f"--only {text!r}: give comma-separated parts of {', '.join(names)} "
                         "or ato:K/N")
    for item in items:
        m = re.fullmatch(r"ato:([0-9]{1,4})/([0-9]{1,4})", item)
        if m:
            k, n = int(m[1]), int(m[2])
            if not 1 <= k <= n:
                raise ValueError(f"--only {item}: K must be in 1..N (the K-th of N shares)")
            shares.add((k, n))
        elif item in names:
            parts.add(item)
        else:
            raise ValueError(f"--only: unknown part {item!r} (parts: {', '.join(names)}, "
                             "ato:K/N)")
    if len({n for _, n in shares}) > 1:
        raise ValueError(f"--only {text}: ATO shares of different splits "
                         f"({', '.join(f'{k}/{n}' for k, n in sorted(shares))})")
    if shares and "ato" in parts:
        raise ValueError(f"--only {text}: 'ato' (every ATO) and an ato:K/N share together")
    return Share(frozenset(parts), tuple(sorted(shares)))


def share_of(a: argparse.Namespace) -> Share | None:
    """This host's share (None: the whole graph)."""
    return parse_only(a.only) if getattr(a, "only", "") else None


def share_trains(train_ids: Sequence[str], k: int, n: int) -> list[str]:
    """The trains of ATO share ``k`` of ``n`` (1-based): trains k, k + n, ... of the list."""
    return list(train_ids)[k - 1::n]


def check(a: argparse.Namespace, train_ids: Sequence[str]) -> str | None:
    """The split options against the scenario's trains; one error line or None."""
    if not split(a):
        return None
    try:
        sh = share_of(a)
    except ValueError as exc:
        return str(exc)
    if a.single_process:
        return "--only and --dds-hosts need the multi-process graph (not --single-process)"
    if not (0.1 <= a.peer_timeout <= 86400.0):
        return f"--peer-timeout {a.peer_timeout:g}: must be in 0.1 .. 86400 s"
    if sh is None:
        return None
    for k, n in sh.ato_shares:
        if n > len(train_ids):
            return f"--only ato:{k}/{n}: the scenario has {len(train_ids)} trains, fewer " \
                f"than {n} shares"
    if "recorder" in sh.parts and a.record is None:
        return "--only recorder: needs --record"
    return None


def share(a: argparse.Namespace, specs: Sequence[Any], train_ids: Sequence[str],
          groups: Callable[[Sequence[str], int], list[list[str]]]) -> list[Any]:
    """The process specs (:class:`metro_atc.launcher.ProcessSpec`) this host starts.

    ``specs`` is the whole graph.  The ATO processes of a share ``ato:K/N`` are made from
    the whole graph's first ATO process (same parameters, the share's trains composed
    ``--ato-per-process`` to a process by ``groups``, the launcher's ``ato_groups``).
    In a split run the simulator waits ``--peer-timeout`` for the graph
    (``startup_timeout_s``, ``ato_absent_timeout_s``).
    """
    sh = share_of(a)
    out: list[Any] = []
    for spec in specs:
        part = PARTS.get(spec.executable, spec.executable)
        if spec.executable == "line_simulator" and split(a):
            spec = replace(spec, params=dict(spec.params, startup_timeout_s=a.peer_timeout,
                                             ato_absent_timeout_s=a.peer_timeout))
        if sh is None or part in sh.parts:
            out.append(spec)
    if sh is not None and sh.ato_shares:
        template = next(s for s in specs if s.executable == "ato_controller")
        for k, n in sh.ato_shares:
            for group in groups(share_trains(train_ids, k, n), a.ato_per_process):
                out.append(replace(template, label=f"ato_{group[0]}",
                                   params=dict(template.params, train_ids=group)))
    return out


def watch_command(a: argparse.Namespace) -> list[str] | None:
    """The watcher's command line on a host without the simulator (None: it has one)."""
    sh = share_of(a)
    if sh is None or "simulator" in sh.parts:
        return None
    return [sys.executable, "-m", "metro_atc.deploy", "watch",
            "--timeout", repr(float(a.peer_timeout)), "--duration", repr(float(a.duration))]


# --------------------------------------------------------------------------- peer list

@dataclass(frozen=True)
class Hosts:
    """A peer list: every host's address (file order) and this host's own address."""

    addresses: tuple[str, ...]
    names: tuple[str, ...]
    own: str


def read_hosts(path: str) -> Hosts:
    """Read and check a peer list (ValueError: one line naming the file, line and problem).

    One host a line: an IPv4 unicast address, optionally followed by a name; blank lines
    and ``#`` comments are skipped.  Exactly one address must be this host's (a UDP socket
    binds to it); every other must have a route from here (a UDP ``connect`` succeeds:
    nothing is sent).
    """
    try:
        text = Path(path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ValueError(f"--dds-hosts {path}: cannot read it: "
                         f"{getattr(exc, 'strerror', None) or exc}") from None
    addresses: list[str] = []
    names: list[str] = []
    for n, raw in enumerate(text.splitlines(), 1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        where = f"--dds-hosts {path}:{n}"
        fields = line.split()
        if len(fields) > 2:
            raise ValueError(f"{where}: expected 'ADDRESS [NAME]', got {line!r}")
        try:
            ip = ipaddress.IPv4Address(fields[0])
        except ValueError:
            raise ValueError(f"{where}: {fields[0]!r} is not an IPv4 address") from None
        if ip.is_loopback or ip.is_multicast or ip.is_unspecified or ip.is_reserved or \
                ip.is_link_local or str(ip).endswith(".255"):
            raise ValueError(f"{where}: {ip} is not a host's unicast address")
        if str(ip) in addresses:
            raise ValueError(f"{where}: {ip} listed twice")
        name = fields[1] if len(fields) == 2 else f"host{len(addresses) + 1}"
        if not NAME_RE.fullmatch(name) or name in names:
            raise ValueError(f"{where}: host name {name!r} (lowercase letters, digits, _ "
                             "and -, starting with a letter; unique)")
        addresses.append(str(ip))
        names.append(name)
    if not addresses:
        raise ValueError(f"--dds-hosts {path}: no address in it")
    if len(addresses) > MAX_HOSTS:
        raise ValueError(f"--dds-hosts {path}: {len(addresses)} addresses, at most "
                         f"{MAX_HOSTS}")
    own = [x for x in addresses if is_local(x)]
    if len(own) != 1:
        raise ValueError(f"--dds-hosts {path}: {len(own)} of its addresses are this "
                         f"host's ({', '.join(own) or 'none'}); exactly one must be")
    for x in addresses:
        if x != own[0]:
            problem = route_problem(x)
            if problem:
                raise ValueError(f"--dds-hosts {path}: {x} unreachable from {own[0]}: "
                                 f"{problem}")
    return Hosts(tuple(addresses), tuple(names), own[0])


def is_local(address: str) -> bool:
    """True if ``address`` is one of this host's (network namespace's) addresses."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.bind((address, 0))
        except OSError:
            return False
    return True


def route_problem(address: str) -> str | None:
    """Why this host cannot send to ``address`` (no route, network down), or None.

    A UDP ``connect`` asks the kernel for a route and sends nothing.
    """
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.connect((address, PORT_BASE))
        except OSError as exc:
            return os.strerror(exc.errno) if exc.errno else str(exc)
    return None


def check_domain(env: dict[str, str] | os._Environ[str]) -> str | None:
    """The domain id's DDS ports must fit in 16 bits (RTPS port mapping); error or None."""
    raw = env.get("ROS_DOMAIN_ID", "0") or "0"
    try:
        domain = int(raw)
    except ValueError:
        return f"ROS_DOMAIN_ID={raw!r}: not an integer"
    top = PORT_BASE + DOMAIN_GAIN * domain + 11 + 2 * (MAX_PARTICIPANTS - 1)
    if not 0 <= domain or top > 65535:
        return f"ROS_DOMAIN_ID={domain}: its DDS ports (up to {top}) exceed 65535; use 0..232"
    return None


def dds_ports(domain: int) -> tuple[int, int]:
    """The UDP port range [first, last] a domain's participants use (RTPS mapping)."""
    base = PORT_BASE + DOMAIN_GAIN * domain
    return base, base + 11 + 2 * (MAX_PARTICIPANTS - 1)


def profile_xml(hosts: Hosts, loopback_profile: Path) -> str:
    """The Fast DDS profile of a split run, made from the project's loopback profile.

    The same transports (shared memory, one UDPv4 transport with an interface allowlist)
    and discovery timing; the allowlist and the unicast locators are this host's address
    instead of 127.0.0.1, the initial peers every address of the list.
    """
    ns = "http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles"
    ET.register_namespace("", ns)
    root = ET.parse(loopback_profile).getroot()
    q = "{%s}" % ns
    for allow in root.iter(q + "interfaceWhiteList"):
        for a in allow.findall(q + "address"):
            a.text = hosts.own
    for tag in ("defaultUnicastLocatorList", "metatrafficUnicastLocatorList"):
        for lst in root.iter(q + tag):
            for a in lst.iter(q + "address"):
                a.text = hosts.own
    peers = list(root.iter(q + "initialPeersList"))
    if len(peers) != 1:
        raise ValueError(f"{loopback_profile}: expected one initialPeersList")
    lst = peers[0]
    for child in list(lst):
        lst.remove(child)
    for addr in hosts.addresses:
        loc = ET.SubElement(lst, q + "locator")
        ET.SubElement(ET.SubElement(loc, q + "udpv4"), q + "address").text = addr
    body = ET.tostring(root, encoding="unicode")
    return ("<?xml version=\"1.0\" encoding=\"UTF-8\" ?>\n<!-- metro_atc split run: DDS "
            f"on {hosts.own} only, unicast discovery of {', '.join(hosts.addresses)} "
            "(made from config/fastdds_profile.xml by metro_atc.deploy) -->\n" + body + "\n")


def configure(a: argparse.Namespace) -> tuple[str | None, Path | None]:
    """Apply ``--dds-hosts`` to this process's environment: (error line, profile written).

    Runs before the DDS defaults and before any node (or the fork server) starts; the
    profile file is removed by the caller at the end of the run.  Also checks the
    ``--only`` syntax, so a bad value is refused before anything starts.
    """
    try:
        share_of(a)
    except ValueError as exc:
        return str(exc), None
    if not getattr(a, "dds_hosts", ""):
        return None, None
    from metro_atc.dds import config_dir
    problem = check_domain(os.environ)
    if problem:
        return problem, None
    try:
        hosts = read_hosts(a.dds_hosts)
    except ValueError as exc:
        return str(exc), None
    if os.environ.get("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp") != "rmw_fastrtps_cpp":
        return f"--dds-hosts needs Fast DDS (RMW_IMPLEMENTATION is " \
            f"{os.environ['RMW_IMPLEMENTATION']})", None
    fd, name = tempfile.mkstemp(prefix="metro_atc_dds_hosts_", suffix=".xml")
    with os.fdopen(fd, "w", encoding="utf-8") as fh:
        fh.write(profile_xml(hosts, config_dir() / "fastdds_profile.xml"))
    os.environ["FASTRTPS_DEFAULT_PROFILES_FILE"] = name
    # as with the loopback profile: LOCALHOST/SUBNET would add the rmw's own UDP transport
    # on every interface
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "SYSTEM_DEFAULT"
    os.environ.pop("ROS_STATIC_PEERS", None)
    first, last = dds_ports(int(os.environ.get("ROS_DOMAIN_ID", "0") or "0"))
    print(f"metro_atc run: DDS on {hosts.own} only, peers {', '.join(hosts.addresses)} "
          f"(UDP ports {first}-{last})", file=sys.stderr, flush=True)
    return None, Path(name)


# --------------------------------------------------------------------------- watcher

def watch_verdict(finished: bool, completed: int, trains: int, sim_time_s: float,
                  duration_s: float) -> tuple[Exit, str]:
    """A host's exit code from the simulator's last ``/line/status``, and one line."""
    said = f"the simulator ended the run at t={sim_time_s:.1f} s with {completed} of " \
        f"{trains} trains completed"
    if finished and completed >= trains:
        return Exit.OK, said
    if duration_s > 0 and sim_time_s >= duration_s - 1e-9:
        return Exit.CUT, said + f" (cut by --duration {duration_s:g})"
    return Exit.SERVICE_INCOMPLETE, said


def watch_main(argv: Sequence[str] | None = None) -> int:
    """``python -m metro_atc.deploy watch``: follow the simulator of another host.

    Exit 0 / 5 / 6 when the simulator, having reported the end of the run
    (:func:`watch_verdict`), left the domain (after writing its outputs: until then it may
    wait for this host's brake diagnosis to acknowledge its last samples), 7 when no
    simulator appeared within ``--timeout`` wall seconds, 3 when it left the domain for
    :data:`LEFT_GRACE_S` without reporting the end; one line on stderr.
    """
    p = argparse.ArgumentParser(prog="python -m metro_atc.deploy watch")
    p.add_argument("--timeout", type=float, default=PEER_TIMEOUT_S)
    p.add_argument("--duration", type=float, default=0.0)
    a = p.parse_args(argv)
    import signal

    import rclpy
    from metro_atc_msgs.msg import LineStatus
    from metro_atc.nodes.common import QOS_LATCHED
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))
    rclpy.init(signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    node = rclpy.create_node(f"simulator_watch_{os.getpid()}")
    last: list[Any] = []
    node.create_subscription(LineStatus, "/line/status", last.append, QOS_LATCHED)
    say = node.get_logger()
    t0 = time.monotonic()
    seen_at: float | None = None
    verdict: tuple[Exit, str] | None = None
    absent_since: float | None = None
    try:
        while True:
            rclpy.spin_once(node, timeout_sec=0.2)
            now = time.monotonic()
            if verdict is None and last and last[-1].finished:
                m = last[-1]
                verdict = watch_verdict(True, m.completed_trains, m.trains, m.sim_time_s,
                                        a.duration)
                say.info("the simulator reported the end of the run; waiting for it to "
                         "leave (its last sensor samples still need this host)")
            present = node.count_publishers("/line/status") > 0
            if verdict is not None and not present:
                # the simulator wrote its outputs and left: this host's part is done
                print(f"simulator_watch: exit {int(verdict[0])}: {verdict[1]}",
                      file=sys.stderr, flush=True)
                os._exit(int(verdict[0]))  # no DDS teardown to wait for
            if present:
                if seen_at is None:
                    seen_at = now
                    say.info(f"simulator found after {now - t0:.2f} s")
                absent_since = None
            elif seen_at is None and now - t0 > a.timeout:
                print(f"simulator_watch: error: no simulator on ROS_DOMAIN_ID="
                      f"{os.environ.get('ROS_DOMAIN_ID', '0')} within {a.timeout:g} s "
                      "(check the peer list, the other hosts and that one of them runs "
                      "--only simulator)", file=sys.stderr, flush=True)
                os._exit(int(Exit.GRAPH_NOT_READY))
            elif seen_at is not None:
                absent_since = now if absent_since is None else absent_since
                if now - absent_since > LEFT_GRACE_S:
                    print(f"simulator_watch: error: the simulator left the domain "
                          f"{LEFT_GRACE_S:g} s ago without reporting the end of the run",
                          file=sys.stderr, flush=True)
                    os._exit(int(Exit.NODE_FAILED))
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


def share_end(a: argparse.Namespace, code: int, log_dir: Path) -> int:
    """The end of a host without the simulator: the watcher's verdict (exit code, line).

    ``code`` is the launcher's (0 when the watcher reported the run's end: its own exit
    code, 0, 5 or 6, is in its log line ``simulator_watch: exit N: ...``).
    """
    if code != 0:
        return code
    try:
        text = (log_dir / f"{WATCH_LABEL}.log").read_text(errors="replace")
    except OSError:
        text = ""
    m = None
    for m in re.finditer(r"^simulator_watch: exit ([0-9]+): (.*)$", text, re.M):
        pass
    if m is None:
        print(f"metro_atc run: error: --only {a.only}: no verdict of the simulator's end in "
              f"{log_dir / (WATCH_LABEL + '.log')}", file=sys.stderr)
        return int(Exit.NODE_FAILED)
    print(f"metro_atc run: --only {a.only}: {m[2]}", file=sys.stderr)
    return int(m[1])


def profile_main(argv: Sequence[str] | None = None) -> int:
    """``python -m metro_atc.deploy profile FILE``: this host's Fast DDS profile on stdout.

    For ROS tools beside a split run (``ros2 topic echo`` on one of the hosts): save it and
    export ``FASTRTPS_DEFAULT_PROFILES_FILE`` to it with ``ROS_AUTOMATIC_DISCOVERY_RANGE=
    SYSTEM_DEFAULT``.  Exit 2 with one line for a bad peer list.
    """
    p = argparse.ArgumentParser(prog="python -m metro_atc.deploy profile")
    p.add_argument("hosts_file", metavar="FILE")
    a = p.parse_args(argv)
    from metro_atc.dds import config_dir
    try:
        hosts = read_hosts(a.hosts_file)
    except ValueError as exc:
        print(f"metro_atc.deploy: error: {exc}", file=sys.stderr)
        return int(Exit.REFUSED)
    sys.stdout.write(profile_xml(hosts, config_dir() / "fastdds_profile.xml"))
    return 0


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "watch":
        sys.exit(watch_main(sys.argv[2:]))
    if len(sys.argv) > 1 and sys.argv[1] == "profile":
        sys.exit(profile_main(sys.argv[2:]))
    print("usage: python -m metro_atc.deploy {watch [--timeout S] [--duration S], "
          "profile FILE}", file=sys.stderr)
    sys.exit(int(Exit.REFUSED))
