"""PlanStore: plans shared between ATO processes are the plans computed."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from metro_atc.core.ato.plan_store import PlanStore
from metro_atc.core.ato.planner import Profile


def _profile(rng: np.random.Generator, feasible: bool = True) -> Profile:
    n = int(rng.integers(1, 6))
    s = np.sort(rng.uniform(0.0, 2000.0, 50))
    return Profile(planner="ectp", x_start_m=float(rng.uniform(0, 1e4)),
                   x_stop_m=float(rng.uniform(0, 1e4)), target_running_time_s=101.0,
                   section_bounds_m=np.sort(rng.uniform(0, 2000, n + 1)),
                   modes=rng.integers(0, 4, n).astype(np.int64),
                   codes_mps=rng.uniform(0, 25, n), coast_point_m=math.nan if n % 2 else 5.5,
                   running_time_s=float(rng.uniform(60, 200)), energy_j=float(rng.uniform(0, 1e8)),
                   feasible=feasible, message="ok \u00e9", s_grid=s,
                   v_profile=rng.uniform(0, 25, s.size), compute_s=0.25)


def _same(a: Profile, b: Profile) -> bool:
    for k, v in vars(a).items():
        w = getattr(b, k)
        if isinstance(v, np.ndarray):
            if v.dtype != w.dtype or not np.array_equal(v, w):
                return False
        elif isinstance(v, float) and math.isnan(v):
            if not (isinstance(w, float) and math.isnan(w)):
                return False
        elif v != w or type(v) is not type(w):
            return False
    return True


def test_round_trip_is_exact(tmp_path: Path) -> None:
    """Every field comes back bit for bit and of the same type (a process reading a plan
    tracks exactly what the process that computed it tracks)."""
    rng = np.random.default_rng(13)
    a, b = PlanStore(tmp_path, "line|train"), PlanStore(tmp_path, "line|train")
    for k in range(40):
        p = _profile(rng, feasible=bool(k % 3))
        memo = ("ectp", (float(k), 2000.0), 101.0 + k, (("h_m", "2.0"),))
        assert b.get(memo) is None
        a.put(memo, p)
        q = b.get(memo)
        assert q is not None and _same(p, q), k
    assert b.hits == 40 and a.writes == 40


def test_other_context_and_damaged_files_miss(tmp_path: Path) -> None:
    """A store of another line/train never answers; a truncated or foreign file is ignored."""
    rng = np.random.default_rng(1)
    a = PlanStore(tmp_path, "line_a|train")
    memo = ("ectp", (0.0, 1.0), 90.0, ())
    a.put(memo, _profile(rng))
    assert PlanStore(tmp_path, "line_b|train").get(memo) is None
    f = a.path(memo)
    data = f.read_bytes()
    f.write_bytes(data[: len(data) // 2])
    assert a.get(memo) is None
    f.write_bytes(b"not a zip at all")
    assert a.get(memo) is None
    np.savez(f, planner=np.array([object()], dtype=object))  # needs pickle: refused
    assert a.get(memo) is None
    assert not list(tmp_path.glob(".plan_*")), "temporary files left behind"
