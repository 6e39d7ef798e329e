"""The run's PNGs rendered in parallel: same files, same bytes; train labels do not overlap."""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

import pytest

from metro_atc.forked import run_jobs
from metro_atc.plots import _end_labels, _plt, output_jobs, write_outputs
from test_plots import _sim


def _digests(folder: Path) -> dict[str, str]:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.iterdir()) if p.is_file()}


@pytest.mark.skipif(not hasattr(os, "fork"), reason="no fork: rendered one after another")
def test_parallel_outputs_are_the_sequential_ones(tmp_path: Path) -> None:
    """workers=2 and 3 write the files of workers=1 byte for byte, in the same order."""
    sim = _sim(400.0)
    ref = write_outputs(sim, tmp_path / "seq", workers=1)
    names = [p.name for p in ref]
    assert names[:3] == ["kpis.json", "events.csv", "train_graph.png"]
    assert names[-1] == "energy.png" and any(n.startswith("speed_") for n in names)
    for w in (2, 3):
        got = write_outputs(sim, tmp_path / f"par{w}", workers=w)
        assert [p.name for p in got] == names
        assert _digests(tmp_path / f"par{w}") == _digests(tmp_path / "seq")


@pytest.mark.skipif(not hasattr(os, "fork"), reason="no fork")
def test_a_failed_worker_share_is_rendered_here(tmp_path: Path,
                                                capfd: pytest.CaptureFixture[str]) -> None:
    """A job that fails in the forked worker is run again in this process: files all there."""
    parent = os.getpid()

    def job(path: Path) -> None:
        if os.getpid() != parent:
            raise RuntimeError("worker failure for the test")
        path.write_text("ok")

    jobs = [(tmp_path / f"f{k}.txt", (lambda k=k: job(tmp_path / f"f{k}.txt")))
            for k in range(4)]
    run_jobs(jobs, workers=2)
    assert all((tmp_path / f"f{k}.txt").read_text() == "ok" for k in range(4))
    assert "writing them here" in capfd.readouterr().err


def test_output_jobs_list_each_file_once(tmp_path: Path) -> None:
    """The jobs cover the events CSV, the train graph, the speed plots and energy, once each."""
    sim = _sim(400.0)
    paths = [p.name for p, _ in output_jobs(sim, tmp_path, speed_trains=[0, 1])]
    assert sorted(paths) == sorted(["events.csv", "train_graph.png", "speed_train_01.png",
                                    "speed_train_02.png", "energy.png"])


def test_end_labels_do_not_overlap() -> None:
    """30 trains ending at the terminus 2 min apart (the Blue line): no two labels overlap."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(13, 8))
    ends = [(50.0 + 2.0 * k + 0.3 * (k % 3), 27.0 + 0.01 * (k % 2), f"T{k + 1:02d}", "k")
            for k in range(30)]
    ax.plot([0.0, 110.0], [0.0, 27.0])
    ax.set_xlim(0.0, 115.0)
    _end_labels(fig, ax, ends)
    fig.tight_layout()
    fig.canvas.draw()
    r = fig.canvas.get_renderer()
    boxes = [t.get_window_extent(r) for t in ax.texts]
    assert len(boxes) == 30
    overlaps = [(a, b) for i, a in enumerate(boxes) for b in boxes[i + 1:] if a.overlaps(b)]
    plt.close(fig)
    assert overlaps == []
    # the labels fit inside the axes (the y range grew for the rows above the terminus)
    fig2, ax2 = plt.subplots(figsize=(13, 8))
    ax2.plot([0.0, 110.0], [0.0, 27.0])
    ax2.set_xlim(0.0, 115.0)
    _end_labels(fig2, ax2, ends)
    assert ax2.get_ylim()[1] > 27.0 + 0.05 * 27.0
    plt.close(fig2)
