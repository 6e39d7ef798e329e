"""The graph split over three "hosts": network namespaces on a private bridge, DDS between them.

:class:`metro_atc.netns.Lab` makes three host namespaces (``10.213.D.1-3/24``, D = the
test's DDS domain) whose only link is a bridge in a fourth namespace: host 1 runs
``--only simulator,ats``, host 2 ``--only ato:1/2,brake``, host 3 ``--only ato:2/2``, each
with ``--dds-hosts`` naming the three addresses.  The split run of the mini scenario must
write the ``events.csv`` of the one-host run byte for byte and its ``kpis.json`` field for
field (the session's clean run, ``conftest.mini_graph_runs``, with the same options);
so must a split run whose host-3 ATO process is killed mid-run (SIGKILL) and respawned
by that host's launcher.  A capture on the bridge ports shows that every frame stayed
between the lab's addresses and that it saw every frame the hosts sent (their ``eth0``
counters): the default namespace has no interface, address or route of the lab.
Bad input: a simulator whose ATO hosts never appear, an ATO host whose simulator never
appears, two simulators on one domain on two hosts, a peer list that is malformed or
names an address without a route: one line and a non-zero exit within the stated time.
Skipped (one line) where network namespaces cannot be made (not root, no CAP_NET_ADMIN).
"""

from __future__ import annotations

import contextlib
import ipaddress
import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Iterator

import pytest

from graph_runs import STEP_TIMEOUT_S
from harness import DomainAllocator
from metro_atc import netns

pytestmark = pytest.mark.integration

WHY = netns.unavailable()
if WHY is not None:
    pytest.skip(f"multi-host test skipped: {WHY}", allow_module_level=True)

SCENARIO = "mini"
TWO_SIMS_SCENARIO = "taipei_blue"
"""Two graphs on one domain: a run long enough (3 600 simulated s, ~15 s of wall time on a
quiet machine) for the second graph to start while the first steps (its arguments come
after :func:`_start`'s: argparse takes the last)."""
SHARES = ("simulator,ats", "ato:1/2,brake", "ato:2/2")
"""``--only`` of hosts 1, 2, 3."""
RUN_TIMEOUT_S = 300.0
"""Wall-clock limit of a split run [s] (~12 s on a quiet 2-core machine)."""
KILL_AT_S = 300.0
"""Simulated time [s] at which host 3's ATO process (train_02, in service 170-600 s) is
killed: read from its state journal, which has a line per step."""
PEER_TIMEOUT_S = 3.0
"""``--peer-timeout`` of the bad-input runs [s]."""
START_ALLOWANCE_S = 60.0
"""Wall time [s] allowed for a launcher's start-up (Python imports, the fork server, the
scenario) on top of the bound a bad-input run states (``--peer-timeout`` and
``--step-timeout``)."""


def _peers(path: Path, lab: netns.Lab, hosts: tuple[int, ...]) -> Path:
    path.write_text("# metro_atc peer list\n" + "".join(
        f"{lab.address(k)} host{k}\n" for k in hosts))
    return path


def _start(lab: netns.Lab, k: int, dom: int, out: Path, *args: str) -> subprocess.Popen[str]:
    """``python -m metro_atc run`` of the mini scenario on host ``k`` into ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    argv = lab.exec_argv(k, [sys.executable, "-m", "metro_atc", "run", "--scenario",
                             SCENARIO, "--json", "--no-plots", "--out", str(out),
                             "--ato-per-process", "1", "--progress", "never", *args])
    return subprocess.Popen(argv, env=dict(os.environ, ROS_DOMAIN_ID=str(dom)),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            cwd=out, stdin=subprocess.DEVNULL)


def _finish(p: subprocess.Popen[str], timeout: float = RUN_TIMEOUT_S) -> dict[str, Any]:
    try:
        stdout, stderr = p.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        tree = subprocess.run(["ps", "-e", "-o", "pid,ppid,stat,etimes,args"],
                              capture_output=True, text=True).stdout
        p.send_signal(signal.SIGTERM)
        stdout, stderr = p.communicate(timeout=60)
        pytest.fail(f"run did not end in {timeout:g} s: {p.args}\n{stderr[-3000:]}\n"
                    f"processes then:\n{tree[-6000:]}")
    return {"code": p.returncode, "stdout": stdout, "stderr": stderr}


def _journal_t(path: Path) -> float:
    """Simulated time of the last line of an ATO state journal [s] (-1: none yet)."""
    try:
        with path.open("rb") as fh:
            fh.seek(max(0, path.stat().st_size - 4096))
            lines = [ln for ln in fh.read().splitlines() if ln.strip()]
        return float(json.loads(lines[-1])["t_s"]) if lines else -1.0
    except (OSError, ValueError, KeyError, IndexError):
        return -1.0


def _split_run(lab: netns.Lab, dom: int, tmp: Path, kill: bool) -> dict[str, Any]:
    tmp.mkdir(parents=True)
    peers = _peers(tmp / "peers.txt", lab, (1, 2, 3))
    procs = [_start(lab, k, dom, tmp / f"host{k}", "--only", only, "--dds-hosts", str(peers),
                    "--step-timeout", str(STEP_TIMEOUT_S))
             for k, only in enumerate(SHARES, 1)]
    killed_at = None
    if kill:
        journal = tmp / "host3" / "checkpoints" / "ato_train_02.jsonl"
        deadline = time.monotonic() + RUN_TIMEOUT_S
        while killed_at is None and time.monotonic() < deadline and procs[0].poll() is None:
            t = _journal_t(journal)
            if t >= KILL_AT_S:
                pids = json.loads((tmp / "host3" / "logs" / "pids.json").read_text())
                os.kill(int(pids["ato_train_02"]), signal.SIGKILL)
                killed_at = t
            time.sleep(0.01)
    res = [_finish(p) for p in procs]
    return {"hosts": res, "killed_at": killed_at, "out": tmp / "host1",
            "stderr": [r["stderr"] for r in res]}


@pytest.fixture(scope="module")
def lab_runs(installed: Path, tmp_path_factory: pytest.TempPathFactory
             ) -> Iterator[dict[str, Any]]:
    """The lab, and its two split runs (plain, host 3's ATO killed) with a capture."""
    tmp = tmp_path_factory.mktemp("multihost")
    domains = DomainAllocator()
    with domains.allocate() as d1, domains.allocate() as d2, netns.Lab(3, d1) as lab:
        cap = tmp / "capture.json"
        sniffer = subprocess.Popen(["ip", "netns", "exec", lab.hub, sys.executable, "-m",
                                    "metro_atc.netns", "sniff", str(cap)],
                                   stdin=subprocess.DEVNULL)
        try:
            ready = Path(str(cap) + ".ready")
            t0 = time.monotonic()
            while not ready.exists() and time.monotonic() - t0 < 60 and sniffer.poll() is None:
                time.sleep(0.05)
            assert ready.exists(), "the capture did not start"
            before = [lab.counters(k) for k in (1, 2, 3)]
            t0 = time.monotonic()
            plain = _split_run(lab, d1, tmp / "plain", kill=False)
            plain_wall = time.monotonic() - t0
            killed = _split_run(lab, d2, tmp / "killed", kill=True)
        finally:
            sniffer.send_signal(signal.SIGTERM)
            sniffer.wait(timeout=60)
        after = [lab.counters(k) for k in (1, 2, 3)]
        yield {"lab": lab, "plain": plain, "killed": killed, "plain_wall_s": plain_wall,
               "capture": json.loads(cap.read_text()),
               "tx_frames": sum(a["tx_packets"] - b["tx_packets"]
                                for a, b in zip(after, before)),
               "root_addrs": subprocess.run(["ip", "-4", "-o", "addr"], capture_output=True,
                                            text=True, check=True).stdout,
               "routes": [subprocess.run(lab.exec_argv(k, ["ip", "-4", "route"]),
                                         capture_output=True, text=True,
                                         check=True).stdout for k in (1, 2, 3)],
               "tmp": tmp}


def _comparable(kpis: dict[str, Any]) -> dict[str, Any]:
    """KPIs without wall-clock fields."""
    return {k: v for k, v in kpis.items() if "wall" not in k and "real_time" not in k}


def _reference(mini_graph_runs: dict[str, Any]) -> tuple[str, dict[str, Any]]:
    out = Path(mini_graph_runs["out"][1])
    return (out / "events.csv").read_text(), json.loads((out / "kpis.json").read_text())


@pytest.mark.parametrize("name", ["plain", "killed"])
def test_split_run_equals_the_one_host_run(lab_runs: dict[str, Any],
                                           mini_graph_runs: dict[str, Any],
                                           name: str) -> None:
    """Every host exits 0; events.csv byte for byte, kpis.json field for field."""
    run = lab_runs[name]
    for k, res in enumerate(run["hosts"], 1):
        assert res["code"] == 0, f"host {k}: {res['stderr'][-3000:]}"
    events, kpis = _reference(mini_graph_runs)
    assert (run["out"] / "events.csv").read_text() == events
    assert _comparable(json.loads((run["out"] / "kpis.json").read_text())) == \
        _comparable(kpis)
    # the brake diagnosis on host 2 acknowledged the last samples (its host did not stop it
    # before the simulator was done with it)
    assert "did not acknowledge" not in (run["out"] / "logs" / "line_simulator.log").read_text()
    # the hosts without the simulator say how the run ended
    for res in run["hosts"][1:]:
        assert "the simulator ended the run at t=" in res["stderr"]
        assert "with 2 of 2 trains completed" in res["stderr"]


def test_killed_ato_host_was_respawned_mid_run(lab_runs: dict[str, Any]) -> None:
    """Host 3's launcher restarted its killed ATO process; the kill hit the running graph."""
    run = lab_runs["killed"]
    assert run["killed_at"] is not None and run["killed_at"] >= KILL_AT_S, \
        f"no kill: {run['stderr'][2][-2000:]}"
    assert "ato_train_02 exited with -9 (killed by SIGKILL); restarting it" in \
        run["stderr"][2]
    log = (run["out"].parent / "host3" / "logs" / "ato_train_02.log").read_text()
    assert "journal" in log.lower()


def test_each_host_ran_its_share_only(lab_runs: dict[str, Any]) -> None:
    """Host 1 ran the simulator and the ATS, host 2 train_01's ATO and the brake
    diagnosis, host 3 train_02's ATO, each beside its watcher where no simulator ran."""
    tmp = lab_runs["plain"]["out"].parent
    logs = {k: sorted(p.stem for p in (tmp / f"host{k}" / "logs").glob("*.log"))
            for k in (1, 2, 3)}
    assert logs == {1: ["ats_regulator", "line_simulator"],
                    2: ["ato_train_01", "brake_diagnostic", "simulator_watch"],
                    3: ["ato_train_02", "simulator_watch"]}


def test_no_packet_left_the_lab(lab_runs: dict[str, Any]) -> None:
    """The capture on the bridge ports: every frame is ARP or IPv4 between two lab
    addresses, and it saw every frame the hosts sent (no drop); the data crossed the bridge
    (a run's fleet states, commands and sensor samples: megabytes, not discovery alone);
    no lab address or route outside the lab's namespaces."""
    lab: netns.Lab = lab_runs["lab"]
    cap = lab_runs["capture"]
    assert cap["dropped"] == 0
    frames, ip_bytes = 0, {}
    for key, n in cap["tally"].items():
        frames += n["frames"]
        kind, *rest = key.split()
        if kind == "ether":
            assert rest == ["0x0806"], f"a frame that is neither ARP nor IPv4: {key}"
            continue
        src, dst = (ipaddress.IPv4Address(x) for x in rest)
        assert src in lab.network and dst in lab.network, f"left the lab: {key}"
        ip_bytes[(str(src), str(dst))] = n["bytes"]
    assert frames == lab_runs["tx_frames"]
    for k in (2, 3):
        to_host = ip_bytes.get((lab.address(1), lab.address(k)), 0)
        from_host = ip_bytes.get((lab.address(k), lab.address(1)), 0)
        assert to_host > 1_000_000 and from_host > 100_000, ip_bytes
    assert f"{netns.SUBNET_PREFIX}.{lab.subnet}." not in lab_runs["root_addrs"]
    for routes in lab_runs["routes"]:
        assert routes.strip().splitlines() == [
            ln for ln in routes.strip().splitlines() if ln.startswith(str(lab.network))]


def test_split_run_is_short(lab_runs: dict[str, Any]) -> None:
    """The three hosts' run of the mini scenario took under 90 s of wall time."""
    assert lab_runs["plain_wall_s"] < 90.0


# --------------------------------------------------------------------------- bad input

@contextlib.contextmanager
def _bad_lab() -> Iterator[tuple[netns.Lab, list[int]]]:
    domains = DomainAllocator()
    with domains.allocate() as a, domains.allocate() as b, domains.allocate() as c, \
            domains.allocate() as d, netns.Lab(3, a) as lab:
        yield lab, [a, b, c, d]


@pytest.fixture(scope="module")
def bad_runs(installed: Path, tmp_path_factory: pytest.TempPathFactory
             ) -> dict[str, Any]:
    """The bad-input runs, side by side (each case on its own DDS domain)."""
    tmp = tmp_path_factory.mktemp("multihost_bad")
    with _bad_lab() as (lab, doms):
        peers12 = _peers(tmp / "peers12.txt", lab, (1, 2))
        peers13 = _peers(tmp / "peers13.txt", lab, (1, 3))
        (tmp / "malformed.txt").write_text(f"{lab.address(1)}\n10.213.300.2 east\n")
        (tmp / "noroute.txt").write_text(f"{lab.address(1)}\n192.0.2.1\n")
        (tmp / "notmine.txt").write_text(f"{lab.address(2)}\n{lab.address(3)}\n")
        t = ["--peer-timeout", str(PEER_TIMEOUT_S), "--step-timeout", str(PEER_TIMEOUT_S)]
        two_sims = ["--dds-hosts", str(peers13), "--peer-timeout", "30", "--step-timeout",
                    "30", "--scenario", TWO_SIMS_SCENARIO, "--duration", "3600",
                    "--ato-per-process", "15"]
        starts = {
            "no_ato_host": _start(lab, 1, doms[0], tmp / "a1", "--only", "simulator,ats,brake",
                                  "--dds-hosts", str(peers12), *t),
            "no_sim_host": _start(lab, 2, doms[1], tmp / "b2", "--only", "ato",
                                  "--dds-hosts", str(peers12), *t),
            # the duplicate is found at discovery; 30 s so that a loaded machine's slow
            # start-up is not taken for absent ATOs first (exit 7 instead of the refusal).
            # The second graph starts once the first is stepping, and the first runs long
            # enough to be on the domain with it: two mini runs of ~5 s each, started
            # together, once ran one after the other on a loaded machine (both exit 0,
            # rightly: they never shared the domain)
            "two_sims_1": _start(lab, 1, doms[2], tmp / "c1", *two_sims),
        }
        # the simulator killed mid-run, not restarted (its host's run fails): the ATO host
        # gives up once it is gone
        peers23 = _peers(tmp / "peers23.txt", lab, (2, 3))
        starts["sim_left_2"] = _start(lab, 2, doms[3], tmp / "d2", "--only",
                                      "simulator,ats,brake", "--respawn-limit", "0",
                                      "--dds-hosts", str(peers23))
        starts["sim_left_3"] = _start(lab, 3, doms[3], tmp / "d3", "--only", "ato",
                                      "--dds-hosts", str(peers23))
        for name in ("malformed", "noroute", "notmine"):
            starts[name] = _start(lab, 1, doms[0], tmp / name, "--dds-hosts",
                                  str(tmp / f"{name}.txt"))
        t0 = time.monotonic()
        ends: dict[str, float] = {}
        sim_log = tmp / "d2" / "logs" / "line_simulator.log"
        killed_at = math.nan
        c1_log = tmp / "c1" / "logs" / "line_simulator.log"
        while (len(ends) < len(starts) or "two_sims_3" not in starts) \
                and time.monotonic() - t0 < RUN_TIMEOUT_S:
            if "two_sims_3" not in starts and (
                    "two_sims_1" in ends or (c1_log.is_file() and "graph ready" in
                                             c1_log.read_text(errors="replace"))):
                starts["two_sims_3"] = _start(lab, 3, doms[2], tmp / "c3", *two_sims)
            if math.isnan(killed_at) and sim_log.is_file() and \
                    "graph ready" in sim_log.read_text(errors="replace"):
                pids = json.loads((tmp / "d2" / "logs" / "pids.json").read_text())
                os.kill(int(pids["line_simulator"]), signal.SIGKILL)
                killed_at = time.monotonic()
            for name, p in starts.items():
                if name not in ends and p.poll() is not None:
                    ends[name] = time.monotonic() - t0
            time.sleep(0.05)
        res = {}
        for name, p in starts.items():
            res[name] = dict(_finish(p, timeout=60.0), wall_s=ends.get(name, math.inf),
                             out=tmp / name, end=t0 + ends.get(name, math.inf))
        res["sim_left_3"]["after_kill_s"] = res["sim_left_3"]["end"] - killed_at
        return res


def _one_error(stderr: str) -> str:
    errs = [ln for ln in stderr.splitlines() if "error:" in ln]
    assert errs, stderr[-2000:]
    return errs[0]


def test_simulator_gives_up_on_absent_ato_host(bad_runs: dict[str, Any]) -> None:
    """No ATO host: exit 7 (GRAPH_NOT_READY) within --peer-timeout + the first step's
    --step-timeout (+ start-up), naming the missing ATO endpoints."""
    r = bad_runs["no_ato_host"]
    assert r["code"] == 7, r["stderr"][-2000:]
    assert "no ATO answered" in _one_error(r["stderr"])
    assert r["wall_s"] < 2 * PEER_TIMEOUT_S + START_ALLOWANCE_S


def test_ato_host_gives_up_on_absent_simulator(bad_runs: dict[str, Any]) -> None:
    """No simulator host (its address is in the list, nothing answers there): exit 7 within
    --peer-timeout (+ start-up), one line saying so."""
    r = bad_runs["no_sim_host"]
    assert r["code"] == 7, r["stderr"][-2000:]
    assert "no simulator on ROS_DOMAIN_ID" in _one_error(r["stderr"])
    assert r["wall_s"] < PEER_TIMEOUT_S + START_ALLOWANCE_S


def test_two_simulators_on_one_domain_refused(bad_runs: dict[str, Any]) -> None:
    """Two whole graphs on one domain, on two hosts: both simulators refuse (another
    line_simulator on the domain), both runs exit non-zero."""
    for name in ("two_sims_1", "two_sims_3"):
        r = bad_runs[name]
        assert r["code"] not in (0, 5, 6), r["stderr"][-2000:]
        # either refusal: it saw the other publish the fleet state, or saw the other's
        # refusal first (sim_domain.check_alone / check_not_refused)
        assert "a second graph on this domain" in r["stderr"], r["stderr"][-2000:]


def test_ato_host_gives_up_when_the_simulator_leaves(bad_runs: dict[str, Any]) -> None:
    """The simulator killed mid-run and not restarted: its host's run fails (3), and the ATO
    host ends with 3 and one line once the simulator is gone (its participant's 10 s lease,
    then deploy.LEFT_GRACE_S), not at its --timeout."""
    from metro_atc.deploy import LEFT_GRACE_S
    assert bad_runs["sim_left_2"]["code"] == 3, bad_runs["sim_left_2"]["stderr"][-2000:]
    r = bad_runs["sim_left_3"]
    assert r["code"] == 3, r["stderr"][-2000:]
    assert "the simulator left the domain" in _one_error(r["stderr"])
    assert r["after_kill_s"] < 10.0 + LEFT_GRACE_S + START_ALLOWANCE_S


@pytest.mark.parametrize("name,words", [
    ("malformed", "malformed.txt:2: '10.213.300.2' is not an IPv4 address"),
    ("noroute", "192.0.2.1 unreachable from"),
    ("notmine", "0 of its addresses are this host's"),
])
def test_bad_peer_list_refused(bad_runs: dict[str, Any], name: str, words: str) -> None:
    """A malformed peer list, an address without a route, a list without this host: exit 2
    before any node starts, one line naming the file and the problem."""
    r = bad_runs[name]
    assert r["code"] == 2, r["stderr"][-2000:]
    line = _one_error(r["stderr"])
    assert words in line and "--dds-hosts" in line
    assert not (r["out"] / "logs").exists()  # no node started
    assert r["wall_s"] < START_ALLOWANCE_S
