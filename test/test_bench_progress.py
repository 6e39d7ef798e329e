"""Progress rows of the benches: content, rate limit, switch, no side effect."""

from __future__ import annotations

import io

import numpy as np
import pytest

from metro_atc.bench.progress import PROGRESS_ENV, Progress, progress_each, progress_enabled
from metro_atc.core.ato.envelope import RunModel
from metro_atc.core.ato.fuzzy import FuzzyController
from metro_atc.core.ato.reference_curve import ReferenceCurve
from metro_atc.core.ato.tracking import simulate_tracking
from metro_atc.core.line.vehicle import THSR_700T, Track


def test_row_has_done_total_rate_and_eta() -> None:
    buf = io.StringIO()
    p = Progress("bench x", 100, "simulated s", stream=buf, enabled=True, rate_name="rtf")
    assert p.update(0, force=True)
    text = p.row(50, "3 trains")
    assert text.startswith("bench x: 50 / 100 simulated s, 3 trains, ")
    assert "x real time" in text and "ETA " in text and "ETA ?" not in text


def test_rows_are_rate_limited_and_forced_rows_always_print() -> None:
    buf = io.StringIO()
    p = Progress("b", 10, stream=buf, enabled=True, period_s=3600.0)
    assert p.update(1, force=True)
    assert not p.update(2)
    assert p.update(10, "done", force=True)
    assert buf.getvalue().count("\n") == 2 and p.rows == 2


def test_switch_by_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(PROGRESS_ENV, "never")
    assert not progress_enabled(io.StringIO())
    monkeypatch.setenv(PROGRESS_ENV, "always")
    assert progress_enabled(io.StringIO())
    monkeypatch.delenv(PROGRESS_ENV)
    assert not progress_enabled(io.StringIO())  # not a terminal


def test_progress_each_yields_everything_and_ends_with_done() -> None:
    buf = io.StringIO()
    assert list(progress_each("b", [3, 1, 2], stream=buf, enabled=True)) == [3, 1, 2]
    last = buf.getvalue().strip().splitlines()[-1]
    assert last.startswith("b: 3 / 3 items, done")


def test_tracking_progress_callback_sees_time_and_changes_nothing() -> None:
    track = Track.flat(300.0 / 3.6)
    runs = [RunModel(THSR_700T, track, 0.0, d) for d in (1500.0, 2500.0)]
    refs = [ReferenceCurve(r) for r in runs]
    seen: list[tuple[float, int]] = []
    a = simulate_tracking(runs, refs, FuzzyController(), dt_s=0.2)
    b = simulate_tracking(runs, refs, FuzzyController(), dt_s=0.2,
                          on_time=lambda t, n: seen.append((t, n)))
    assert [r.trip_time_s for r in a] == [r.trip_time_s for r in b]
    assert [r.energy_j for r in a] == [r.energy_j for r in b]
    t = np.array([s[0] for s in seen])
    running = [s[1] for s in seen]
    assert np.all(np.diff(t) > 0) and running[0] == 2 and running[-1] == 0
    assert sorted(running, reverse=True) == running
