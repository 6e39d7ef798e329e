"""SUMO side by side (metro_atc.bench.sumo): the scenario writer without SUMO, a smoke run with.

The writer is checked against our own static line description (timetable, geometry, rolling
stock) for three lines: the Blue line, the toy line and a generated one (plus THSR's
rolling stock). The SUMO runs only happen where SUMO is found ($SUMO_HOME, PATH or the
``sumo`` package); otherwise they are skipped.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from metro_atc.bench import sumo as bs
from metro_atc.core.line.geometry import build_geometry
from metro_atc.core.line.rolling_stock import train_params_for
from metro_atc.core.line.scenario import Scenario, load_scenario
from metro_atc.core.line.service import B_DRIVE_FRACTION, timetable_for
from metro_atc.core.linegen import load_generated

SCENARIOS = {"taipei_blue": lambda: load_scenario("taipei_blue"),
             "mini": lambda: load_scenario("mini"),
             "thsr": lambda: load_scenario("thsr"),
             "gen_0007": lambda: load_generated(7)}


@pytest.fixture(scope="module", params=sorted(SCENARIOS))
def written(request: Any, tmp_path_factory: Any) -> tuple[Scenario, bs.SumoScenario]:
    """One scenario written to a fresh directory."""
    scn = SCENARIOS[request.param]()
    return scn, bs.write_sumo_scenario(scn, tmp_path_factory.mktemp(request.param))


def _root(sc: bs.SumoScenario, key: str) -> ET.Element:
    return ET.parse(sc.files[key]).getroot()


def _chainage_of_nodes(sc: bs.SumoScenario, scn: Scenario) -> dict[str, float]:
    """Node id -> chainage [m] (x in the file is chainage - start of the first edge)."""
    x0 = float(scn.line.stations[0].position_m) - train_params_for(scn).length_m \
        - bs.APPROACH_M
    return {n.get("id", ""): float(n.get("x", "nan")) + x0
            for n in _root(sc, "nodes").iter("node")}


def test_every_file_parses_and_names_what_exists(written: Any) -> None:
    scn, sc = written
    assert set(sc.files) == {"nodes", "edges", "stops", "routes", "config"}
    for path in sc.files.values():
        assert path.is_file() and path.parent == sc.directory
        ET.parse(path)  # raises on malformed XML
    cfg = _root(sc, "config")
    assert cfg.find("input/net-file").get("value") == "line.net.xml"  # built by netconvert
    for key, tag in (("routes", "route-files"), ("stops", "additional-files")):
        assert cfg.find(f"input/{tag}").get("value") == sc.files[key].name
    assert float(cfg.find("time/step-length").get("value")) == scn.sim.control_period_s
    assert cfg.find("time/end") is None  # no duration: the scenario's end
    assert cfg.find("processing/railsignal-moving-block").get("value") == "true"


def test_edges_cover_the_line_with_our_limits(written: Any) -> None:
    scn, sc = written
    p = train_params_for(scn)
    geom = build_geometry(scn, p)
    node_x = _chainage_of_nodes(sc, scn)
    edges = list(_root(sc, "edges").iter("edge"))
    assert len(edges) == len(sc.edges) >= len(scn.line.stations)
    total = 0.0
    prev_to = None
    for e in edges:
        a, b = node_x[e.get("from", "")], node_x[e.get("to", "")]
        length = float(e.get("length", "nan"))
        assert length > 0.0 and length == pytest.approx(b - a, abs=2e-3)
        assert prev_to is None or e.get("from") == prev_to  # one chain, in order
        prev_to = e.get("to")
        assert e.get("allow") == "rail" and e.get("numLanes") == "1"
        mid = 0.5 * (a + b)
        assert float(e.get("speed", "nan")) == pytest.approx(
            float(geom.static_limit[geom.cell(mid)]), abs=1e-3)
        total += length
    first, last = float(geom.station_positions_m[0]), float(geom.station_positions_m[-1])
    x_start = first - p.length_m - bs.APPROACH_M
    assert total == pytest.approx(last + scn.line.tail_track_m - x_start, abs=0.05)
    assert total == pytest.approx(sc.line_length_m, abs=0.05)


def test_train_stops_end_at_our_stop_points_in_order(written: Any) -> None:
    scn, sc = written
    node_x = _chainage_of_nodes(sc, scn)
    start = {e.get("id"): node_x[e.get("from", "")] for e in _root(sc, "edges").iter("edge")}
    stops = list(_root(sc, "stops").iter("trainStop"))
    want = [s.position_m for s in scn.line.stations]
    assert len(stops) == len(want)
    got = [start[s.get("lane", "").rsplit("_", 1)[0]] + float(s.get("endPos", "nan"))
           for s in stops]
    np.testing.assert_allclose(got, want, atol=2e-3)
    assert all(float(s.get("startPos", "nan")) < float(s.get("endPos", "nan")) for s in stops)
    names = [f"{st.code} {st.name}".strip() for st in scn.line.stations]
    assert [s.get("name") for s in stops] == names


def test_one_vehicle_per_timetable_train_with_our_times(written: Any) -> None:
    scn, sc = written
    tt = timetable_for(scn)
    rou = _root(sc, "routes")
    vehs = list(rou.iter("vehicle"))
    assert sorted(v.get("id") for v in vehs) == sorted(tt.train_ids)
    departs = [float(v.get("depart", "nan")) for v in vehs]
    assert departs == sorted(departs)  # SUMO wants route files sorted by departure
    route = rou.find("route").get("edges", "").split()
    assert route == [e.get("id") for e in _root(sc, "edges").iter("edge")]
    first_len = float(next(_root(sc, "edges").iter("edge")).get("length", "nan"))
    stop_ids = [s.get("id") for s in _root(sc, "stops").iter("trainStop")]
    for v in vehs:
        i = tt.train_ids.index(v.get("id", ""))
        # enters at its scheduled platform entry, front at the first stop point, standing
        assert float(v.get("depart", "nan")) == pytest.approx(tt.arrival_s[i, 0], abs=1e-3)
        assert float(v.get("departPos", "nan")) == pytest.approx(first_len)
        assert v.get("departSpeed") == "0" and v.get("route") == "line"
        st = list(v.iter("stop"))
        assert [s.get("trainStop") for s in st] == stop_ids
        np.testing.assert_allclose([float(s.get("until", "nan")) for s in st],
                                   tt.departure_s[i], atol=1e-3)
        np.testing.assert_allclose([float(s.get("duration", "nan")) for s in st],
                                   tt.dwell_s[i], atol=1e-3)
    assert tt.departure_s[0, 0] < tt.departure_s[-1, 0]  # the times really differ


def test_vtype_is_our_rolling_stock(written: Any) -> None:
    scn, sc = written
    p = train_params_for(scn)
    vt = _root(sc, "routes").find("vType")
    assert vt.get("vClass") == "rail" and vt.get("sigma") == "0"
    assert float(vt.get("length", "nan")) == pytest.approx(p.length_m, abs=1e-3)
    assert float(vt.get("maxSpeed", "nan")) == pytest.approx(p.max_speed_mps, abs=1e-3)
    assert float(vt.get("accel", "nan")) == pytest.approx(p.a1_mps2, abs=1e-3)
    assert float(vt.get("decel", "nan")) == pytest.approx(
        B_DRIVE_FRACTION * p.max_service_brake_mps2, abs=1e-3)
    assert float(vt.get("emergencyDecel", "nan")) == pytest.approx(p.emergency_brake_mps2,
                                                                   abs=1e-3)
    assert float(vt.get("minGap", "nan")) == scn.signalling.safety_margin_m


def test_rolling_stock_differs_between_lines(tmp_path: Path) -> None:
    """The vType follows the scenario (THSR's 700T is not the Taipei 6-car train)."""
    lens = set()
    for name in ("taipei_blue", "thsr"):
        sc = bs.write_sumo_scenario(load_scenario(name), tmp_path / name)
        lens.add(ET.parse(sc.files["routes"]).getroot().find("vType").get("length"))
    assert len(lens) == 2


def test_duration_sets_the_end(tmp_path: Path) -> None:
    sc = bs.write_sumo_scenario(load_scenario("mini"), tmp_path, duration_s=60.0)
    assert ET.parse(sc.files["config"]).getroot().find("time/end").get("value") == "60"
    assert sc.end_s == 60.0


def test_sumo_duration_statistics_parse() -> None:
    """SUMO prints ``Duration: 1.77s`` or ``Duration: 123ms`` under Performance."""
    for text, want in (("Performance:\n Duration: 1.77s\n Real time factor: 3", "1.77 s"),
                       ("Performance:\n Duration: 123ms\n", "123 ms")):
        m = bs._DURATION_RE.search(text)
        assert m is not None and f"{m.group(1)} {m.group(2)}" == want


def test_missing_sumo_is_one_clear_line(monkeypatch: Any, tmp_path: Path,
                                        capsys: Any) -> None:
    monkeypatch.delenv("SUMO_HOME", raising=False)
    monkeypatch.setenv("PATH", str(tmp_path))
    monkeypatch.setattr(bs, "_home_from_package", lambda: None)
    assert bs.find_sumo() is None
    assert bs.main(["--no-graph", "--pairs", "1"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and err.startswith("bench sumo: SUMO not found")
    assert "eclipse-sumo" in err


def test_traci_errors_become_one_line_runtime_errors() -> None:
    """A failed TraCI connection ends the bench with its message, not a traceback."""
    import types

    class Fatal(Exception):
        pass

    class Plain(Exception):
        pass

    fake = types.SimpleNamespace(exceptions=types.SimpleNamespace(FatalTraCIError=Fatal,
                                                                  TraCIException=Plain))
    for exc in (Fatal("connection closed by SUMO"), Plain("unknown vehicle")):
        with pytest.raises(RuntimeError, match=f"TraCI: {type(exc).__name__}: {exc}"):
            with bs._traci_errors(fake):
                raise exc
    with pytest.raises(KeyError):  # anything else is a bug: not hidden
        with bs._traci_errors(fake):
            raise KeyError("x")


def test_bad_arguments_are_refused() -> None:
    with pytest.raises(SystemExit):
        bs.main(["--pairs", "0"])


# --------------------------------------------------------------------------- with SUMO

SUMO = bs.find_sumo()
needs_sumo = pytest.mark.skipif(SUMO is None, reason=bs.NOT_FOUND)


@needs_sumo
def test_sumo_smoke_60_s(tmp_path: Path) -> None:
    """60 simulated seconds standalone and over TraCI (both read modes) on the Blue line."""
    assert SUMO is not None
    sc = bs.write_sumo_scenario(load_scenario("taipei_blue"), tmp_path, duration_s=60.0)
    assert bs.build_network(SUMO, sc).is_file()
    net = ET.parse(tmp_path / "line.net.xml").getroot()
    lanes = {ln.get("id"): float(ln.get("length", "nan")) for ln in net.iter("lane")}
    for e in sc.edges:  # netconvert kept our lengths
        assert lanes[f"{e.id}_0"] == pytest.approx(e.length_m, abs=0.01)
    r = bs.run_standalone(SUMO, sc)
    assert r["sim_time_s"] == 60.0 and r["rtf"] > 0.0
    for reads in ("get", "subscribe"):
        t = bs.run_traci(SUMO, sc, 60.0, reads)
        assert t["steps"] == 240 and t["sim_time_s"] == pytest.approx(60.0)
        assert t["commands"] > 0  # train_01 enters at 35 s: one command per step after
    assert "SUMO" in SUMO.version


@needs_sumo
def test_sumo_runs_the_mini_line_to_the_end(tmp_path: Path) -> None:
    """Every train arrives, serves every stop in order, in a run time close to ours."""
    assert SUMO is not None
    scn = load_scenario("mini")
    sc = bs.write_sumo_scenario(scn, tmp_path)
    bs.build_network(SUMO, sc)
    r = bs.run_standalone(SUMO, sc)
    c = bs.check_sumo_run(sc)
    n_st = len(scn.line.stations)
    assert c["arrived"] == c["trains"] == scn.trains.count
    assert c["trains_all_stops_in_order"] == scn.trains.count
    assert c["stops_served"] == c["stops_expected"] == scn.trains.count * n_st
    tt = timetable_for(scn)
    i = len(tt.train_ids) // 2
    sched = float(tt.arrival_s[i, -1] - tt.departure_s[i, 0])
    assert c["middle_train_run_time_s"] is not None
    # SUMO drives flat out (no margin): faster than the schedule, within its 7 % margin +
    # what SUMO models less (traction curve, jerk); not an order of magnitude off
    assert 0.8 * sched < c["middle_train_run_time_s"] < 1.05 * sched
    assert math.isfinite(r["sim_time_s"]) and r["sim_time_s"] > tt.arrival_s[-1, -1]


@needs_sumo
def test_bench_end_to_end_60_s(capsys: Any, tmp_path: Path) -> None:
    """The command: one pair over 60 simulated s (no graph), one JSON, then the table."""
    import json
    assert bs.main(["--json", "--pairs", "1", "--duration", "60", "--no-graph",
                    "--out", str(tmp_path)]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["sim_time_s"]["sumo"] == 60.0 and res["sim_time_s"]["core"] == 60.0
    assert res["trains"] == 30 and res["pairs"] == len(res["runs"]) == 1
    for key in ("sumo_standalone", "sumo_traci", "core_with_sensors"):
        assert res["median_rtf"][key] > 0.0 and res["median_rtf_cpu"][key] > 0.0
    assert res["median_rtf"]["graph"] is None
    run = res["runs"][0]
    assert res["ratios_ours_over_sumo"]["core_vs_sumo"] == pytest.approx(
        run["core"]["rtf"] / run["sumo"]["rtf"], rel=1e-2)
    assert bs.main(["--pairs", "1", "--duration", "60", "--no-graph"]) == 0
    out = capsys.readouterr().out
    assert "SUMO standalone" in out and "our core with sensors" in out
