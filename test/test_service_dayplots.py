"""Pictures of a service day: train graph, circulation chart, KPI table, output writer."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from metro_atc.bench.service_day import main as service_day_main
from metro_atc.core.service.day import run_day, taipei_blue_day
from metro_atc.core.service.dayplots import _hhmm, _trip_paths, write_day_outputs
from metro_atc.core.service.planned import Incident, planned_records

PLAN = taipei_blue_day()
CIRC, _ = run_day(PLAN)


def _png_shape(path: Path) -> tuple:
    import matplotlib.image as mpimg
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    return mpimg.imread(str(path)).shape


def test_hhmm() -> None:
    """Seconds after midnight in hh:mm, past midnight too."""
    assert _hhmm(0.0) == "00:00" and _hhmm(7 * 3600 + 59 * 60 + 59.6) == "08:00"
    assert _hhmm(24.5 * 3600) == "24:30"


def test_trip_paths_climb_up_and_descend_down() -> None:
    """Up trips go up the chainage, down trips go down; each path is monotone in time."""
    rec = planned_records(PLAN, CIRC)
    y = np.concatenate([[0.0], np.cumsum(PLAN.line.distance_m)]) / 1000.0
    paths = _trip_paths(rec.stops, y)
    assert len(paths) == 586
    for tid, (_, d, tt, yy, late) in list(paths.items())[::37]:
        assert np.all(np.diff(tt) >= 0.0) and late == 0.0
        assert (yy[-1] > yy[0]) == (d == "up")
        assert yy[0] in (y[0], y[-1]) and yy[-1] in (y[0], y[-1])


def test_write_day_outputs(tmp_path: Path) -> None:
    """kpis.json/txt, three PNGs and the records of the morning of a day with a delay."""
    keep = {t.trip_id for b in CIRC.blocks for t in b.trips if t.departure_s < 9 * 3600}
    rec = planned_records(PLAN, CIRC, [Incident("up020", 0, 180.0)])
    stops = [r for r in rec.stops if r.trip_id in keep]
    tbs = [r for r in rec.turnbacks if r.arr_trip_id in keep]
    dep = [r for r in rec.depot if r.sched_t_s < 9.5 * 3600]
    paths = write_day_outputs(PLAN, stops, tbs, dep, tmp_path / "out",
                              zooms=((7 * 3600.0, 8 * 3600.0),))
    assert set(paths) == {"kpis_json", "kpis_txt", "train_graph", "circulation", "kpi_table",
                          "calls", "turnbacks", "depot"}
    # the records as CSV: a header, one row per record, floats read back exactly
    import csv
    rows = list(csv.DictReader(Path(paths["calls"]).open()))
    assert len(rows) == len(stops)
    for a, b in zip(rows, stops):
        assert float(a["arr_s"]) == b.arr_s or (a["arr_s"] == "nan" and math.isnan(b.arr_s))
        assert (a["train"], a["trip_id"], int(a["station"])) == (b.train, b.trip_id, b.station)
    assert len(list(csv.DictReader(Path(paths["turnbacks"]).open()))) == len(tbs)
    assert len(list(csv.DictReader(Path(paths["depot"]).open()))) == len(dep)
    k = json.loads(Path(paths["kpis_json"]).read_text())
    assert k["periods"][1]["directions"]["up"]["punctuality"] < 1.0
    assert "morning_peak" in Path(paths["kpis_txt"]).read_text()
    h, w = _png_shape(Path(paths["train_graph"]))[:2]
    assert w >= 1500 and h >= 1000        # two panels, wide enough for a day
    for name in ("circulation", "kpi_table"):
        assert _png_shape(Path(paths[name]))[1] >= 1500


def test_service_day_cli_refuses_bad_input(tmp_path: Path, capsys: pytest.CaptureFixture
                                           ) -> None:
    """A malformed clock or a station out of range: exit 2 with one line."""
    with pytest.raises(SystemExit) as ei:
        service_day_main(["--out", str(tmp_path), "--at", "7h30"])
    assert ei.value.code == 2
    with pytest.raises(SystemExit) as ei:
        service_day_main(["--out", str(tmp_path), "--station", "99"])
    assert ei.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("service_day: incident on") and not list(tmp_path.iterdir())
