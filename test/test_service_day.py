"""The day of periods: shipped Taipei Blue table, transitions, fleet, one-line refusals."""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from metro_atc.core.atr.blue_line import default_periods
from metro_atc.core.atr.tsk import dispatch_instants
from metro_atc.core.service.day import (LIN2010A_PEAK_HEADWAY_S, DayError, departures,
                                        headway_at, load_day, parse_day, run_day,
                                        taipei_blue_day, trip_time_s, day_file)

RAW = yaml.safe_load(day_file().read_text())


def _bad(**edits: Any) -> str:
    raw = copy.deepcopy(RAW)
    for key, fn in edits.items():
        fn(raw)
    with pytest.raises(DayError) as ei:
        run_day(parse_day(raw, "t.yaml"))
    msg = str(ei.value)
    assert "\n" not in msg
    return msg


def test_shipped_table_matches_the_atr_periods() -> None:
    """Six periods 06:00-24:00, peak 105 s (Lin 2010a), same table as the ATR line data."""
    plan = taipei_blue_day()
    assert [p.name for p in plan.periods] == ["early", "morning_peak", "midday",
                                              "evening_peak", "evening", "late"]
    assert plan.periods[0].start_s == 6 * 3600.0 and plan.periods[-1].end_s == 24 * 3600.0
    assert min(p.headway_s for p in plan.periods) == LIN2010A_PEAK_HEADWAY_S
    assert all(p.basis for p in plan.periods if p.estimate)
    assert not plan.periods[1].estimate
    # the ATR line data read the same table (one source)
    assert len(default_periods()) == len(plan.periods)
    for ours, atr in zip(plan.periods, default_periods()):
        assert (ours.start_s, ours.end_s, ours.headway_s, ours.flow_up) == \
            (atr.start_s, atr.end_s, atr.headway_s, atr.flow_factor)


def test_crisp_transition_is_the_tsk_dispatch() -> None:
    """W = 0 gives exactly the instants of the TSK model (Lin 2010a, eq. 8)."""
    plan = taipei_blue_day()
    z = departures(plan.periods, plan.periods[0].start_s, 0.0)
    ref = dispatch_instants([p.as_tsk("up") for p in plan.periods])
    assert np.array_equal(z, ref)


def test_smooth_transition_bounds_headway_steps() -> None:
    """With W > 0 headways stay between neighbours and change by bounded steps."""
    plan = taipei_blue_day()
    w = plan.transition_s
    z = departures(plan.periods, plan.periods[0].start_s, w)
    h = np.diff(z)
    hs = [p.headway_s for p in plan.periods]
    assert h.min() >= min(hs) - 1e-9 and h.max() <= max(hs) + 1e-9
    jumps = [abs(b.headway_s - a.headway_s) for a, b in zip(plan.periods, plan.periods[1:])]
    assert np.abs(np.diff(h)).max() <= max(jumps) * max(hs) / w + 1e-9
    crisp = np.abs(np.diff(np.diff(departures(plan.periods, plan.periods[0].start_s, 0.0))))
    assert crisp.max() > np.abs(np.diff(h)).max()  # the crisp rule jumps, ours does not
    assert headway_at(plan.periods, 12 * 3600.0, w) == 300.0
    assert headway_at(plan.periods, 9 * 3600.0, w) == pytest.approx(0.5 * (105.0 + 300.0))


def test_fleet_per_period_and_depot() -> None:
    """Peak needs ceil(cycle / 105 s); the circulation meets it; trains return to depots."""
    plan = taipei_blue_day()
    circ, rep = run_day(plan)
    peak = rep[1]
    assert peak.closed_form_fleet == int(np.ceil(peak.cycle_s / 105.0))
    # the closed form assumes one headway for ever; the trains still out from the headway
    # blend into the next period (600 s window) can need one more at the peak
    assert peak.closed_form_fleet <= peak.peak_in_service <= peak.closed_form_fleet + 1
    assert circ.fleet == max(r.peak_in_service for r in rep) <= plan.fleet
    assert sum(circ.pull_outs.values()) == sum(circ.pull_ins.values())
    assert rep[2].pull_ins > 0  # withdrawal after the morning peak
    assert rep[3].pull_outs > 0  # build-up for the evening peak
    need = {t.station: t.min_turnback_s + 210.0 for t in plan.termini}
    assert {t.station: t.buffer_s for t in plan.termini} == {"BL01": 210.0, "BL23": 210.0}
    for term, lay in circ.layovers():
        assert lay >= need[term] - 1e-9  # minimum turnback + Lin 2010a's 210 s buffer
    t = trip_time_s(plan.line, 105.0, 1.0)
    assert 1800.0 < t < 3600.0


def test_refusals_name_the_period_and_the_need() -> None:
    """Fleet too small, turnback too short, a missing or mid-line depot: one line each."""
    msg = _bad(fleet=lambda r: r.__setitem__("fleet", 30))
    fleet = run_day(taipei_blue_day())[0].fleet
    assert "period morning_peak" in msg and f"needs {fleet} trains" in msg \
        and "fleet is 30" in msg
    msg = _bad(t=lambda r: r["termini"][1].__setitem__("min_turnback_s", 60))
    assert "BL23 turnback 60 s is shorter" in msg and "needs" in msg
    msg = _bad(d=lambda r: r["termini"][0].__setitem__("depot_station", "BL99"))
    assert "BL99" in msg and "not a station" in msg
    msg = _bad(d=lambda r: r["termini"][0].__setitem__("depot_station", "BL05"))
    assert "not at terminus BL01" in msg
    msg = _bad(d=lambda r: r["termini"][1].update(depot_station=None))
    assert "period early" in msg and "BL23 has no depot connection" in msg
    msg = _bad(p=lambda r: r["periods"][2].__setitem__("start_h", 9.5))
    assert "midday" in msg and "09:30" in msg
    msg = _bad(p=lambda r: r["periods"][1].__setitem__("headway_s", float("nan")))
    assert "periods[1].headway_s" in msg
    msg = _bad(p=lambda r: r["periods"][0].__setitem__("colour", "red"))
    assert "unknown key 'colour'" in msg
    msg = _bad(f=lambda r: r.__setitem__("fleet", 50.5))
    assert "fleet: expected an integer" in msg
    msg = _bad(p=lambda r: r["periods"][3].__setitem__("name", ["x"]))
    assert "periods[3].name" in msg
    msg = _bad(t=lambda r: r["termini"][1].__setitem__("layout", "loop"))
    assert "termini[1].layout" in msg and "tail_track, scissors" in msg


def test_load_errors_are_one_line(tmp_path: Path) -> None:
    """Missing files and non-mapping YAML give a one-line DayError."""
    with pytest.raises(DayError):
        load_day(tmp_path / "nope.yaml")
    f = tmp_path / "x.yaml"
    f.write_text("- 1\n- 2\n")
    with pytest.raises(DayError, match="expected a mapping"):
        load_day(f)
