"""AOC/DHP weights belong to a line: content hash, refusal, cache, training."""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from metro_atc import launcher  # noqa: E402
from metro_atc.core.atr import weights_store as store  # noqa: E402
from metro_atc.core.atr.blue_line import small_line  # noqa: E402
from metro_atc.core.atr.dispatch import make_dispatcher  # noqa: E402
from metro_atc.core.atr.fingerprint import line_hash  # noqa: E402
from metro_atc.core.atr.lines import atr_line_for  # noqa: E402
from metro_atc.core.atr.regulators import load_weights, read_blob  # noqa: E402
from metro_atc.core.line.scenario import load_scenario  # noqa: E402
from metro_atc.core.linegen import generate_line, load_generated, scenario_yaml  # noqa: E402

EPOCHS = 3
"""Enough to write a valid file; these tests check bookkeeping, not the policy."""


@pytest.fixture()
def cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A private, empty weights cache (also for the ATS core and the launcher)."""
    d = tmp_path / "cache"
    monkeypatch.setenv(store.CACHE_ENV, str(d))
    return d


def test_hash_covers_every_traffic_model_input_and_nothing_else() -> None:
    """Each traffic-model input changes the hash; name, codes, distances, periods do not."""
    line = small_line(5)
    h = line_hash(line)
    assert h == line_hash(small_line(5)) and len(h) == 64
    arr = {"run_s", "run_min_s", "run_max_s", "dwell_fixed_s", "dwell_fixed_min_s",
           "boarding_pax_h"}
    scal = {"hold_max_s", "t_board_s", "headway_s", "separation_min_s", "disturbance_mean_s",
            "crowding_gain", "board_max_s"}
    for name in arr:
        v = np.array(getattr(line, name), dtype=float)
        v[-1] += 0.5
        assert line_hash(dataclasses.replace(line, **{name: v})) != h, name
    for name in scal:
        assert line_hash(dataclasses.replace(line, **{name: getattr(line, name) * 1.01 + 0.1})) \
            != h, name
    assert line_hash(small_line(6)) != h
    same = dataclasses.replace(line, name="other", station_codes=tuple("ABCDE"),
                               distance_m=line.distance_m * 2, periods=())
    assert line_hash(same) == h
    # rounding: a last-bit difference does not change the hash
    assert line_hash(dataclasses.replace(line, run_s=line.run_s * (1 + 1e-15))) == h


def test_generated_lines_with_the_same_station_count_differ() -> None:
    """Two generated 15-station lines: same count, different traffic models, different hash."""
    a = atr_line_for(load_generated(1, n_stations=15))
    b = atr_line_for(load_generated(2, n_stations=15))
    assert a.n_stations == b.n_stations == 15
    assert line_hash(a) != line_hash(b)


def test_weights_of_another_line_are_refused(tmp_path: Path) -> None:
    """A file trained on line A loads on A and is refused on B with the same station count."""
    a = small_line(4)
    b = dataclasses.replace(a, run_s=a.run_s + 3.0)
    f = tmp_path / "a.pt"
    info = store.train_weights("aoc", a, f, epochs=EPOCHS)
    assert read_blob(f)["line_hash"] == line_hash(a)
    assert {"cost", "cost_none", "ratio_to_none"} <= set(info["validation"])
    assert load_weights(f, a).name == "aoc"
    with pytest.raises(ValueError, match="another line") as exc:
        load_weights(f, b)
    assert "\n" not in str(exc.value)
    # a file written before weights were tied to a line (no hash) is refused too
    blob = torch.load(str(f), weights_only=True)
    del blob["line_hash"]
    old = tmp_path / "old.pt"
    torch.save(blob, str(old))
    with pytest.raises(ValueError, match="no traffic-model hash"):
        load_weights(old, a)


def test_cache_miss_trains_once_then_hits(cache: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """ensure_weights: refuse without training; train into <hash>-<kind>.pt; then a hit."""
    line = small_line(4)
    with pytest.raises(ValueError, match=line_hash(line)[:12]):
        store.ensure_weights("dhp", line, train_missing=False)
    assert not cache.exists() or not any(cache.iterdir())
    calls: list[Path] = []
    real = store.train_weights

    def counting(kind: str, ln: object, out: Path, **kw: object) -> object:
        calls.append(out)
        return real(kind, ln, out, **kw)  # type: ignore[arg-type]

    monkeypatch.setattr(store, "train_weights", counting)
    said: list[str] = []
    p = store.ensure_weights("dhp", line, epochs=EPOCHS, progress=said.append)
    assert p == cache / f"{line_hash(line)}-dhp.pt" and p.is_file()
    assert len(calls) == 1 and any("epoch" in m for m in said), said
    mtime = p.stat().st_mtime_ns
    assert store.ensure_weights("dhp", line, epochs=EPOCHS) == p
    assert store.ensure_weights("dhp", line, train_missing=False) == p
    assert len(calls) == 1 and p.stat().st_mtime_ns == mtime
    # weights of another line copied to this line's cache name are not a hit
    other = dataclasses.replace(line, headway_s=150.0)
    (cache / f"{line_hash(other)}-dhp.pt").write_bytes(p.read_bytes())
    assert store.find_weights("dhp", other) is None
    # aoc is another kind: not a hit for the dhp file
    assert store.find_weights("aoc", line) is None


def test_shipped_weights_are_found_for_their_line_only(cache: Path) -> None:
    """The shipped taipei_blue files carry its hash; a generated 23-station line gets none."""
    tb = atr_line_for(load_scenario("taipei_blue"))
    for kind in ("aoc", "dhp"):
        p = store.find_weights(kind, tb)
        assert p is not None and p.name == f"{kind}_taipei_blue.pt"
        assert load_weights(p, tb).name == kind
        other = atr_line_for(load_generated(3, n_stations=23))
        assert store.find_weights(kind, other) is None


def test_ats_refuses_a_line_without_weights(cache: Path, tmp_path: Path) -> None:
    """make_dispatcher (what the ATS node runs): no weights for the line -> one-line error;
    the shipped taipei_blue weights given explicitly on a generated line -> refused."""
    scn = load_generated(4, n_stations=6)
    with pytest.raises(ValueError, match="no aoc weights") as exc:
        make_dispatcher(scn, "aoc")
    assert "\n" not in str(exc.value)
    ship = store.DATA_DIR / "aoc_taipei_blue.pt"
    with pytest.raises(ValueError):
        make_dispatcher(scn, "aoc", weights_file=str(ship))
    store.ensure_weights("aoc", atr_line_for(scn), epochs=EPOCHS)
    d = make_dispatcher(scn, "aoc")
    assert d.core is not None and d.core.regulator.name == "aoc"


def test_run_refuses_before_any_node_starts(cache: Path, tmp_path: Path) -> None:
    """``run --regulator dhp --train-regulator never`` on a line without weights: exit 2, one
    line naming the regulator and the hash, no node started (no log directory)."""
    f = tmp_path / "gen.yaml"
    f.write_text(scenario_yaml(generate_line(5, n_stations=6)))
    out = tmp_path / "o"
    t0 = time.monotonic()
    code = launcher.main(["--scenario", str(f), "--regulator", "dhp", "--train-regulator",
                          "never", "--out", str(out), "--no-plots"])
    assert code == 2 and time.monotonic() - t0 < 30.0
    assert not (out / "logs").exists()
    code = launcher.main(["--scenario", str(f), "--regulator", "aoc", "--weights",
                          str(store.DATA_DIR / "aoc_taipei_blue.pt"), "--out", str(out),
                          "--no-plots"])
    assert code == 2 and not (out / "logs").exists()


def test_run_resolves_cached_weights_for_the_ats(cache: Path, tmp_path: Path) -> None:
    """prepare_regulator hands the ATS the cached weights of the line (a cache hit)."""
    f = tmp_path / "gen.yaml"
    f.write_text(scenario_yaml(generate_line(6, n_stations=6)))
    scn = load_scenario(str(f))
    p = store.ensure_weights("aoc", atr_line_for(scn), epochs=EPOCHS)
    a = launcher.parse_args(["--scenario", str(f), "--regulator", "aoc",
                             "--train-regulator", "never"])
    assert launcher.prepare_regulator(a, scn) is None
    assert a.weights_file == str(p)
    ats = [s for s in launcher.processes_for(a, list(scn.train_ids), tmp_path)
           if s.label == "ats_regulator"][0]
    assert ats.params["weights_file"] == str(p)
