"""A restarted brake_diagnostic node replays its sample journals to the same state.

In process (no graph): the recorded ``mini_pad_fault`` batches of ``test/brake_replay.py``
fed to a :class:`~metro_atc.nodes.brake_diagnostic.BrakeDiagnostic` with a checkpoint
directory; a second node started on that directory (the restart) holds every train's watch
exactly as the first left it (counters, observer state, judged estimates: the summary of
``brake_replay.train_summary``), also with hostile samples mixed in, and (on the stream as
recorded) after both took the rest of it.  Journals written one JSON sample per line (main
before the packed lines) are read the same.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any, Iterator

import pytest

rclpy = pytest.importorskip("rclpy")

sys.path.insert(0, str(Path(__file__).parent))

import brake_replay as br  # noqa: E402

BATCHES = Path(__file__).parent / "data" / "brake_batches_mini_pad_fault.npz"
CHANNELS = ("wheel_angular_speed_radps", "clamp_force_n", "longitudinal_acceleration_mps2",
            "reference_speed_mps", "car_mass_kg")


@pytest.fixture
def make_node(ros_domain: int) -> Iterator[Any]:
    """``make_node(checkpoint_dir)``: a BrakeDiagnostic of mini_pad_fault (destroyed after)."""
    from rclpy.context import Context
    from rclpy.parameter import Parameter

    from metro_atc.nodes.brake_diagnostic import BrakeDiagnostic

    ctx = Context()
    rclpy.init(context=ctx, domain_id=ros_domain)
    made: list[Any] = []

    def make(ck: Path) -> Any:
        n = BrakeDiagnostic(context=ctx, parameter_overrides=[
            Parameter("scenario", value="mini_pad_fault"),
            Parameter("checkpoint_dir", value=str(ck))])
        made.append(n)
        return n

    try:
        yield make
    finally:
        for n in made:
            n.destroy_node()
        rclpy.shutdown(context=ctx)


def _msgs(seed: int) -> list[Any]:
    from metro_atc_msgs.msg import FleetBrakeSensorData

    batches = br.load_batches(BATCHES)
    if seed >= 0:
        batches = br.perturbed(batches, seed)
    out = []
    for b in batches:
        m = FleetBrakeSensorData()
        m.train_id = list(b["train_id"])
        m.sample_train = b["sample_train"].astype(int).tolist()
        m.stamp_ns = b["stamp_ns"].astype(int).tolist()
        m.axle_count = b["axle_count"].astype(int).tolist()
        for k in CHANNELS:
            setattr(m, k, b[k].astype(float).tolist())
        out.append(m)
    return out


def _state(node: Any) -> Any:
    """Every train's watch summary, as JSON text (NaN == NaN, floats exact)."""
    return json.dumps({t: br.train_summary(w) for t, w in node.watch.items()}, sort_keys=True)


def _feed(node: Any, msgs: list[Any]) -> None:
    for m in msgs:
        node._on_batch(m)
        node.flush()


@pytest.mark.parametrize("seed", [-1, 1])
def test_restart_replays_the_journal_to_the_same_state(make_node: Any, tmp_path: Path,
                                                       seed: int) -> None:
    """The restarted node's watches equal the first node's, then and after the rest."""
    from metro_atc.nodes.brake_diagnostic import PACKED_KEY

    msgs = _msgs(seed)
    cut = 700  # the pad fault (270 s) and its ERROR after the restart
    a = make_node(tmp_path)
    _feed(a, msgs[:cut])
    lines = (tmp_path / "brake_train_01.jsonl").read_text().splitlines()
    assert any(PACKED_KEY in x for x in lines)
    assert a.watch["train_01"].counts["paused"] > 1000
    b = make_node(tmp_path)
    assert _state(b) == _state(a)
    if seed >= 0:
        # (after a restart, a sample behind the stream is taken for the simulator's
        # re-send and the observer is rebuilt: the perturbed stream's stamps moved back
        # then diverge from the first node, as in main)
        return
    _feed(a, msgs[cut:])
    _feed(b, msgs[cut:])
    assert _state(b) == _state(a)
    assert b.watch["train_01"].level() == 2
    assert b.summary()[1:] == a.summary()[1:]  # (the first line: CPU rates)


@pytest.mark.parametrize("back", [1, 2, 3, 5, 10, 20, 40])
def test_a_resend_overlapping_the_journal_rebuilds_to_the_same_state(
        make_node: Any, tmp_path: Path, back: int) -> None:
    """After a restart, the simulator's re-send starts ``back`` batches before the end of
    what the killed node had journaled (its acknowledgement lagged the journal): the
    restarted node rebuilds its observers from the journal up to the first re-sent sample,
    takes the re-sent stream, and ends where the uninterrupted node ends.  (In the graph
    test of a killed brake_diagnostic this path is taken only when the kill fell between a
    journal write and its acknowledgement.)"""
    msgs = _msgs(-1)
    cut = 700
    a = make_node(tmp_path)
    _feed(a, msgs[:cut])
    b = make_node(tmp_path)
    rebuilt: list[str] = []
    replay = b._replay

    def spy(train_id: str, entries: list[Any]) -> None:
        rebuilt.append(train_id)
        replay(train_id, entries)

    b._replay = spy
    # a rebuild is due when a re-sent sample is behind the restarted observer's newest one
    # (the newest sent again is skipped: nothing new)
    newest = {t: w.t_last for t, w in b.watch.items()}
    due = {m.train_id[w] for m in msgs[cut - back:cut] for w, ns in
           zip(m.sample_train, m.stamp_ns) if ns * 1e-9 < newest[m.train_id[w]] - 1e-6}
    _feed(a, msgs[cut:])
    _feed(b, msgs[cut - back:])
    assert _state(b) == _state(a)
    assert b.summary()[1:] == a.summary()[1:]
    assert set(rebuilt) == due


def test_a_restarted_node_acknowledges_its_journal_until_the_resend_reaches_back(
        make_node: Any, tmp_path: Path) -> None:
    """After a restart the live stream may reach the node before the simulator's re-send
    (batches 700-719 published while it was down): its acknowledgement stays at its newest
    journaled sample, so the simulator still sees those samples pending (at the end of a run
    its drain waits for them), until a re-sent sample at or before it arrives, then at what
    its observer has taken until it has taken all; the node ends as the uninterrupted one.
    Without a re-send the hold lapses after HOLD_MAX_S."""
    import time

    msgs = _msgs(-1)
    cut, down = 700, 20
    a = make_node(tmp_path)
    _feed(a, msgs)
    journaled = make_node(tmp_path / "b")
    _feed(journaled, msgs[:cut])
    b = make_node(tmp_path / "b")
    held = dict(b.held)
    assert set(held) == {"train_01", "train_02"}, held
    _feed(b, msgs[cut + down:cut + down + 40])  # live, after the gap
    assert all(b._recv_t[t] > held[t] for t in held), (b._recv_t, held)
    assert {t: b._train_stamp(t) for t in held} == held
    _feed(b, msgs[cut - 3:cut + 5])  # the re-send of the kept samples begins
    assert not b.held and b.catching_up
    for t in b.catching_up:  # acknowledged as far as the observer has taken
        assert b._train_stamp(t) == b.watch[t].t_last < b._recv_t[t]
    _feed(b, msgs[cut + 5:])  # the rest of it, then the live stream
    assert not b.held
    assert all(b._train_stamp(t) == a._train_stamp(t) for t in held)
    assert _state(b) == _state(a)
    _feed(make_node(tmp_path / "c"), msgs[:cut])
    c = make_node(tmp_path / "c")  # restarted, and no re-send comes
    _feed(c, msgs[cut + down:cut + down + 40])
    assert c.held and all(c._train_stamp(t) < c._recv_t[t] for t in c.held)
    c._held_until = time.monotonic() - 1.0
    assert all(c._train_stamp(t) == c._recv_t[t] for t in ("train_01", "train_02"))
    assert not c.held


def test_journal_of_one_sample_per_line_is_read(make_node: Any, tmp_path: Path) -> None:
    """Journals written one JSON sample per line (the format before batches) replay the same."""
    from metro_atc.nodes.brake_diagnostic import unpacked_entries

    msgs = _msgs(1)[:500]
    a = make_node(tmp_path / "a")
    _feed(a, msgs)
    old = tmp_path / "old"
    old.mkdir()
    for f in (tmp_path / "a").glob("brake_*.jsonl"):
        entries, whole = unpacked_entries([json.loads(x) for x in f.read_text().splitlines()])
        assert whole
        (old / f.name).write_text("".join(json.dumps(e) + "\n" for e in entries))
    b = make_node(old)
    assert _state(b) == _state(a)


@pytest.mark.parametrize("seed", [-1, 1])
def test_decoder_rows_are_the_samples_bit_for_bit(seed: int) -> None:
    """The decoder's packed rows read back as its sample dicts (every float's bits)."""
    import base64
    import struct
    from types import SimpleNamespace

    from metro_atc.core.line.scenario import load_scenario
    from metro_atc.core.validate import bounds_for
    from metro_atc.nodes.wire import fleet_sensors
    from metro_atc.nodes.brake_diagnostic import PACKED_KEY, unpacked_entries

    scn = load_scenario("mini_pad_fault")
    index = {t: i for i, t in enumerate(scn.train_ids)}
    batches = br.load_batches(BATCHES)
    if seed >= 0:
        batches = br.perturbed(batches, seed)
    n = 0
    for b in batches:
        rows: list[bytes] = []
        items = fleet_sensors.samples(SimpleNamespace(**b), "/x", index, 4,
                                      bounds_for(scn), lists=True, rows=rows)
        assert len(rows) == len(items)
        for (_, _, s), row in zip(items, rows):
            if not isinstance(s, dict):
                continue
            e = unpacked_entries([{PACKED_KEY: base64.b64encode(row).decode("ascii")}])[0][0]
            flat = [s["t_s"], *s["omega"], *s["clamp"], s["accel"], s["ref_speed"],
                    s["car_mass"]]
            got = [e["t_s"], *e["omega"], *e["clamp"], e["accel"], e["ref_speed"],
                   e["car_mass"]]
            assert all(type(v) is float for v in flat)
            assert struct.pack("<12d", *got) == struct.pack("<12d", *flat)
            n += 1
    assert n > 4000


def test_journal_text_does_not_depend_on_the_bursts(make_node: Any, tmp_path: Path) -> None:
    """Written after every batch or once: the same journal files (two runs compare them)."""
    msgs = _msgs(1)[:400]
    a = make_node(tmp_path / "a")
    _feed(a, msgs)
    b = make_node(tmp_path / "b")
    for n, m in enumerate(msgs):
        b._on_batch(m)
        if n % 37 == 0:
            b.flush()
    b.flush()
    names = sorted(p.name for p in (tmp_path / "a").glob("brake_*.jsonl"))
    assert names and names == sorted(p.name for p in (tmp_path / "b").glob("brake_*.jsonl"))
    for name in names:
        text = (tmp_path / "a" / name).read_text()
        assert text and text == (tmp_path / "b" / name).read_text(), name


def test_a_level_change_goes_to_diagnostics_at_once(make_node: Any, tmp_path: Path) -> None:
    """OK -> WARN -> ERROR of the pad fault: /diagnostics published right after each batch
    that changed a level (not only at the wall-clock tick: a fast run's last tick can come
    before the ERROR), carrying the new level."""
    node = make_node(tmp_path)
    sent: list[int] = []
    publish = node.rt.publish

    def spy() -> None:
        sent.append(node._levels["train_01"])
        publish()

    node.rt.publish = spy
    levels = []
    for m in _msgs(-1):
        before = dict(node._levels)
        node._on_batch(m)
        node.flush()
        if node._levels["train_01"] != before["train_01"] and before["train_01"] >= 0:
            levels.append(node._levels["train_01"])
    assert levels == [1, 2], levels
    assert sent == levels
