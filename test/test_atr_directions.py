"""Regulators for both directions of the service day: traffic models, weights, validation."""

from __future__ import annotations

from pathlib import Path
from typing import Dict

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from metro_atc.core.atr import regulators as regs  # noqa: E402
from metro_atc.core.atr import weights_store as store  # noqa: E402
from metro_atc.core.atr.blue_line import LineData, small_line  # noqa: E402
from metro_atc.core.atr.cost import CostWeights  # noqa: E402
from metro_atc.core.atr.fingerprint import line_hash  # noqa: E402
from metro_atc.core.atr.lines import get_line  # noqa: E402
from metro_atc.core.atr.registry import TRAINED  # noqa: E402
from metro_atc.core.atr.regulators import (NeuralRegulator, load_weights,  # noqa: E402
                                           make_regulator, read_blob)
from metro_atc.core.service.day import taipei_blue_day  # noqa: E402
from metro_atc.core.service.regulation import (direction_line, peak_lines,  # noqa: E402
                                               peak_period)

SHORT_EPISODES = 2
"""Episodes of the short validation of the shipped weights (the files record 8)."""


@pytest.fixture(scope="module")
def blue() -> Dict[str, LineData]:
    """Both directions' traffic models of the taipei_blue scenario at the day's peak."""
    return peak_lines(taipei_blue_day(), get_line("taipei_blue"))


def test_direction_line_known_answers() -> None:
    """Up at factor 1 is the line itself (same hash); down reverses and scales p_j."""
    line = small_line(5)
    assert direction_line(line, "up", 1.0) is line
    down = direction_line(line, "down", 0.5)
    assert down.station_codes == line.station_codes[::-1]
    np.testing.assert_array_equal(down.run_s, line.run_s[::-1])
    np.testing.assert_array_equal(down.boarding_pax_h, line.boarding_pax_h[::-1] * 0.5)
    assert line_hash(down) != line_hash(line)
    for bad in (-0.1, float("nan"), float("inf")):
        with pytest.raises(ValueError):
            direction_line(line, "down", bad)
    with pytest.raises(ValueError):
        direction_line(line, "sideways", 1.0)


def test_peak_lines_take_the_peak_flow_factors(blue: Dict[str, LineData]) -> None:
    """The day's peak (105 s, Lin 2010a Exp. 2): up factor 1.00 keeps the scenario's hash,
    the down line runs backwards with the down flow factor of that period."""
    plan = taipei_blue_day()
    p = plan.periods[peak_period(plan)]
    assert p.headway_s == 105.0
    line = get_line("taipei_blue")
    assert line_hash(blue["up"]) == line_hash(line)
    np.testing.assert_allclose(blue["down"].boarding_pax_h,
                               line.boarding_pax_h[::-1] * p.flow_down)
    assert blue["down"].station_codes[0] == plan.termini[1].station


def test_down_weights_refused_on_the_up_line(tmp_path: Path) -> None:
    """Weights trained for a down line load on it and are refused on the up line's hash
    (and the up line's on the down line); make_regulator finds shipped ones by hash."""
    up = small_line(5)
    down = direction_line(up, "down", 0.55)
    w_down, w_up = tmp_path / "aoc_small5_down.pt", tmp_path / "aoc_small5.pt"
    store.train_weights("aoc", down, w_down, epochs=2)
    store.train_weights("aoc", up, w_up, epochs=2)
    assert load_weights(w_down, down).name == "aoc"
    assert load_weights(w_up, up).name == "aoc"
    with pytest.raises(ValueError, match="trained on another line"):
        load_weights(w_down, up)
    with pytest.raises(ValueError, match="trained on another line"):
        load_weights(w_up, down)
    assert regs.shipped_weights("aoc", down, tmp_path) == w_down
    assert regs.shipped_weights("aoc", up, tmp_path) == w_up
    assert regs.shipped_weights("dhp", down, tmp_path) is None


@pytest.mark.parametrize("direction", ["up", "down"])
@pytest.mark.parametrize("kind", TRAINED)
def test_shipped_weights_of_each_direction(blue: Dict[str, LineData], kind: str,
                                           direction: str) -> None:
    """Every trained regulator has shipped weights for both directions, refused on the
    other direction's hash, found by make_regulator without a path."""
    line, other = blue[direction], blue["down" if direction == "up" else "up"]
    path = regs.shipped_weights(kind, line)
    assert path is not None, f"no shipped {kind} weights for the {direction} line"
    assert read_blob(path)["line_hash"] == line_hash(line)
    with pytest.raises(ValueError, match="trained on another line"):
        load_weights(path, other)
    reg = make_regulator(kind, line)
    assert isinstance(reg, NeuralRegulator) and reg.name == kind
    assert reg.meta["path"] == str(path)


@pytest.mark.parametrize("direction", ["up", "down"])
@pytest.mark.parametrize("kind", TRAINED)
def test_shipped_weights_pass_their_validation(blue: Dict[str, LineData], kind: str,
                                               direction: str) -> None:
    """Shipped weights regulate better than the timetable: by the validation recorded in the
    file and by a short validation now (same episodes for both, truth traffic model)."""
    line = blue[direction]
    path = regs.shipped_weights(kind, line)
    assert path is not None
    assert store.validation_problem(path) is None
    v = read_blob(path)["info"]["validation"]
    assert v["cost"] < v["cost_none"]
    reg = load_weights(path, line)
    c = read_blob(path)["cost"]
    w = CostWeights(q=c["q"], r=c["r"], x_scale_s=c["x_scale_s"], horizon=c["horizon"])
    now = store.validate(line, reg, w, episodes=SHORT_EPISODES)
    assert now["cost"] < now["cost_none"], now


def test_energy_table_of_the_down_line_runs_backwards(blue: Dict[str, LineData]) -> None:
    """ELQR's energy table of the down line: down run 0 (BL23 -> BL22) is the up line's last
    segment run the other way (same length: flat-out times within 3 s), not the up line's
    first segment (1440 m vs 1060 m: 16 s apart)."""
    from metro_atc.core.atr.energy import build_energy_table
    from metro_atc.core.line.scenario import load_scenario
    scn = load_scenario("taipei_blue")
    last = blue["up"].n_stations - 2
    up = build_energy_table(scn, blue["up"], runs=[0, last])
    down = build_energy_table(scn, blue["down"], runs=[0])
    assert abs(down.r_fast_s[0] - up.r_fast_s[1]) < 3.0
    assert abs(down.r_fast_s[0] - up.r_fast_s[0]) > 10.0


def test_train_command_trains_the_down_line(blue: Dict[str, LineData], tmp_path: Path) -> None:
    """``train aoc --direction down`` writes weights with the down line's hash, which the down
    line accepts and the up line refuses; ``--day`` alone is a usage error."""
    from metro_atc import atr_train
    out = tmp_path / "w.pt"
    assert atr_train.main(["aoc", "--scenario", "taipei_blue", "--direction", "down",
                           "--epochs", "1", "--quiet", "--out", str(out)]) == 0
    assert read_blob(out)["line_hash"] == line_hash(blue["down"])
    assert load_weights(out, blue["down"]).name == "aoc"
    with pytest.raises(ValueError, match="trained on another line"):
        load_weights(out, blue["up"])
    with pytest.raises(SystemExit):
        atr_train.main(["aoc", "--day", "x.yaml", "--epochs", "1", "--out", str(out)])
