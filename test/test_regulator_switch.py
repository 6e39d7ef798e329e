"""A dispatcher's regulator switch: validated at the desk, deterministic in the ATS."""

from __future__ import annotations

import math

from metro_atc.core.atr.dispatch import make_dispatcher
from metro_atc.core.atr.switch import RegulatorSwitch
from metro_atc.core.dispatcher_commands import KIND_REGULATOR, LEAD_S, Command, Dispatcher
from metro_atc.core.line.scenario import load_scenario
from metro_atc.core.plant.driver import simple_driver
from metro_atc.core.plant.line import LineSim


def _events() -> list[tuple[str, int, str, float]]:
    scn = load_scenario("mini")
    sim = LineSim(scn, seed=3, trace_period_s=0.0)
    while not sim.done:
        sim.step(simple_driver(sim))
    return [(sim.train_ids[e.train_idx], e.station_idx, e.kind, e.t_s)
            for e in sim.event_log()]


def _build(name: str, weights: str = "") -> object:
    return make_dispatcher(load_scenario("mini"), name, weights)


def test_desk_refuses_an_unknown_regulator_or_bad_weights_and_records_the_time() -> None:
    sim = LineSim(load_scenario("mini"), seed=3, trace_period_s=0.0)
    d = Dispatcher(sim)
    ok, why, _ = d.submit(Command(KIND_REGULATOR, regulator="pid"))
    assert not ok and why.startswith("regulator 'pid': expected one of none, lqr")
    ok, why, _ = d.submit(Command(KIND_REGULATOR, regulator="dhp",
                                  weights_file="/nonexistent/dhp.pt"))
    assert not ok and why.startswith("regulator 'dhp'") and "\n" not in why, why
    assert d.refused == {"invalid": 2} and not d.queue
    for _ in range(40):
        sim.step(simple_driver(sim))
    assert d.submit(Command(KIND_REGULATOR, regulator="lqr", from_s=1e9))[0]
    a = d.apply_due(sim.step_count)[0]
    assert a.command.from_s == sim.t + LEAD_S == 10.0 + LEAD_S
    assert a.csv_row(sim.station_names, -1)[3:] == [
        "regulator", "10.00", "", "", "", "", "", "", f"step 40; lqr from {10 + LEAD_S:.2f} s"]


def test_switch_decides_from_its_time_with_the_new_regulators_full_state() -> None:
    """Before from_s the decisions are the timetable's ('none'); from it on they are those
    of an LQR that regulated from the start (it was given every earlier event)."""
    ev = _events()
    arrivals = [e for e in ev if e[2] == "arrival" and 0 < e[1] < 3]
    t_sw = arrivals[1][3] + 1.0  # after the second intermediate arrival
    sw = RegulatorSwitch(_build("none"), "none", _build)  # type: ignore[arg-type]
    assert sw.announce(1, t_sw, "lqr") and not sw.announce(1, t_sw, "lqr")
    none, lqr = _build("none"), _build("lqr")
    got, exp, tt = [], [], []
    for e in ev:
        got.append(sw.on_event(*e))
        a, b = none.on_event(*e), lqr.on_event(*e)  # type: ignore[attr-defined]
        exp.append(a if e[3] < t_sw else b)
        tt.append(a)
    assert got == exp and sw.regulator == "lqr" and sw.switched == [(t_sw, "lqr")]
    assert sw.late == 0 and not sw.failed
    # the switch changed decisions (the LQR's are not the timetable's here)
    after = [(g, a) for g, a, e in zip(got, tt, ev) if g is not None and e[3] >= t_sw]
    assert after and any(g != a for g, a in after)
    assert all(not math.isnan(g.departure_s) for g, _ in after)


def test_a_late_or_failing_switch_is_counted() -> None:
    ev = _events()
    sw = RegulatorSwitch(_build("none"), "none", _build)  # type: ignore[arg-type]
    for e in ev[:6]:
        sw.on_event(*e)
    assert sw.announce(1, ev[2][3], "lqr") and sw.late == 1
    sw.announce(2, ev[5][3] + 1.0, "dhp", "/nonexistent/dhp.pt")
    for e in ev[6:]:
        sw.on_event(*e)
    assert sw.regulator == "lqr" and len(sw.failed) == 1 and "dhp" in sw.failed[0]
