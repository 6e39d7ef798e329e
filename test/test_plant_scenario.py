"""Scenario schema: embedded files, facts from the seeds, one-line validation errors."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable

import numpy as np
import pytest
import yaml

from metro_atc.core.line.scenario import (SCENARIO_NAMES, ScenarioError, load_scenario,
                                          parse_scenario, schema_keys)

SCN_DIR = Path(__file__).resolve().parent.parent / "metro_atc" / "scenarios"


def _mini() -> dict[str, Any]:
    return dict(yaml.safe_load((SCN_DIR / "mini.yaml").read_text()))


def test_embedded_scenarios_load() -> None:
    """All shipped scenarios validate; the required ones exist."""
    assert {"taipei_blue", "taipei_blue_delay", "thsr", "mini"} <= set(SCENARIO_NAMES)
    for name in SCENARIO_NAMES:
        scn = load_scenario(name)
        assert scn.name == name
        assert scn.sources, f"{name}: must say where its numbers come from"


def test_load_by_path_equals_by_name() -> None:
    """A path to a YAML file loads the same scenario as its embedded name."""
    assert load_scenario(SCN_DIR / "mini.yaml").line == load_scenario("mini").line


def test_taipei_blue_facts() -> None:
    """Lin 2010a: 23 real stations BL01..BL23, ~1.28 km spacing, 80 km/h, peak."""
    scn = load_scenario("taipei_blue")
    st = scn.line.stations
    assert len(st) == 23
    assert (st[0].code, st[0].name) == ("BL01", "Dingpu")
    assert (st[-1].code, st[-1].name) == ("BL23", "Nangang Exhibition Center")
    assert [s.code for s in st] == [f"BL{i:02d}" for i in range(1, 24)]
    spacing = np.diff([s.position_m for s in st]).mean()
    assert 1200.0 <= spacing <= 1350.0
    assert scn.line.line_speed_kmh == 80.0
    assert scn.trains.count >= 25 and scn.trains.preset == "taipei_mrt_6car"
    heads = [p.headway_s for p in scn.timetable.periods]
    assert min(heads) == 105.0 and max(heads) <= 135.0
    assert scn.sim.duration_s <= 3 * 3600.0


def test_taipei_blue_delay_incident() -> None:
    """Seed 000 Exp. 2: 180 s initial delay at the first station."""
    scn = load_scenario("taipei_blue_delay")
    holds = [i for i in scn.incidents if i.kind == "hold"]
    assert len(holds) == 1
    h = holds[0]
    assert (h.train, h.station, h.duration_s) == ("train_01", "BL01", 180.0)


def test_thsr_distances() -> None:
    """Seed 004 Table 3 inter-station distances and the 700T preset."""
    scn = load_scenario("thsr")
    d = np.diff([s.position_m for s in scn.line.stations]) / 1000.0
    assert np.allclose(d, [7.3, 34.9, 29.9, 93.6, 85.8, 62.3, 31.4])
    assert scn.trains.preset == "thsr_700t" and scn.line.line_speed_kmh == 300.0


def _set(path: str, value: Any) -> Callable[[dict[str, Any]], None]:
    def f(d: dict[str, Any]) -> None:
        keys = path.split(".")
        cur: Any = d
        for k in keys[:-1]:
            cur = cur[int(k)] if isinstance(cur, list) else cur.setdefault(k, {})
        if isinstance(cur, list):
            cur[int(keys[-1])] = value
        else:
            cur[keys[-1]] = value
    return f


def _delete(path: str) -> Callable[[dict[str, Any]], None]:
    def f(d: dict[str, Any]) -> None:
        keys = path.split(".")
        cur: Any = d
        for k in keys[:-1]:
            cur = cur[k]
        del cur[keys[-1]]
    return f


@pytest.mark.parametrize("mutate, expected", [
    (_set("trains.count", "x"), "trains.count: expected int in [1, 60], got 'x'"),
    (_set("trains.count", 61), "trains.count: expected int in [1, 60], got 61"),
    (_set("trains.count", True), "trains.count: expected int in [1, 60], got True"),
    (_set("bogus", 1), "bogus: unknown key (known: name,"),
    (_set("line.foo", 1), "line.foo: unknown key"),
    (_delete("trains.count"), "trains.count: missing required key (int)"),
    (_set("sim.control_period_s", 0.0), "sim.control_period_s: expected float in [0.01, 5]"),
    (_set("sim.control_period_s", float("nan")), "sim.control_period_s: expected float"),
    (_set("signalling.mode", "cbtc"), "signalling.mode: expected one of 'moving_block', "
                                      "'fixed_block', got 'cbtc'"),
    (_set("line.stations.2.position_m", 100.0),
     "line.stations[2].position_m: expected > stations[1].position_m + 10"),
    (_set("line.stations.1.name", 5), "line.stations[1].name: expected str, got 5"),
    (_set("timetable.periods.0.boarding_pph", [1.0, 2.0]),
     "timetable.periods[0].boarding_pph: expected list of 4 floats"),
    (_set("passengers.alight_fraction", [0.0, 0.2, 1.5, 1.0]),
     "passengers.alight_fraction[2]: expected float in [0, 1], got 1.5"),
    (_set("incidents", [{"kind": "hold", "train": "train_09", "station": "MN01",
                         "duration_s": 10}]),
     "incidents[0].train: expected a train id train_01..train_02, got 'train_09'"),
    (_set("incidents", [{"kind": "hold", "train": "train_01", "station": "Nowhere",
                         "duration_s": 10}]),
     "incidents[0].station: expected a station code or name, got 'Nowhere'"),
    (_set("faults", [{"kind": "pad_mu", "train": "train_01", "axle": 7}]),
     "faults[0].axle: expected int in [0, 4], got 7"),
    (_set("signalling.response_time_s", 0.1),
     "signalling.response_time_s: expected >= sim.control_period_s"),
    (_set("line.speed_limits", "fast"), "line.speed_limits: expected list of mapping"),
])
def test_validation_errors(mutate: Callable[[dict[str, Any]], None], expected: str) -> None:
    """Each bad value yields one line naming the key path and the expected type/range."""
    d = _mini()
    mutate(d)
    with pytest.raises(ScenarioError) as ei:
        parse_scenario(yaml.safe_dump(d), "t.yaml")
    msg = str(ei.value)
    assert "\n" not in msg
    assert msg.startswith("scenario t.yaml: ")
    assert expected in msg, msg


def test_unknown_name_lists_known() -> None:
    """An unknown scenario name names the embedded ones."""
    with pytest.raises(ScenarioError) as ei:
        load_scenario("atlantis")
    assert "unknown scenario 'atlantis'" in str(ei.value)
    for n in SCENARIO_NAMES:
        assert n in str(ei.value)


def test_missing_file_and_malformed_yaml(tmp_path: Path) -> None:
    """Missing files and YAML syntax errors are one-line ScenarioErrors."""
    with pytest.raises(ScenarioError, match="file not found"):
        load_scenario(tmp_path / "nope.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: [unclosed\n")
    with pytest.raises(ScenarioError) as ei:
        load_scenario(bad)
    assert "malformed YAML" in str(ei.value) and "\n" not in str(ei.value)
    top = tmp_path / "top.yaml"
    top.write_text("- 1\n- 2\n")
    with pytest.raises(ScenarioError, match="expected a mapping at the top level"):
        load_scenario(top)


def test_schema_md_documents_every_key() -> None:
    """SCHEMA.md lists every key path of the schema (and no stale ones)."""
    text = (SCN_DIR / "SCHEMA.md").read_text()
    paths = {k[0] for k in schema_keys()}
    for p in paths:
        assert f"| `{p}` |" in text, f"SCHEMA.md misses {p}"
    import re
    documented = set(re.findall(r"^\| `([^`]+)` \|", text, flags=re.M))
    assert documented == paths
