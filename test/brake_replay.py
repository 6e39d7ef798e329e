"""ROS-free replay of recorded fleet brake sensor batches through the brake watches.

The ``brake_diagnostic`` node's verdicts are a deterministic function of the sample stream of
each train.  This module keeps the ``/line/brake_sensors`` batches of a run (read from a
``run --record`` bag), replays them the way the node handles them (validation by
:func:`metro_atc.nodes.wire.fleet_sensors.samples`, one
:class:`~metro_atc.core.brake.train_watch.TrainBrakeWatch` per train, the level checked after
every sample) and summarises per train the final diagnosis (result, counters, judged
estimates, observer state) and every level change (the alarm events: stamp, level, text).
Two versions of the code compare by their summaries (floats to a relative tolerance, the
rest exactly).

Command line (``PYTHONPATH`` choosing the code version)::

    python test/brake_replay.py record OUT/bag/bag.mcap batches.npz [--t-max S]
    python test/brake_replay.py replay batches.npz SCENARIO summary.json [--repeat 3]
    python test/brake_replay.py compare a.json b.json

``replay`` prints the CPU time of the replay (median of ``--repeat``).  The small version
kept as a test (``test/test_brake_replay.py``): the first 420 s of a ``mini_pad_fault``
graph run (``test/data/brake_batches_mini_pad_fault.npz``) against the summary recorded
from the code before the issue-13 per-sample rewrite
(``test/data/brake_replay_mini_pad_fault.json.gz``).  Re-record only when the diagnosis is
meant to change, and say so in the commit.
"""

from __future__ import annotations

import argparse
import gzip
import inspect
import json
import math
import statistics
import sys
import time
from pathlib import Path
from types import SimpleNamespace
from typing import Any, Sequence

import numpy as np

FIELDS = ("sample_train", "stamp_ns", "axle_count", "wheel_angular_speed_radps",
          "clamp_force_n", "longitudinal_acceleration_mps2", "reference_speed_mps",
          "car_mass_kg")
"""The per-sample array fields of a FleetBrakeSensorData kept per batch."""


def batches_from_bag(path: Path, t_max: float = math.inf) -> list[dict[str, Any]]:
    """The ``/line/brake_sensors`` batches of an MCAP bag (stamps up to ``t_max`` [s])."""
    from mcap.reader import make_reader
    from metro_atc_msgs.msg import FleetBrakeSensorData
    from rclpy.serialization import deserialize_message

    out: list[dict[str, Any]] = []
    with open(path, "rb") as f:
        for _, ch, m in make_reader(f).iter_messages(topics=["/line/brake_sensors"]):
            msg = deserialize_message(m.data, FleetBrakeSensorData)
            if msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec > t_max:
                continue
            b: dict[str, Any] = {"train_id": list(msg.train_id)}
            b.update({k: np.array(getattr(msg, k)) for k in FIELDS})
            out.append(b)
    return out


def save_batches(batches: Sequence[dict[str, Any]], path: Path) -> None:
    """Batches into one compressed ``.npz`` (fields concatenated, per-batch counts)."""
    ids = sorted({t for b in batches for t in b["train_id"]})
    arrays: dict[str, Any] = {"ids": np.array(ids)}
    arrays["batch_ids"] = np.array([[ids.index(t) for t in b["train_id"]] + [-1] *
                                    (len(ids) - len(b["train_id"])) for b in batches])
    for k in FIELDS:
        arrays[k] = np.concatenate([np.asarray(b[k]).reshape(-1) for b in batches])
        arrays[k + "_n"] = np.array([np.asarray(b[k]).size for b in batches])
    np.savez_compressed(path, **arrays)


def load_batches(path: Path) -> list[dict[str, Any]]:
    """The batches of :func:`save_batches`."""
    d = np.load(path)
    ids = [str(x) for x in d["ids"]]
    out: list[dict[str, Any]] = [{"train_id": [ids[i] for i in row if i >= 0]}
                                 for row in d["batch_ids"]]
    for k in FIELDS:
        ends = np.cumsum(d[k + "_n"])
        for b, part in zip(out, np.split(d[k], ends[:-1])):
            b[k] = part
    return out


def perturbed(batches: Sequence[dict[str, Any]], seed: int = 0) -> list[dict[str, Any]]:
    """The batches with hostile and degraded samples mixed in (deterministic in ``seed``).

    Per sample, independently: NaN wheel speeds / reference speed / clamp forces /
    acceleration / mass (dropouts), two axles beyond the adhesion peak (a slide), a wheel
    speed out of range, a stamp moved back (out of order), a sample of a train not in the
    scenario.  Every branch of the watch's sample handling is exercised.
    """
    rng = np.random.default_rng(seed)
    out = []
    for b in batches:
        n = b["stamp_ns"].size
        c = {k: (list(v) if k == "train_id" else np.array(v, copy=True)) for k, v in b.items()}
        if n == 0:
            out.append(c)
            continue
        w = c["wheel_angular_speed_radps"].reshape(n, -1)
        cl = c["clamp_force_n"].reshape(n, -1)
        u = rng.random((n, 10))
        w[u[:, 0] < 0.03, 1] = np.nan
        w[u[:, 1] < 0.01, :] = np.nan
        c["reference_speed_mps"][u[:, 2] < 0.03] = np.nan
        cl[u[:, 3] < 0.03, 2] = np.nan
        c["longitudinal_acceleration_mps2"][u[:, 4] < 0.03] = np.nan
        c["car_mass_kg"][u[:, 5] < 0.03] = np.nan
        w[u[:, 6] < 0.01, :2] *= 0.8
        w[u[:, 7] < 0.005, 3] = 5000.0
        back = u[:, 8] < 0.01
        c["stamp_ns"][back] -= 2_000_000_000
        c["stamp_ns"] = np.maximum(c["stamp_ns"], 0)
        if (u[:, 9] < 0.005).any():
            c["train_id"].append("train_99")
            c["sample_train"][u[:, 9] < 0.005] = len(c["train_id"]) - 1
        out.append(c)
    return out


def _f(x: Any) -> Any:
    """JSON-able plain values (floats, ints, bools, lists)."""
    if isinstance(x, np.ndarray):
        return [_f(v) for v in x.tolist()]
    if isinstance(x, (list, tuple)):
        return [_f(v) for v in x]
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    if isinstance(x, (int, np.integer)):
        return int(x)
    if isinstance(x, (float, np.floating)):
        return float(x)
    return x


def train_summary(w: Any) -> dict[str, Any]:
    """Final state of one TrainBrakeWatch (diagnosis, counters, judged, observer state)."""
    r = w.result
    res = {k: _f(getattr(r, k)) for k in (
        "t", "mu_b", "mu_b_std", "forces", "force_std", "target_forces", "residual_forces",
        "residuals", "creep", "speed", "grade", "pad_flaw", "wheel_flaw", "level", "message",
        "measurement_used", "skipped_reason")}
    lvl, text = w.level_message()
    ukf = w.obs.ukf
    return {"result": res, "level": lvl, "text": text, "counts": dict(w.counts),
            "t_last": _f(w.t_last), "max_gap": _f(w.max_gap), "state": w.state,
            "updates": w.updates, "braked_updates": w.braked_updates,
            "mu_b_range": _f(w.mu_b_range), "flaw_time": w.flaw_time,
            "flaw_text": w.flaw_text, "last_judged": _f(w.last_judged), "judged": _f(w.judged),
            "mass": _f(w.obs.mass), "obs_resets": w.obs.counters.resets,
            "obs_updates": w.obs.counters.updates,
            "ukf_x": None if ukf is None else _f(ukf.x),
            "ukf_p_diag": None if ukf is None else _f(np.diagonal(ukf.p))}


def replay(batches: Sequence[dict[str, Any]], scenario: str) -> tuple[dict[str, Any], float]:
    """Feed the batches to fresh watches as the node does; (summary, CPU seconds)."""
    from metro_atc.core.brake.train_watch import N_AXLES, TrainBrakeWatch, observer_setup
    from metro_atc.core.line.scenario import load_scenario
    from metro_atc.core.validate import bounds_for
    from metro_atc.nodes import conversions as conv
    from metro_atc.nodes.wire import fleet_sensors

    scn = load_scenario(scenario)
    setup = observer_setup(scn)
    bounds = bounds_for(scn)
    ids = list(scn.sensors.trains or scn.train_ids)
    index = {t: i for i, t in enumerate(ids)}
    watch = {t: TrainBrakeWatch(t, setup) for t in ids}
    levels = {t: -1 for t in ids}
    events: dict[str, list[Any]] = {t: [] for t in ids}
    # the node's own options where this code version has them (an older one: defaults)
    kw = ({"lists": True} if "lists" in inspect.signature(fleet_sensors.samples).parameters
          else {})
    fast_level = hasattr(TrainBrakeWatch, "level")
    t0 = time.process_time()
    for bt in batches:
        items = fleet_sensors.samples(SimpleNamespace(**bt), "/line/brake_sensors", index,
                                      N_AXLES, bounds, **kw)
        for tid, _, s in items:
            if tid is None:
                continue
            w = watch[tid]
            if isinstance(s, conv.MessageRejected):
                w.reject()
                continue
            if w.feed(s) == "out_of_order":
                continue
            lvl = w.level() if fast_level else w.level_message()[0]
            if lvl != levels[tid]:
                events[tid].append([s["t_s"], lvl, w.level_message()[1]])
                levels[tid] = lvl
    cpu = time.process_time() - t0
    return {"trains": {t: train_summary(watch[t]) for t in ids}, "events": events}, cpu


def compare(a: Any, b: Any, rtol: float = 1e-9, path: str = "") -> list[str]:
    """Differences between two summaries: floats beyond ``rtol`` relative, anything else."""
    out: list[str] = []
    if isinstance(a, dict) and isinstance(b, dict):
        for k in sorted(set(a) | set(b)):
            if k not in a or k not in b:
                out.append(f"{path}/{k}: missing on one side")
            else:
                out += compare(a[k], b[k], rtol, f"{path}/{k}")
    elif isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            out.append(f"{path}: length {len(a)} != {len(b)}")
        else:
            for i, (x, y) in enumerate(zip(a, b)):
                out += compare(x, y, rtol, f"{path}[{i}]")
    elif isinstance(a, float) and isinstance(b, float):
        if not (a == b or (math.isnan(a) and math.isnan(b))
                or abs(a - b) <= rtol * max(abs(a), abs(b))):
            out.append(f"{path}: {a!r} != {b!r}")
    elif a != b:
        out.append(f"{path}: {a!r} != {b!r}")
    return out


def _write(obj: Any, path: Path) -> None:
    text = json.dumps(obj)
    if str(path).endswith(".gz"):
        with gzip.open(path, "wt", encoding="utf-8") as f:
            f.write(text)
    else:
        Path(path).write_text(text, encoding="utf-8")


def read_summary(path: Path) -> Any:
    """A summary written by ``replay`` (``.json`` or ``.json.gz``)."""
    if str(path).endswith(".gz"):
        with gzip.open(path, "rt", encoding="utf-8") as f:
            return json.load(f)
    return json.loads(Path(path).read_text(encoding="utf-8"))


def main(argv: Sequence[str] | None = None) -> int:
    """Command line (module docstring)."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("record")
    r.add_argument("bag", type=Path)
    r.add_argument("out", type=Path)
    r.add_argument("--t-max", type=float, default=math.inf)
    p = sub.add_parser("replay")
    p.add_argument("batches", type=Path)
    p.add_argument("scenario")
    p.add_argument("out", type=Path)
    p.add_argument("--repeat", type=int, default=1)
    p.add_argument("--perturb", type=int, default=-1, metavar="SEED",
                   help="replay perturbed(batches, SEED) (hostile and degraded samples)")
    c = sub.add_parser("compare")
    c.add_argument("a", type=Path)
    c.add_argument("b", type=Path)
    c.add_argument("--rtol", type=float, default=1e-9)
    a = ap.parse_args(argv)
    if a.cmd == "record":
        batches = batches_from_bag(a.bag, a.t_max)
        save_batches(batches, a.out)
        print(f"{len(batches)} batches, {sum(b['stamp_ns'].size for b in batches)} samples")
        return 0
    if a.cmd == "replay":
        batches = load_batches(a.batches)
        if a.perturb >= 0:
            batches = perturbed(batches, a.perturb)
        cpus = []
        for _ in range(max(a.repeat, 1)):
            summary, cpu = replay(batches, a.scenario)
            cpus.append(cpu)
        _write(summary, a.out)
        print(f"replay CPU {statistics.median(cpus):.3f} s (median of {len(cpus)}: "
              f"{', '.join(f'{x:.3f}' for x in cpus)})")
        return 0
    diffs = compare(read_summary(a.a), read_summary(a.b), a.rtol)
    print("\n".join(diffs[:50]) or "identical")
    print(f"{len(diffs)} differences")
    return 1 if diffs else 0


if __name__ == "__main__":
    sys.exit(main())
