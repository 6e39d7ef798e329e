"""Rolling stock that means what it says: masses, refusals at load time, TTOBench, ``show``.

Known answers: a 45 t empty train with 200 persons of 65 kg weighs 58 t in the plant; the
TTOBench Beijing train weighs its 278 t; track data beyond the buffer stop are refused.
"""

from __future__ import annotations

import copy
import json
from pathlib import Path
from typing import Any, Callable

import numpy as np
import pytest
import yaml

from metro_atc.cli import main as cli_main
from metro_atc.core.line.rolling_stock import PRESETS, train_params_for
from metro_atc.core.line.scenario import ScenarioError, parse_scenario
from metro_atc.core.line.vehicle import TrainParams
from metro_atc.core.plant.line import LineSim
from metro_atc.ttobench.importer import TtobenchError, import_ttobench

MINI = Path(__file__).resolve().parents[1] / "metro_atc" / "scenarios" / "mini.yaml"
LIGHT = {"tare_mass_kg": 45_000.0, "mass_load_pax": 0.0, "length_m": 30.0,
         "capacity_pax": 200.0, "stock": {"cars": 3}}


def _mini(edit: Callable[[dict[str, Any]], None]) -> dict[str, Any]:
    d = yaml.safe_load(MINI.read_text())
    edit(d)
    return d


def _parse(d: dict[str, Any]):  # type: ignore[no-untyped-def]
    return parse_scenario(yaml.safe_dump(d), "x.yaml")


def _refused(edit: Callable[[dict[str, Any]], None], key: str) -> str:
    with pytest.raises(ScenarioError) as exc:
        _parse(_mini(edit))
    msg = str(exc.value)
    assert "\n" not in msg and f"x.yaml: {key}: " in msg, msg
    return msg


# ----------------------------------------------------------------------------- masses


def test_preset_figures_a_short_train_cannot_hold_are_refused() -> None:
    """A 30 m train left with the 6-car preset's cars and 1 900 persons: refused, named."""
    msg = _refused(lambda d: d["trains"].update(tare_mass_kg=45_000.0, mass_load_pax=0.0,
                                                length_m=30.0), "trains.stock.cars")
    assert "5 m per car" in msg
    msg = _refused(lambda d: d["trains"].update(tare_mass_kg=45_000.0, mass_load_pax=0.0,
                                                length_m=30.0, stock={"cars": 3}),
                   "trains.capacity_pax")
    assert "63.3 per metre" in msg
    _parse(_mini(lambda d: d["trains"].update(LIGHT)))  # the same train, its own figures


def test_light_train_mass_without_its_load_is_refused() -> None:
    """45 t with the preset's 1 000 persons was an empty train of -20 t: now refused."""
    _refused(lambda d: d["trains"].update(mass_kg=45_000.0, length_m=30.0,
                                          stock={"cars": 3}), "trains.mass_load_pax")
    msg = _refused(lambda d: d["trains"].update(mass_kg=45_000.0, mass_load_pax=1000.0,
                                                length_m=30.0, stock={"cars": 3}),
                   "trains.mass_kg")
    assert "-20000 kg" in msg


def test_light_train_mass_in_the_plant() -> None:
    """Empty 45 t + 200 persons x 65 kg = 58 t, the same given as tare or as mass + load."""
    for light in (LIGHT, {**{k: v for k, v in LIGHT.items() if k != "tare_mass_kg"},
                          "mass_kg": 45_000.0 + 100 * 65.0, "mass_load_pax": 100.0}):
        scn = _parse(_mini(lambda d, x=light: d["trains"].update(copy.deepcopy(x))))
        p = train_params_for(scn)
        assert p.tare_mass_kg == pytest.approx(45_000.0)
        sim = LineSim(scn, seed=0, trace_period_s=0.0)
        assert np.allclose(sim.fleet.mass, 45_000.0 + 200 * 65.0)
        assert p.mass_at_load(0.0) == pytest.approx(45_000.0)
        assert p.mass_at_load(p.capacity_pax) == pytest.approx(45_000.0 + 200 * 65.0)


def test_every_plant_figure_can_be_given() -> None:
    """Figures that were preset-only reach TrainParams from the file."""
    stock = {"emergency_jerk_mps3": 4.0, "regen_fade_speed_kmh": 7.2, "axles_per_car": 4,
             "motored_axle_fraction": 0.25, "wheel_radius_m": 0.42,
             "wheel_inertia_kgm2": 100.0, "brake_radius_m": 0.2, "pad_mu_nominal": 0.3}
    scn = _parse(_mini(lambda d: d["trains"].update(stock=stock, pax_mass_kg=75.0)))
    p = train_params_for(scn)
    assert (p.emergency_jerk_mps3, p.axles_per_car, p.motored_axle_fraction, p.wheel_radius_m,
            p.wheel_inertia_kgm2, p.brake_radius_m, p.pad_mu_nominal, p.pax_mass_kg) == \
        (4.0, 4, 0.25, 0.42, 100.0, 0.2, 0.3, 75.0)
    assert p.regen_fade_speed_mps == pytest.approx(2.0)


def test_non_physical_stock_is_refused_naming_the_key() -> None:
    """Crush load that cannot start on 20 permille, EB below the guarantee, axles."""
    msg = _refused(lambda d: d["trains"].update(stock={"traction_force_kn": 50.0}),
                   "trains.stock.traction_force_kn")
    assert "20 permille" in msg and "crush" in msg
    _refused(lambda d: d["trains"].update(stock={"emergency_brake_actual_mps2": 1.1}),
             "trains.stock.emergency_brake_actual_mps2")
    _refused(lambda d: d["signalling"].update(guaranteed_decel_mps2=1.5),
             "signalling.guaranteed_decel_mps2")
    _refused(lambda d: d["trains"].update(stock={"motored_axle_fraction": 0.9}),
             "trains.stock.motored_axle_fraction")
    _refused(lambda d: d["trains"].update(initial_load_pax=2500.0), "trains.initial_load_pax")
    _refused(lambda d: d["trains"].update(mass_load_pax=100.0), "trains.mass_load_pax")


def test_crush_start_threshold_is_the_force_balance() -> None:
    """Refused exactly when F <= A + m_crush g sin(atan(grade)): 30 kN, 58 t at crush."""
    light = {**LIGHT, "stock": {"cars": 3, "traction_force_kn": 30.0}}
    m = 45_000.0 + 200 * 65.0
    a = PRESETS["taipei_mrt_6car"].davis_a_n * 45_000.0 / 214_000.0  # A scales with mass
    lim = float(np.tan(np.arcsin((30e3 - a) / (m * 9.80665))) * 1000.0)  # 51.2 permille
    assert 50.0 < lim < 52.0

    def steep(g: float) -> Callable[[dict[str, Any]], None]:
        def edit(d: dict[str, Any]) -> None:
            d["trains"].update(copy.deepcopy(light))
            d["line"]["gradients"].append({"start_m": 2600.0, "grade_permille": g})
        return edit
    _refused(steep(round(lim + 0.1, 1)), "trains.stock.traction_force_kn")
    _parse(_mini(steep(round(lim - 0.1, 1))))


# ----------------------------------------------------------------------------- track


@pytest.mark.parametrize("edit,key", [
    (lambda d: d["line"]["speed_limits"].append({"start_m": 25_000.0, "limit_kmh": 50.0}),
     "line.speed_limits[3].start_m"),
    (lambda d: d["line"]["gradients"].append({"start_m": 3100.0, "grade_permille": 5.0}),
     "line.gradients[5].start_m"),
    (lambda d: d["line"].update(temporary_speed_limits=[
        {"start_m": 15_000.0, "end_m": 15_300.0, "limit_kmh": 30.0}]),
     "line.temporary_speed_limits[0].end_m"),
    (lambda d: d["line"]["curves"].append({"start_m": -5000.0, "end_m": -4000.0,
                                           "radius_m": 300.0}), "line.curves[1].start_m"),
    (lambda d: d.update(incidents=[{"kind": "tsr", "at_s": 100.0, "duration_s": 60.0,
                                    "start_m": 9000.0, "end_m": 9200.0}]),
     "incidents[0].end_m"),
])
def test_track_data_off_the_line_is_refused(edit: Callable[[dict[str, Any]], None],
                                            key: str) -> None:
    """mini spans [0 - 141 - 500, 2800 + 300] m: data beyond are refused, one line."""
    msg = _refused(edit, key)
    assert "[-641, 3100] m" in msg


def test_track_data_at_the_line_ends_are_accepted() -> None:
    """A TSR up to the buffer stop and a limit starting just before it load."""
    _parse(_mini(lambda d: (d["line"]["speed_limits"].append({"start_m": 3099.0,
                                                              "limit_kmh": 30.0}),
                            d["line"].update(temporary_speed_limits=[
                                {"start_m": -641.0, "end_m": 3100.0, "limit_kmh": 30.0}]))))


# ----------------------------------------------------------------------------- TTOBench


def test_ttobench_keeps_the_mass_and_refuses_a_missing_length() -> None:
    """The Beijing train's 278 t run as 278 t (was 278 - 65 t); no length: refused."""
    with pytest.raises(TtobenchError, match="missing field 'length'"):
        import_ttobench("CN_Songjiazhuang_Yizhuang", "CN_Beijing_Subway")
    imp = import_ttobench("CN_Songjiazhuang_Yizhuang", "CN_Beijing_Subway", length_m=118.0)
    scn = parse_scenario(imp.yaml_text(), "t.yaml")
    assert scn.trains.length_m == 118.0 and any("118 m" in n for n in imp.notes)
    sim = LineSim(scn, seed=0, trace_period_s=0.0)
    assert np.all(sim.fleet.mass == 278_000.0)


def test_ttobench_train_with_a_length_keeps_it(tmp_path: Path) -> None:
    """A train file with a length keeps it; giving another one too is refused."""
    from metro_atc.ttobench.importer import load_json
    _, raw = load_json("CN_Beijing_Subway")
    raw["length"] = {"unit": "m", "value": 58.6}
    f = tmp_path / "r.json"
    f.write_text(json.dumps(raw))
    imp = import_ttobench("CN_Songjiazhuang_Yizhuang", str(f))
    assert imp.scenario["trains"]["length_m"] == 58.6
    with pytest.raises(TtobenchError, match="give one"):
        import_ttobench("CN_Songjiazhuang_Yizhuang", str(f), length_m=100.0)


# ----------------------------------------------------------------------------- show


def test_show_lists_every_figure_with_its_source(tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    """Every TrainParams field is shown; file values say so, the others name the preset."""
    import dataclasses

    from metro_atc.show import STOCK_ROWS, resolved, stock_line
    shown = {r[0] for r in STOCK_ROWS}
    assert {f.name for f in dataclasses.fields(TrainParams)} <= shown
    d = _mini(lambda d: (d["trains"].update(copy.deepcopy(LIGHT)),
                         d["trains"]["stock"].update(traction_force_kn=60.0)))
    f = tmp_path / "light.yaml"
    f.write_text(yaml.safe_dump(d))
    scn = parse_scenario(f.read_text(), str(f))
    rows = {r["key"]: r for r in resolved(scn)["rolling_stock"]}
    assert rows["traction_force_n"]["value"] == pytest.approx(60.0)
    assert rows["traction_force_n"]["source"] == "file (trains.stock.traction_force_kn)"
    assert rows["aux_power_w"]["source"] == "preset taipei_mrt_6car"
    assert rows["aux_power_w"]["value"] == 150.0
    assert rows["davis_a_n"]["source"] == "preset taipei_mrt_6car, scaled to the file's mass"
    assert rows["tare_mass_kg"]["value"] == pytest.approx(45.0)
    assert cli_main(["show", "--scenario", str(f)]) == 0
    out = capsys.readouterr().out
    assert "fleet needed: 2 trains" in out and "file (trains.tare_mass_kg" in out
    assert "45 t" in stock_line(scn)
    assert cli_main(["show", "--scenario", str(tmp_path / "none.yaml")]) == 2


def test_show_fleet_needed_counts_overlapping_services() -> None:
    """Two trains 150 s apart on a ~450 s service overlap: the mini line needs both."""
    from metro_atc.core.line.scenario import load_scenario
    from metro_atc.show import resolved
    tt = resolved(load_scenario("mini"))["timetable"]
    assert tt["trains"] == 2 and tt["fleet_needed"] == 2
    assert tt["last_departure_s"] - tt["first_departure_s"] == pytest.approx(150.0)


# ----------------------------------------------------------------------------- corpus


def test_extended_corpus_has_light_heavy_dense_and_long() -> None:
    """The extended generator draws light / heavy stock and every interstation kind."""
    from metro_atc.core.linegen import SPACINGS, generate_line, load_generated_named
    seen: dict[str, int] = {}
    for seed in range(40):
        name, scn = load_generated_named(seed, extended=True)
        seen[name] = seen.get(name, 0) + 1
        p = train_params_for(scn)
        if name == "light_metro":
            assert 30e3 <= p.tare_mass_kg <= 70e3 and 20.0 <= p.length_m <= 40.0
        if name == "heavy_metro_8car":
            assert 300e3 <= p.tare_mass_kg <= 450e3 and p.cars == 8
            assert 100.0 <= scn.line.line_speed_kmh <= 120.0
    assert seen.get("light_metro") and seen.get("heavy_metro_8car")
    for kind, (lo, hi) in SPACINGS.items():
        g = generate_line(5, extended=True, spacing_kind=kind, stock="taipei_mrt_6car")
        gaps = np.diff([s["position_m"] for s in g["line"]["stations"]])
        assert np.all((gaps >= lo - 0.1) & (gaps <= hi + 0.1)), kind
    assert generate_line(3) == generate_line(3, extended=False)
