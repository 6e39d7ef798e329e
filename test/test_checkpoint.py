"""Checkpoint of the line plant: save -> load -> continue equals the uninterrupted run.

ROS-free and fast. Several scenarios (incidents, wheel/pad/sensor faults, TSRs, ATP
interventions, NaN commands, ATS departure commands), a seeded random checkpoint step each
(printed): the resumed plant must give the same events, sensor samples and KPIs and end in a
bit-identical state (every array and scalar the walker captures, the RNG states included).
"""

from __future__ import annotations

import json
import math
import sys
import zlib
from pathlib import Path
from typing import Any

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

from golden import CASES, scenario_of  # noqa: E402

from metro_atc.core.checkpoint import CheckpointError, read  # noqa: E402
from metro_atc.core.plant.driver import random_driver, simple_driver  # noqa: E402
from metro_atc.core.plant.line import LineSim  # noqa: E402
from metro_atc.core.plant.snapshot import capture_line, load_line, save_line  # noqa: E402

STEPS = 1400
"""Steps of each run (0.5 s control period: 700 s, the incidents and faults included)."""


def _policy(sim: LineSim, k: int, rng: np.random.Generator) -> np.ndarray:
    """Reference driver, random commands (NaN/inf too) at times, ATS commands now and then."""
    if k % 97 == 5:
        for i in range(sim.n):
            j = int(sim.fleet.cur_station[i])
            if 0 <= j < sim.n_st - 1:
                sim.set_departure(i, j, sim.t + 20.0, 80.0)
    return random_driver(sim, rng) if k % 50 < 3 else simple_driver(sim)


def _outputs(res: Any) -> list[Any]:
    """Events and sensor samples of a step, as comparable values."""
    out: list[Any] = [repr(e) for e in res.events]
    b = res.sensor_arrays
    if b is not None:
        channels = ("t", "trains", "omega", "clamp", "accel", "vref")
        out += [np.asarray(getattr(b, c)).tobytes() for c in channels]
    return out


def _same_state(a: LineSim, b: LineSim) -> None:
    """The captured states are identical: same tree, bit-identical arrays."""
    ta, aa = capture_line(a)
    tb, ab = capture_line(b)
    assert json.dumps(ta) == json.dumps(tb)
    assert len(aa) == len(ab)
    for x, y in zip(aa, ab):
        assert x.dtype == y.dtype and x.shape == y.shape and x.tobytes() == y.tobytes()


@pytest.mark.parametrize("case", ["mini_incidents", "mini_atp_eb", "mini_pad_fault"])
def test_resume_equals_uninterrupted(case: str, tmp_path: Path) -> None:
    """Run A uninterrupted; run B checkpointed at a random step into a file and resumed."""
    c = next(x for x in CASES if x.name == case)
    scn = scenario_of(c)
    seed_rng = np.random.default_rng(zlib.crc32(case.encode()))
    k_save = int(seed_rng.integers(100, STEPS - 100))
    print(f"{case}: checkpoint at step {k_save}")
    a = LineSim(scn, seed=c.seed)
    b = LineSim(scn, seed=c.seed)
    ra, rb = np.random.default_rng(7), np.random.default_rng(7)
    out_a: list[Any] = []
    for k in range(STEPS):
        out_a += _outputs(a.step(_policy(a, k, ra)))
    out_b: list[Any] = []
    for k in range(k_save):
        out_b += _outputs(b.step(_policy(b, k, rb)))
    path = save_line(tmp_path / "line.npz", b, step=k_save)
    rb_state = rb.bit_generator.state
    for k in range(k_save, k_save + 40):  # B runs on: the resume must not depend on it
        b.step(_policy(b, k, rb))
    resumed = LineSim(scn, seed=c.seed)
    head = load_line(path, resumed)
    assert head["step"] == k_save and resumed.step_count == k_save
    rb.bit_generator.state = rb_state
    for k in range(k_save, STEPS):
        out_b += _outputs(resumed.step(_policy(resumed, k, rb)))
    assert len(out_a) == len(out_b)
    assert out_a == out_b
    ka, kb = a.kpis(), resumed.kpis()
    assert json.dumps(ka, sort_keys=True) == json.dumps(kb, sort_keys=True)
    assert [repr(e) for e in a.event_log()] == [repr(e) for e in resumed.event_log()]
    _same_state(a, resumed)
    assert math.isfinite(resumed.t) and resumed.t == a.t


def test_refuses_another_seed_or_a_foreign_file(tmp_path: Path) -> None:
    """A checkpoint of another seed, a non-checkpoint and a pickled array are refused."""
    scn = scenario_of(next(x for x in CASES if x.name == "mini_incidents"))
    sim = LineSim(scn, seed=1)
    for _ in range(20):
        sim.step(simple_driver(sim))
    path = save_line(tmp_path / "ck.npz", sim, step=20)
    with pytest.raises(CheckpointError, match="refusing"):
        load_line(path, LineSim(scn, seed=2))
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a checkpoint")
    with pytest.raises(CheckpointError, match="not a readable checkpoint"):
        read(bad)
    pickled = tmp_path / "pickled.npz"
    np.savez(pickled, header=np.frombuffer(b'{"format": 1}', dtype=np.uint8),
             a0=np.array([object()], dtype=object))
    with pytest.raises(CheckpointError):
        read(pickled)
    # the file is written atomically: no temporary file left behind
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.npz", "ck.npz", "pickled.npz"]


def test_journal_survives_a_torn_line(tmp_path: Path) -> None:
    """A line torn by a kill ends the journal; reopening keeps the good lines, appends on."""
    from metro_atc.core.journal import Journal, read_entries

    j = Journal(tmp_path / "j.jsonl")
    j.append({"step": 0, "x": math.nan})
    j.append({"step": 1, "x": math.inf})
    with open(tmp_path / "j.jsonl", "a") as fh:
        fh.write('{"step": 2, "x"')  # killed mid-write
    j2 = Journal(tmp_path / "j.jsonl")
    assert [e["step"] for e in j2.entries] == [0, 1]
    assert math.isnan(j2.entries[0]["x"]) and j2.entries[1]["x"] == math.inf
    j2.append({"step": 2})
    assert [e["step"] for e in read_entries(tmp_path / "j.jsonl")] == [0, 1, 2]
    j2.reset(j2.entries[:1])
    assert [e["step"] for e in read_entries(tmp_path / "j.jsonl")] == [0]


def test_journal_reading_stops_at_the_first_refused_entry(tmp_path: Path) -> None:
    """``read_entries(accept=...)``: the first entry refused (False or a KeyError) ends it."""
    from metro_atc.core.journal import read_entries
    p = tmp_path / "j.jsonl"
    p.write_text("".join(json.dumps({"step": k}) + "\n" for k in (3, 4, 5, 7, 8)))

    def consecutive(e: dict[str, Any], out: list[dict[str, Any]]) -> bool:
        return not out or e["step"] == out[-1]["step"] + 1

    assert [e["step"] for e in read_entries(p, consecutive)] == [3, 4, 5]
    assert len(read_entries(p)) == 5
    assert read_entries(p, lambda e, _: bool(e["missing"])) == []
