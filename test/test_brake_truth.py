"""The brake diagnosis tells the truth: rejected samples change nothing, "not assessed" is said.

In process (no graph), on the recorded ``mini_pad_fault`` batches of ``test/brake_replay.py``:

* a sample stamped 1e6 s (beyond the run: rejected) mixed into the stream leaves every
  train's acknowledgement, journaled samples and observer exactly as without it (before, it
  raised its train's "newest received" stamp, every later BrakeDiagnosis carried that stamp,
  the simulator rejected them all and the run's end waited out its drain timeout);
* a valid sample stamped in the future (inside the run) is followed by the stream behind it
  (``RESYNC_SAMPLES``): the acknowledgement then follows the stream again;
* the ROS-free line monitor and the node's summary say per train whether its brake was
  assessed (friction-brake updates at speed) and count false alarms only where it was.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

sys.path.insert(0, str(Path(__file__).parent))

import brake_replay as br  # noqa: E402
import test_brake_journal as journal  # noqa: E402

_feed, _msgs = journal._feed, journal._msgs
make_node = journal.make_node
"""The fixture of ``test_brake_journal`` (a BrakeDiagnostic of mini_pad_fault)."""

TRAINS = ("train_01", "train_02")


def _one_sample(like: Any, train: str, stamp_ns: int) -> Any:
    """A FleetBrakeSensorData of one sample of ``train`` stamped ``stamp_ns``, its channels
    those of the first sample of ``like`` (plausible values)."""
    from metro_atc_msgs.msg import FleetBrakeSensorData

    m = FleetBrakeSensorData()
    m.train_id = [train]
    m.sample_train = [0]
    m.stamp_ns = [int(stamp_ns)]
    m.axle_count = [4]
    m.wheel_angular_speed_radps = [float(x) for x in like.wheel_angular_speed_radps[:4]]
    m.clamp_force_n = [float(x) for x in like.clamp_force_n[:4]]
    for k in ("longitudinal_acceleration_mps2", "reference_speed_mps", "car_mass_kg"):
        setattr(m, k, [float(getattr(like, k)[0])])
    return m


def _samples(path: Path) -> list[str]:
    """The journal's sample entries (rejection lines left out), as JSON text."""
    from metro_atc.nodes.brake_diagnostic import unpacked_entries

    lines = [json.loads(x) for x in path.read_text().splitlines()]
    entries, whole = unpacked_entries(lines)
    assert whole
    return [json.dumps(e, sort_keys=True) for e in entries if "rejected" not in e]


def _watch(node: Any, train: str) -> dict[str, Any]:
    """A watch's state but its sample counters (which count the rejection)."""
    s = br.train_summary(node.watch[train])
    s.pop("counts")
    s.pop("level"), s.pop("text")  # (the data-quality share of the counters)
    return s


def test_a_rejected_sample_changes_no_acknowledgement(make_node: Any, tmp_path: Path) -> None:
    """A sample stamped 1e6 s: rejected and counted, and nothing else changes."""
    msgs = _msgs(-1)
    cut = 300
    a = make_node(tmp_path / "a")
    b = make_node(tmp_path / "b")
    _feed(a, msgs[:cut])
    _feed(b, msgs[:cut])
    b._on_batch(_one_sample(msgs[cut - 1], "train_01", 10**15))  # t = 1e6 s
    b.flush()
    assert b.watch["train_01"].counts["rejected"] == 1
    assert sum(b.rejections.as_dict().values()) == 1
    for t in TRAINS:
        assert b._train_stamp(t) == a._train_stamp(t) < 1e5, (t, b._train_stamp(t))
    _feed(a, msgs[cut:])
    _feed(b, msgs[cut:])
    a._acknowledge()
    b._acknowledge()
    for t in TRAINS:
        assert b._pub_stamp[t] == a._pub_stamp[t] < 1e5, (t, b._pub_stamp[t])
        assert _watch(b, t) == _watch(a, t)
        assert _samples(tmp_path / "b" / f"brake_{t}.jsonl") == \
            _samples(tmp_path / "a" / f"brake_{t}.jsonl")


def test_the_acknowledgement_follows_the_stream_after_a_future_stamp(
        make_node: Any, tmp_path: Path) -> None:
    """A valid sample stamped 500 s ahead (inside the run) is taken, then the stream behind
    it re-synchronises the watch: from there the acknowledgement is the stream's again."""
    msgs = _msgs(-1)
    cut = 300
    a = make_node(tmp_path / "a")
    b = make_node(tmp_path / "b")
    _feed(a, msgs[:cut])
    _feed(b, msgs[:cut])
    ahead = b.watch["train_01"].t_last + 500.0
    assert ahead < b.bounds.horizon_s
    b._on_batch(_one_sample(msgs[cut - 1], "train_01", int(round(ahead * 1e9))))
    assert b._train_stamp("train_01") == pytest.approx(ahead)
    _feed(a, msgs[cut:])
    _feed(b, msgs[cut:])
    for t in TRAINS:
        assert b._train_stamp(t) == a._train_stamp(t), t
    assert b.watch["train_01"].resyncs == 1


def test_line_monitor_says_where_the_brake_was_not_assessed() -> None:
    """A run whose friction brakes never act at speed: every train "not assessed", and no
    false-alarm count (None) instead of 0; with brakes at speed, assessed and counted."""
    from metro_atc.core.brake.line_monitor import LineBrakeMonitor
    from metro_atc.core.line.scenario import load_scenario

    scn = load_scenario("mini_pad_fault")
    mon = LineBrakeMonitor(scn)
    s = mon.summary()  # nothing fed: nothing assessed
    assert s["brake_assessed"] == {t: False for t in scn.train_ids}
    assert s["brake_trains_assessed"] == 0
    assert s["brake_false_alarms"] is None and s["brake_false_errors"] is None
    # the recorded batches of the same scenario: both trains brake at speed
    for bt in br.load_batches(br_batches()):
        _feed_monitor(mon, bt)
    s = mon.summary()
    assert s["brake_assessed"] == {t: True for t in scn.train_ids}, s
    assert s["brake_false_alarms"] == 0 and s["brake_false_errors"] == 0


def br_batches() -> Path:
    """The recorded mini_pad_fault batches."""
    return Path(__file__).parent / "data" / "brake_batches_mini_pad_fault.npz"


def _feed_monitor(mon: Any, bt: dict[str, Any]) -> None:
    """One recorded batch into the monitor's watches, as :meth:`LineBrakeMonitor._feed`."""
    ids = list(bt["train_id"])
    n = bt["stamp_ns"].size
    w = np.asarray(bt["wheel_angular_speed_radps"], dtype=float).reshape(n, -1)
    c = np.asarray(bt["clamp_force_n"], dtype=float).reshape(n, -1)
    for k in range(n):
        tid = ids[int(bt["sample_train"][k])]
        i = mon.ids.index(tid)
        mon.feed_sample(i, {"t_s": float(bt["stamp_ns"][k]) * 1e-9, "omega": w[k],
                            "clamp": c[k],
                            "accel": float(bt["longitudinal_acceleration_mps2"][k]),
                            "ref_speed": float(bt["reference_speed_mps"][k]),
                            "car_mass": float(bt["car_mass_kg"][k])})


def test_node_summary_says_not_assessed(make_node: Any, tmp_path: Path) -> None:
    """The node's summary: "brake not assessed" for a train without a friction-brake
    update at speed (nor a judged mu_b), "assessed" once it has one; a line counts them."""
    msgs = _msgs(-1)
    a = make_node(tmp_path)
    _feed(a, msgs[:5])
    lines = a.summary()[2:]
    assert all("brake not assessed" in ln for ln in lines), lines
    assert a.summary()[1] == "brake assessed on 0 of 2 trains; not assessed: train_01, " \
        "train_02"
    _feed(a, msgs[5:])
    lines = a.summary()[2:]
    assert all("brake assessed" in ln and "not assessed" not in ln for ln in lines), lines
    assert a.summary()[1] == "brake assessed on 2 of 2 trains"
    assert all(math.isfinite(a.watch[t].t_last) for t in TRAINS)
