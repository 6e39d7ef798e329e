"""The on-board ATO's commands equal those recorded before the tracking fast paths.

The per-train tracking was made cheaper (values computed once per control step instead of
several times, plain floats instead of 0-d numpy in the fuzzy state, look-up tables as
lists); the commands must stay bit-identical.  ``test/ato_replay.py`` replays a graph run's
ATO journals through two code versions; this is its small version: the ROS-free closed loop
on the Blue line (first 300 s) and on a generated line with a TSR (500 s), every command
(effort bits, mode, plan) against ``test/data/ato_commands_golden.json.gz``, recorded from
the code before the change.  Equal commands give equal plant states, so the ATO saw the
same inputs all along.
"""

from __future__ import annotations

import gzip
import json

import pytest

import ato_replay
from metro_atc.launcher import ato_groups


@pytest.mark.parametrize("name,duration_s", ato_replay.GOLDEN_CASES)
def test_closed_loop_commands_equal_the_recorded_ones(name: str, duration_s: float) -> None:
    """Every command of the closed loop, bit for bit, in the same order."""
    golden = json.loads(gzip.decompress(ato_replay.GOLDEN.read_bytes()))
    want = golden[f"{name}@{duration_s:g}"]
    got = ato_replay.closed_loop_commands(name, duration_s)
    moving = sum(1 for line in want if line.split()[3] != "1")  # not dwelling
    assert len(want) > 1000 and moving > 500  # a run with real tracking in it
    for k, (a, b) in enumerate(zip(got, want)):
        assert a == b, f"command {k} differs: got {a!r}, recorded {b!r}"
    assert len(got) == len(want)


def test_ato_groups_round_robin() -> None:
    """Trains dealt round-robin, at most n per process, every train once, in order."""
    ids = [f"train_{k:02d}" for k in range(1, 31)]
    g = ato_groups(ids, 15)
    assert g == [ids[0::2], ids[1::2]]
    for n in (1, 4, 7, 15, 29, 30, 31, 100):
        g = ato_groups(ids, n)
        assert len(g) == -(-30 // n)
        assert all(0 < len(x) <= n for x in g)
        assert sorted(t for x in g for t in x) == ids
        assert all(x == sorted(x) for x in g)
        # balanced: the busiest process hosts at most one train more than the idlest
        assert max(map(len, g)) - min(map(len, g)) <= 1
    assert ato_groups(ids, 1) == [[t] for t in ids]
    assert ato_groups([], 15) == []
