"""FleetBrakeSensorData: the per-train samples' values and rules, batched.

Every sample of a fleet message validates to what :func:`conv.sensor_from_msg` makes of the
same sample sent alone on ``/<train>/brake_sensors`` (bit for bit, stamps included); hostile
messages (wrong lengths, NaN, infinities, unknown trains, huge arrays, random damage) are
rejected with a counted kind and never raise anything else.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message

from metro_atc.core.line.scenario import load_scenario
from metro_atc.core.validate import Rejected, bounds_for
from metro_atc.nodes import conversions as conv
from metro_atc.nodes.wire import fleet_sensors

SCN = load_scenario("mini")
B = bounds_for(SCN)
IDS = ["train_01", "train_02", "train_03", "train_04"]
INDEX = {t: i for i, t in enumerate(IDS)}
TOPIC = "/line/brake_sensors"


def _batch(rng: np.random.Generator, n: int, nan_share: float = 0.2) -> dict[str, Any]:
    """Random realistic samples: stamps increasing, some NaN dropouts, 4 axles."""
    t = np.sort(rng.uniform(0.0, 0.9 * B.horizon_s, size=n))
    w = rng.uniform(0.0, 120.0, size=(n, 4))
    c = rng.uniform(0.0, 3e4, size=(n, 4))
    acc = rng.uniform(-1.5, 1.2, size=n)
    vref = rng.uniform(0.0, 25.0, size=n)
    mass = rng.uniform(3e4, 5e4, size=n)
    for arr in (w, c, acc, vref, mass):
        flat = arr.reshape(-1)
        flat[rng.random(flat.size) < nan_share / 4] = np.nan
    return {"trains": rng.integers(0, len(IDS), size=n), "t_s": t, "omega_radps": w,
            "clamp_n": c, "accel_mps2": acc, "ref_speed_mps": vref, "car_mass_kg": mass}


def _msg(d: dict[str, Any], t_step: float = 100.0, ids: list[str] = IDS) -> Any:
    return fleet_sensors.to_msg(ids, t_step, **d)


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return np.array_equal(np.asarray(a), np.asarray(b), equal_nan=True)
    return a == b or (isinstance(a, float) and isinstance(b, float) and math.isnan(a)
                      and math.isnan(b))


def test_fleet_samples_validate_to_the_per_train_samples() -> None:
    """Through CDR and back, each sample of a batch is the per-train message's sample."""
    from metro_atc_msgs.msg import FleetBrakeSensorData

    rng = np.random.default_rng(5)
    checked = 0
    for n in (0, 1, 2, 7, 40, 300):
        d = _batch(rng, n)
        m = deserialize_message(serialize_message(_msg(d)), FleetBrakeSensorData)
        got = fleet_sensors.samples(m, TOPIC, INDEX, 4, B)
        assert len(got) == n
        for s, (tid, stamp, sample) in enumerate(got):
            i = int(d["trains"][s])
            one = conv.sensor_sample_msg(IDS[i], float(d["t_s"][s]), d["omega_radps"][s],
                                         d["clamp_n"][s], float(d["accel_mps2"][s]),
                                         float(d["ref_speed_mps"][s]),
                                         float(d["car_mass_kg"][s]))
            ref = conv.sensor_from_msg(one, f"/{IDS[i]}/brake_sensors", IDS[i], 4, B)
            assert tid == IDS[i] and stamp == conv.from_time(one.header.stamp)
            assert isinstance(sample, dict) and sample.keys() == ref.keys()
            for k in ref:
                assert _same(sample[k], ref[k]), (k, sample[k], ref[k])
                assert type(sample[k]) is type(ref[k]), k
            checked += 1
        assert list(m.train_id) == IDS
    assert checked == 350


@pytest.mark.parametrize("field", ["sample_train", "stamp_ns", "axle_count",
                                   "wheel_angular_speed_radps", "clamp_force_n",
                                   "longitudinal_acceleration_mps2", "reference_speed_mps",
                                   "car_mass_kg"])
def test_wrong_lengths_reject_the_message(field: str) -> None:
    """One array a value short or long: the whole message is one rejection (kind length)."""
    rng = np.random.default_rng(6)
    for delta in (-1, 1):
        m = _msg(_batch(rng, 5))
        vals = list(getattr(m, field))
        setattr(m, field, vals[:-1] if delta < 0 else vals + [vals[-1]])
        with pytest.raises(Rejected) as exc:
            fleet_sensors.samples(m, TOPIC, INDEX, 4, B)
        assert exc.value.kind == "length", (field, delta, exc.value)


def test_hostile_samples_are_rejected_one_by_one() -> None:
    """Bad samples are rejected with the per-train kinds; the good ones of the batch pass."""
    rng = np.random.default_rng(7)
    d = _batch(rng, 6, nan_share=0.0)
    d["omega_radps"][1, 2] = np.inf             # range
    d["car_mass_kg"][2] = -5.0                  # range
    d["t_s"][3] = 1e6                           # beyond the horizon: time
    d["ref_speed_mps"][4] = np.nan              # a dropout: passes
    m = _msg(d)
    got = fleet_sensors.samples(m, TOPIC, INDEX, 4, B)
    kinds = [s.kind if isinstance(s, Rejected) else "ok" for _, _, s in got]
    assert kinds == ["ok", "range", "range", "time", "ok", "ok"]
    assert math.isnan(got[4][2]["ref_speed"])  # type: ignore[index]
    assert got[3][1] == conv.from_time(conv.to_time(1e6))  # the stamp of a rejected one
    # a sample with 3 axles in the middle: only it is rejected (axles)
    m = _msg(_batch(rng, 3, nan_share=0.0))
    w = list(m.wheel_angular_speed_radps)
    c = list(m.clamp_force_n)
    m.axle_count = [4, 3, 4]
    m.wheel_angular_speed_radps = w[:4] + w[4:7] + w[8:]
    m.clamp_force_n = c[:4] + c[4:7] + c[8:]
    got = fleet_sensors.samples(m, TOPIC, INDEX, 4, B)
    assert [s.kind if isinstance(s, Rejected) else "ok" for _, _, s in got] == \
        ["ok", "axles", "ok"]
    np.testing.assert_array_equal(got[2][2]["omega"], np.asarray(w[8:]))  # type: ignore
    # an unknown train: no train, kind train_id; the others pass
    d = _batch(rng, 4, nan_share=0.0)
    d["trains"] = np.array([0, 1, 0, 1])
    got = fleet_sensors.samples(_msg(d, ids=["train_01", "train_99"]), TOPIC, INDEX, 4, B)
    assert [(t, isinstance(s, Rejected) and s.kind) for t, _, s in got] == \
        [("train_01", False), (None, "train_id"), ("train_01", False), (None, "train_id")]


def test_huge_and_out_of_range_index_messages_are_rejected() -> None:
    """Too many samples, absurd axle counts, indices past train_id: kind length."""
    rng = np.random.default_rng(8)
    n = fleet_sensors.MAX_SAMPLES + 1
    d = _batch(rng, n, nan_share=0.0)
    with pytest.raises(Rejected) as exc:
        fleet_sensors.samples(_msg(d), TOPIC, INDEX, 4, B)
    assert exc.value.kind == "length"
    m = _msg(_batch(rng, 2, nan_share=0.0))
    m.axle_count = [1_000_000_000, 0]
    with pytest.raises(Rejected) as exc:
        fleet_sensors.samples(m, TOPIC, INDEX, 4, B)
    assert exc.value.kind == "length"
    m = _msg(_batch(rng, 2, nan_share=0.0))
    m.sample_train = [0, 7]
    with pytest.raises(Rejected) as exc:
        fleet_sensors.samples(m, TOPIC, INDEX, 4, B)
    assert exc.value.kind == "length"


def test_random_damage_never_raises_anything_else() -> None:
    """Random field damage: a result or a Rejected, nothing else, no NaN train id."""
    rng = np.random.default_rng(9)
    fields = ["sample_train", "stamp_ns", "axle_count", "wheel_angular_speed_radps",
              "clamp_force_n", "longitudinal_acceleration_mps2", "reference_speed_mps",
              "car_mass_kg"]
    outcomes = {"ok": 0, "rejected": 0}
    for _ in range(600):
        m = _msg(_batch(rng, int(rng.integers(0, 12))))
        for _ in range(int(rng.integers(1, 4))):
            f = fields[int(rng.integers(len(fields)))]
            vals = list(getattr(m, f))
            if vals and rng.random() < 0.5:
                j = int(rng.integers(len(vals)))
                if f in ("sample_train", "axle_count"):
                    vals[j] = int(rng.integers(0, 9))
                elif f == "stamp_ns":
                    vals[j] = int(rng.integers(-2**62, 2**62))
                else:
                    vals[j] = float(rng.choice([np.nan, np.inf, -np.inf, 1e300, -1e300, 0.0]))
            else:
                vals = vals[:int(rng.integers(0, len(vals) + 1))]
            setattr(m, f, vals)
        try:
            got = fleet_sensors.samples(m, TOPIC, INDEX, 4, B)
        except Rejected:
            outcomes["rejected"] += 1
            continue
        outcomes["ok"] += 1
        for tid, stamp, s in got:
            assert tid is None or tid in INDEX
            assert isinstance(stamp, float)
            if isinstance(s, dict):
                assert s["omega"].shape == (4,) and s["clamp"].shape == (4,)
                assert 0.0 <= s["t_s"] <= B.horizon_s
    assert outcomes["ok"] > 50 and outcomes["rejected"] > 50, outcomes
