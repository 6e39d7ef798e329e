"""TTOBench import: field mapping, refusals, round trip, a core run; rolling stock from data."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from metro_atc.cli import main as cli_main
from metro_atc.core.plant.driver import simple_driver
from metro_atc.core.plant.line import PRESETS, LineSim, train_params_for
from metro_atc.core.line.scenario import SCENARIO_NAMES, load_scenario, parse_scenario
from metro_atc.core.line.vehicle import (TAIPEI_MRT_6CAR, max_traction_force,
                                         train_params_from_data)
from metro_atc.ttobench.importer import (TtobenchError, data_dir, export_ttobench,
                                         import_ttobench, load_json)

TRACK, TRAIN = "CN_Songjiazhuang_Yizhuang", "CN_Beijing_Subway"
ASSUMED_LENGTH_M = 141.0  # not in the TTOBench train (the bench states the same)


@pytest.fixture(scope="module")
def imported() -> dict:
    """The vendored metro instance imported as a scenario mapping."""
    return import_ttobench(TRACK, TRAIN, length_m=ASSUMED_LENGTH_M).scenario


def test_vendored_files_and_licence() -> None:
    """The vendored data keep the BSD licence text and a SOURCE note."""
    d = data_dir()
    assert "BSD 2-Clause" in (d / "LICENSE").read_text()
    assert "nuorail/ttobench" in (d / "SOURCE.md").read_text()


def test_train_mapping_units(imported: dict) -> None:
    """Every Beijing-train number lands in SI in TrainParams (kN, kW, km/h, %)."""
    scn = parse_scenario(yaml.safe_dump(imported), "t.yaml")
    p = train_params_for(scn)
    m = 278000.0
    assert p.mass_kg == m and p.rotary_allowance == 0.0
    assert max_traction_force(p, 5.0) == pytest.approx(310e3)        # constant force
    assert max_traction_force(p, 20.0) == pytest.approx(3100e3 / 20.0)  # constant power
    assert p.davis_a_n == pytest.approx(3947.6)
    assert p.davis_b_n_per_mps == 0.0
    assert p.davis_c_n_per_mps2 == pytest.approx(0.0022294e3 * 3.6 ** 2)
    assert p.max_service_brake_mps2 == pytest.approx(260e3 / m)
    assert p.max_regen_power_w == pytest.approx(4333e3)
    assert p.max_speed_mps == pytest.approx(80 / 3.6)
    assert p.traction_efficiency == pytest.approx(0.70)
    assert p.regen_efficiency == pytest.approx(0.80)


def test_round_trip(imported: dict) -> None:
    """Import -> scenario -> export gives back the TTOBench numbers."""
    _, t_raw = load_json(TRACK)
    _, r_raw = load_json(TRAIN)
    scn = parse_scenario(yaml.safe_dump(imported), "t.yaml")
    track, train = export_ttobench(scn)
    assert track["stops"]["values"] == pytest.approx(t_raw["stops"]["values"])
    assert np.allclose(track["speed limits"]["values"], t_raw["speed limits"]["values"])
    assert np.allclose(track["gradients"]["values"], t_raw["gradients"]["values"])
    for key, item in r_raw.items():
        if key == "metadata":
            continue
        assert train[key]["unit"] == item["unit"], key
        assert train[key]["value"] == pytest.approx(item["value"], abs=1e-9), key


def _write(tmp: Path, name: str, obj: dict) -> str:
    path = tmp / name
    path.write_text(json.dumps(obj))
    return str(path)


def test_refusals_are_one_line(tmp_path: Path) -> None:
    """Unrepresentable, unknown and badly-united fields are refused with one line."""
    _, t_raw = load_json(TRACK)
    _, r_raw = load_json(TRAIN)
    tun = copy.deepcopy(t_raw)
    tun["tunnels"] = {"units": {}, "values": [[100.0, 50.0, 40.0]]}
    with pytest.raises(TtobenchError, match="'tunnels' cannot be represented") as exc:
        import_ttobench(_write(tmp_path, "t.json", tun), TRAIN, length_m=ASSUMED_LENGTH_M)
    assert "\n" not in str(exc.value)
    out = import_ttobench(_write(tmp_path, "t.json", tun), TRAIN, drop=["tunnels"],
                          length_m=ASSUMED_LENGTH_M)
    assert any("dropped on request" in n for n in out.notes)
    bad = copy.deepcopy(r_raw)
    bad["max traction force"]["unit"] = "lbf"
    with pytest.raises(TtobenchError, match="max traction force: unit 'lbf'"):
        import_ttobench(TRACK, _write(tmp_path, "r.json", bad))
    unk = copy.deepcopy(r_raw)
    unk["flux capacitor"] = 1
    with pytest.raises(TtobenchError, match="unknown field 'flux capacitor'"):
        import_ttobench(TRACK, _write(tmp_path, "r.json", unk))
    neg = copy.deepcopy(t_raw)
    neg["stops"]["values"] = [0.0, 500.0, 400.0]
    with pytest.raises(TtobenchError, match="strictly increasing"):
        import_ttobench(_write(tmp_path, "t.json", neg), TRAIN, length_m=ASSUMED_LENGTH_M)
    assert cli_main(["import", "ttobench", "--track", "nope.json", "--train", TRAIN,
                     "--out", str(tmp_path / "x.yaml")]) == 2


def test_journey_selects_stations(tmp_path: Path) -> None:
    """Stopping points choose the stations; the longest dwell sets the minimum dwell."""
    journey = {"metadata": {"id": "j"}, "timing points": {"units": {}, "values": [
        [0.0, 0, 0, 0, 0], [3906.0, 200, 260, 0, 0], [3906.0, 240, 260, 0, 0],
        [8254.0, 500, 560, 0, 0]]}}
    out = import_ttobench(TRACK, TRAIN, _write(tmp_path, "j.json", journey),
                          length_m=ASSUMED_LENGTH_M)
    pos = [s["position_m"] for s in out.scenario["line"]["stations"]]
    assert pos == [0.0, 3906.0, 8254.0]
    assert out.scenario["passengers"]["min_dwell_s"] == 40.0
    journey["timing points"]["values"][1][3] = 10
    with pytest.raises(TtobenchError, match="passing points"):
        import_ttobench(TRACK, TRAIN, _write(tmp_path, "j.json", journey),
                        length_m=ASSUMED_LENGTH_M)


def test_cli_and_short_core_run(tmp_path: Path) -> None:
    """The CLI writes a loadable scenario; a cut of it runs in the plant: every stop, no ATP
    violation (the whole line in the node graph is run by hand, see the README)."""
    out = tmp_path / "yz.yaml"
    assert cli_main(["import", "ttobench", "--track", TRACK, "--train", TRAIN,
                     "--out", str(out), "--trains", "2", "--length-m", "141"]) == 0
    scn_map = yaml.safe_load(out.read_text())
    assert scn_map["trains"]["count"] == 2 and "timetable: not in the TTOBench" \
        in out.read_text()
    n = 4   # first four stations, to keep the test short
    scn_map["line"]["stations"] = scn_map["line"]["stations"][:n]
    scn_map["timetable"]["periods"][0]["boarding_pph"] = [0.0] * n
    scn_map["passengers"]["alight_fraction"] = [0.0] * (n - 1) + [1.0]
    end = scn_map["line"]["stations"][-1]["position_m"] + 300.0  # the loader refuses data
    for key in ("speed_limits", "gradients"):                      # beyond the buffer stop
        scn_map["line"][key] = [e for e in scn_map["line"][key] if e["start_m"] < end]
    scn_map["line"]["curves"] = [c for c in scn_map["line"].get("curves", [])
                                 if c["end_m"] <= end]
    sim = LineSim(parse_scenario(yaml.safe_dump(scn_map), "cut.yaml"), seed=0)
    while not sim.done:
        sim.step(simple_driver(sim))
    k = sim.kpis()
    assert k["completed_trains"] == 2 and k["skipped_stops"] == 0
    assert k["atp_violations"] == 0
    for i in range(2):
        served = {e.station_idx for e in sim.event_log()
                  if e.train_idx == i and e.kind == "arrival"}
        assert served == set(range(n))


def test_existing_scenarios_keep_their_trains() -> None:
    """Presets and every shipped scenario give bit-identical TrainParams (goldens don't move)."""
    for name in SCENARIO_NAMES:
        scn = load_scenario(name)
        assert train_params_for(scn) == PRESETS[scn.trains.preset]
    assert train_params_from_data(TAIPEI_MRT_6CAR, {}) is TAIPEI_MRT_6CAR


def test_mass_override_keeps_force_and_scales_resistance() -> None:
    """A heavier train: same tractive force, Davis A and B scale with mass, C is kept."""
    p0 = TAIPEI_MRT_6CAR
    p = train_params_from_data(p0, {"mass_kg": 2 * p0.mass_kg})
    assert max_traction_force(p, 3.0) == pytest.approx(max_traction_force(p0, 3.0))
    assert p.davis_a_n == pytest.approx(2 * p0.davis_a_n)
    assert p.davis_b_n_per_mps == pytest.approx(2 * p0.davis_b_n_per_mps)
    assert p.davis_c_n_per_mps2 == p0.davis_c_n_per_mps2
    with pytest.raises(ValueError, match="unknown rolling-stock keys"):
        train_params_from_data(p0, {"mass": 1.0})
    with pytest.raises(ValueError, match="expected a finite number"):
        train_params_from_data(p0, {"davis_a_n": float("nan")})
