"""The brake watches reproduce recorded diagnoses from recorded fleet sensor batches.

``test/data/brake_batches_mini_pad_fault.npz``: the first 420 s of ``/line/brake_sensors`` of
a ``mini_pad_fault`` graph run (main d06fecf; 1 022 batches, 4 462 samples; the pad fault of
train_01 at 270 s and its ERROR at 278.6 s in them).  The expected summaries (final
diagnosis, counters, judged estimates, observer state and every level change per train)
were recorded with the code before the issue-13 per-sample rewrite
(:mod:`test.brake_replay`), on the batches as recorded and with hostile / degraded samples
mixed in (:func:`brake_replay.perturbed`: dropouts, slides, out-of-range values, stamps out
of order, an unknown train).  The rewrite keeps the arithmetic element by element, so the
comparison allows only 1e-9 relative on floats; levels, texts and counters are exact.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path
from typing import Any

import pytest

sys.path.insert(0, str(Path(__file__).parent))

import brake_replay as br  # noqa: E402

DATA = Path(__file__).parent / "data"
BATCHES = DATA / "brake_batches_mini_pad_fault.npz"


@pytest.mark.parametrize("seed,golden", [(-1, "brake_replay_mini_pad_fault.json.gz"),
                                         (1, "brake_replay_mini_pad_fault_perturbed.json.gz")])
def test_replay_matches_recorded_diagnosis(seed: int, golden: str) -> None:
    """Final BrakeDiagnosis state and alarm events equal the recorded ones."""
    batches = br.load_batches(BATCHES)
    if seed >= 0:
        batches = br.perturbed(batches, seed)
    got, _ = br.replay(batches, "mini_pad_fault")
    want = br.read_summary(DATA / golden)
    diffs = br.compare(want, json.loads(json.dumps(got)))
    assert not diffs, "\n".join(diffs[:20])
    # the stream is not trivial: the fault is announced, every sample kind occurs
    ev = want["events"]["train_01"]
    assert [e[1] for e in ev] == [0, 1, 2] and 270.0 < ev[-1][0] < 280.0
    c = want["trains"]["train_01"]["counts"]
    assert c["used"] > 300 and c["paused"] > 2000
    if seed >= 0:
        assert min(c["degraded"], c["sliding"], c["rejected"]) > 0


def test_compare_sees_a_difference() -> None:
    """The comparison is not blind: a changed float, level or length is reported."""
    a = {"x": [1.0, 2.0], "level": 1}
    assert br.compare(a, {"x": [1.0, 2.0 * (1 + 1e-12)], "level": 1}) == []
    assert br.compare(a, {"x": [1.0, 2.0 * (1 + 1e-8)], "level": 1})
    assert br.compare(a, {"x": [1.0, 2.0], "level": 2})
    assert br.compare(a, {"x": [1.0], "level": 1})


def test_batches_round_trip(tmp_path: Path) -> None:
    """save_batches / load_batches keep every field of every batch."""
    batches = br.load_batches(BATCHES)[:50]
    br.save_batches(batches, tmp_path / "b.npz")
    again = br.load_batches(tmp_path / "b.npz")
    assert len(again) == len(batches)
    for x, y in zip(batches, again):
        assert x["train_id"] == y["train_id"]
        for k in br.FIELDS:
            assert x[k].tolist() == y[k].tolist()


def test_packed_journal_lines_give_the_entries_back() -> None:
    """The node's journal lines (samples packed) read back as the entries, exactly.

    Any float (NaN, infinities, -0.0, subnormals) comes back bit for bit; a rejection, a
    sample of another axle count or with a value that is not a float (never from the
    decoder) stays a JSON line of its own, in order; lines written by main (one sample
    each) are read as they are.
    """
    import random
    import struct

    import numpy as np

    from metro_atc.nodes.brake_diagnostic import (PACKED_KEY, _journal_lines, _line_json,
                                                  packed_entries, unpacked_entries)

    rnd = random.Random(0)
    special = [0.0, -0.0, 1e-300, 1e300, math.nan, math.inf, -math.inf, 35000.0, 5e-324]

    def pick() -> float:
        if rnd.random() < 0.3:
            return rnd.choice(special)
        return rnd.uniform(-1e6, 1e6) * 10.0 ** rnd.randint(-12, 12)

    def bits(e: Any) -> Any:
        """Each float as its 8 bytes (NaN == NaN), lists and dicts walked."""
        if isinstance(e, dict):
            return {k: bits(v) for k, v in e.items()}
        if isinstance(e, list):
            return [bits(v) for v in e]
        if isinstance(e, float):
            return (type(e).__name__, struct.pack("<d", e))
        return e

    entries: list[dict[str, Any]] = []
    for i in range(3000):
        if i % 13 == 0:
            entries.append({"rejected": "range"})
            continue
        e: dict[str, Any] = {"t_s": pick(), "omega": [pick() for _ in range(4)],
                             "clamp": [pick() for _ in range(4)], "accel": pick(),
                             "ref_speed": pick(), "car_mass": pick()}
        if i % 29 == 0:
            e["omega"] = e["omega"][:3]
        if i % 31 == 0:
            e["t_s"] = rnd.randint(0, 100)
        entries.append(e)
    lines = packed_entries(entries)
    assert sum(1 for x in lines if PACKED_KEY in x) > 2000  # the samples of floats
    assert len(lines) == len(entries)  # one line each (as main: independent of bursts)
    assert all(_line_json(x) == json.dumps(x) for x in lines)
    # the node's path: samples the decoder packed (bytes) give the same lines
    rows = [struct.pack("<12d", e["t_s"], *e["omega"], *e["clamp"], e["accel"],
                        e["ref_speed"], e["car_mass"])
            if PACKED_KEY in x else e for e, x in zip(entries, lines)]
    assert _journal_lines(rows) == lines
    # through the file's JSON text, as Journal writes and reads it
    back, whole = unpacked_entries([json.loads(json.dumps(x)) for x in lines])
    assert whole
    # JSON lines keep their ints; packed samples come back as Python floats
    assert bits(back) == bits(json.loads(json.dumps(entries)))
    assert all(type(v) is float for e in back if "omega" in e and len(e["omega"]) == 4
               and not isinstance(e["t_s"], int) for v in (e["t_s"], *e["omega"]))
    # main's lines (one sample each) are read as they are
    assert unpacked_entries(entries) == (entries, True)
    # a damaged packed line ends the entries before it, like a torn line
    cut = next(n for n, x in enumerate(lines) if PACKED_KEY in x and n > 3)
    bad = [dict(x) for x in lines]
    bad[cut] = {PACKED_KEY: bad[cut][PACKED_KEY][:-7]}
    got, whole = unpacked_entries(bad)
    want, _ = unpacked_entries(lines[:cut])
    assert not whole and bits(got) == bits(want)
    assert unpacked_entries([{PACKED_KEY: 3}]) == ([], False)
    assert unpacked_entries([{PACKED_KEY: "!!!!"}]) == ([], False)
    del np
