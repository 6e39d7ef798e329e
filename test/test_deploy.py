"""A split run's options (ROS-free): ``--only`` shares, the peer list and its DDS profile."""

from __future__ import annotations

import argparse
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from metro_atc import deploy
from metro_atc.dds import config_dir
from metro_atc.exit_codes import Exit
from metro_atc.launcher import ProcessSpec, ato_groups, parse_args

NS = "{http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles}"
TRAINS = [f"train_{k:02d}" for k in range(1, 8)]


def _specs(a: argparse.Namespace) -> list[ProcessSpec]:
    from metro_atc.launcher import processes_for
    return processes_for(a, TRAINS, Path("/nonexistent"))


@pytest.mark.parametrize("text,parts,shares", [
    ("simulator,ats", {"simulator", "ats"}, ()),
    ("ato:2/3", set(), ((2, 3),)),
    ("ato:1/3, ato:3/3,brake", {"brake"}, ((1, 3), (3, 3))),
    ("ato,recorder", {"ato", "recorder"}, ()),
])
def test_only_parsed(text: str, parts: set[str], shares: tuple[tuple[int, int], ...]) -> None:
    """Parts and ATO shares as written."""
    sh = deploy.parse_only(text)
    assert sh.parts == frozenset(parts) and sh.ato_shares == shares


@pytest.mark.parametrize("text,words", [
    ("", "give comma-separated parts"),
    ("simulator,", "give comma-separated parts"),
    ("sim", "unknown part 'sim'"),
    ("ato:0/3", "K must be in 1..N"),
    ("ato:4/3", "K must be in 1..N"),
    ("ato:1/2,ato:1/3", "different splits"),
    ("ato,ato:1/2", "together"),
    ("ato:1/x", "unknown part"),
])
def test_only_refused(text: str, words: str) -> None:
    """One line naming the problem."""
    with pytest.raises(ValueError, match=words):
        deploy.parse_only(text)


def test_shares_deal_the_trains_round_robin_and_cover_them_once() -> None:
    """Shares 1..N of N hold every train once; share K of N is ato_groups' K-th process."""
    for n in (1, 2, 3, 7):
        got = [t for k in range(1, n + 1) for t in deploy.share_trains(TRAINS, k, n)]
        assert sorted(got) == TRAINS
        assert [deploy.share_trains(TRAINS, k, n) for k in range(1, n + 1)] == \
            ato_groups(TRAINS, -(-len(TRAINS) // n))


def test_share_keeps_the_chosen_parts_with_the_whole_graph_parameters() -> None:
    """``--only simulator,ato:2/3``: the simulator (waiting --peer-timeout for the graph)
    and the ATO processes of trains 2 and 5 (2 per process), as the whole graph has them."""
    a = parse_args(["--scenario", "mini", "--only", "simulator,ato:2/3",
                    "--ato-per-process", "1", "--peer-timeout", "7"])
    whole = _specs(a)
    got = deploy.share(a, whole, TRAINS, ato_groups)
    assert [s.label for s in got] == ["line_simulator", "ato_train_02", "ato_train_05"]
    assert got[0].params["startup_timeout_s"] == 7.0
    assert got[0].params["ato_absent_timeout_s"] == 7.0
    ato = next(s for s in whole if s.executable == "ato_controller")
    assert got[1].params == dict(ato.params, train_ids=["train_02"])
    assert deploy.watch_command(a) is None
    b = parse_args(["--scenario", "mini", "--only", "ato:2/3,brake", "--ato-per-process", "2"])
    assert [s.label for s in deploy.share(b, _specs(b), TRAINS, ato_groups)] == \
        ["brake_diagnostic", "ato_train_02"]
    watch = deploy.watch_command(b)
    assert watch is not None and watch[2:4] == ["metro_atc.deploy", "watch"]


def test_whole_graph_unchanged_without_the_options() -> None:
    """No --only, no --dds-hosts: the process list is the whole graph's, untouched."""
    a = parse_args(["--scenario", "mini"])
    assert not deploy.split(a)
    assert deploy.share(a, _specs(a), TRAINS, ato_groups) == _specs(a)


@pytest.mark.parametrize("argv,words", [
    (["--only", "ato:1/9"], "fewer than 9 shares"),
    (["--only", "recorder"], "needs --record"),
    (["--only", "ats", "--single-process"], "multi-process"),
    (["--only", "ats", "--peer-timeout", "0"], "--peer-timeout 0"),
])
def test_split_options_checked_against_the_scenario(argv: list[str], words: str) -> None:
    """One line before any node starts."""
    a = parse_args(["--scenario", "mini", *argv])
    problem = deploy.check(a, TRAINS)
    assert problem is not None and words in problem


def test_profile_is_the_loopback_profile_on_this_hosts_address() -> None:
    """The UDP transport and the unicast locators on the own address, the initial peers
    every address; nothing on loopback, every other element as in the loopback profile."""
    hosts = deploy.Hosts(("10.213.7.1", "10.213.7.2", "10.213.7.3"), ("a", "b", "c"),
                         "10.213.7.2")
    src = config_dir() / "fastdds_profile.xml"
    root = ET.fromstring(deploy.profile_xml(hosts, src).split("-->", 1)[1])
    assert "127.0.0.1" not in ET.tostring(root, encoding="unicode")
    allow = [a.text for a in root.iter(NS + "interfaceWhiteList") for a in a]
    assert allow == ["10.213.7.2"]
    for tag in ("defaultUnicastLocatorList", "metatrafficUnicastLocatorList"):
        assert [a.text for x in root.iter(NS + tag) for a in x.iter(NS + "address")] == \
            ["10.213.7.2"]
    peers = [a.text for x in root.iter(NS + "initialPeersList") for a in x.iter(NS + "address")]
    assert peers == list(hosts.addresses)
    orig = ET.parse(src).getroot()
    assert [e.tag for e in orig.iter() if "ddress" not in e.tag and e.tag != NS + "locator"
            and e.tag != NS + "udpv4"] == \
        [e.tag for e in root.iter() if "ddress" not in e.tag and e.tag != NS + "locator"
         and e.tag != NS + "udpv4"]
    assert not any(e.tag.endswith("multicastLocatorList") for e in root.iter())


@pytest.mark.parametrize("text,words", [
    ("", "no address in it"),
    ("# only a comment\n\n", "no address in it"),
    ("10.213.1.1 a b\n", ":1: expected 'ADDRESS [NAME]'"),
    ("\n10.213.1.300\n", ":2: '10.213.1.300' is not an IPv4 address"),
    ("host.example\n", "is not an IPv4 address"),
    ("127.0.0.1\n", "not a host's unicast address"),
    ("239.255.0.1\n", "not a host's unicast address"),
    ("0.0.0.0\n", "not a host's unicast address"),
    ("10.213.1.1\n10.213.1.1\n", "listed twice"),
    ("10.213.1.1 Central\n", "host name 'Central'"),
    ("10.213.1.1 a\n10.213.1.2 a\n", "host name 'a'"),
    ("192.0.2.10\n", "0 of its addresses are this host's"),
])
def test_peer_list_refused(tmp_path: Path, text: str, words: str) -> None:
    """A malformed peer list: one line naming the file (and line) and the problem."""
    f = tmp_path / "peers.txt"
    f.write_text(text)
    with pytest.raises(ValueError, match=r"--dds-hosts .*peers\.txt") as exc:
        deploy.read_hosts(str(f))
    assert words in str(exc.value)


def test_peer_list_unreadable(tmp_path: Path) -> None:
    """A missing or binary file: one line."""
    with pytest.raises(ValueError, match="cannot read it"):
        deploy.read_hosts(str(tmp_path / "none.txt"))
    (tmp_path / "bin.txt").write_bytes(b"\xff\xfe\x00")
    with pytest.raises(ValueError, match="cannot read it"):
        deploy.read_hosts(str(tmp_path / "bin.txt"))


@pytest.mark.parametrize("domain,ok", [("0", True), ("232", True), ("233", False),
                                       ("-1", False), ("x", False)])
def test_domain_ports_fit(domain: str, ok: bool) -> None:
    """Domains whose RTPS ports pass 65535 are refused (Fast DDS takes 0..232)."""
    assert (deploy.check_domain({"ROS_DOMAIN_ID": domain}) is None) == ok


@pytest.mark.parametrize("finished,completed,t,duration,code", [
    (True, 2, 623.0, 0.0, Exit.OK),
    (True, 1, 1200.0, 0.0, Exit.SERVICE_INCOMPLETE),
    (True, 1, 300.0, 300.0, Exit.CUT),
])
def test_watcher_verdict(finished: bool, completed: int, t: float, duration: float,
                         code: Exit) -> None:
    """A host without the simulator ends with the run's own outcome."""
    got, line = deploy.watch_verdict(finished, completed, 2, t, duration)
    assert got == code and f"{completed} of 2 trains completed" in line


def test_profile_command_prints_the_hosts_profile(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    """``python -m metro_atc.deploy profile FILE``: the profile of this host's address; a
    bad list: exit 2 and one line."""
    f = tmp_path / "peers.txt"
    f.write_text("10.213.7.1 a\n10.213.7.2 b\n")
    monkeypatch.setattr(deploy, "is_local", lambda x: x == "10.213.7.2")
    monkeypatch.setattr(deploy, "route_problem", lambda x: None)
    assert deploy.profile_main([str(f)]) == 0
    out = capsys.readouterr().out
    assert "DDS on 10.213.7.2 only" in out and "<address>10.213.7.1</address>" in out
    monkeypatch.setattr(deploy, "route_problem", lambda x: "Network is unreachable")
    assert deploy.profile_main([str(f)]) == Exit.REFUSED
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "10.213.7.1 unreachable from 10.213.7.2" in err[0]


def test_wire_sizes_are_the_codecs_bytes() -> None:
    """``bench hosts``' payload table: linear in the trains, equal to a message's bytes."""
    from metro_atc.bench.hosts import wire_sizes
    from metro_atc.nodes.wire import fleet_command
    from metro_atc.nodes.wire import fleet_state
    few, many = wire_sizes(30), wire_sizes(300)
    pad = 8 * len(fleet_state.ARRAYS)  # each array's alignment: < 8 B
    assert abs(many["fleet_state"] - few["fleet_state"]
               - 270 * few["fleet_state_per_train"]) < pad
    assert many["fleet_command"] == len(fleet_command.encode(
        (1, 0), "line", 1, [f"train_{k:02d}" for k in range(1, 301)], [0.5] * 300, [1] * 300))
    assert few["fleet_state_per_train"] > 8 * 8  # at least its eight float64 fields


def test_bench_hosts_refuses_bad_options(capsys: pytest.CaptureFixture[str]) -> None:
    """One line and exit 2 before any namespace is made."""
    from metro_atc.bench.hosts import main
    assert main(["--hosts", "4"]) == 2
    assert main(["--pairs", "0"]) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 2
