"""``bench lines --jobs``: the worker pool keeps the corpus order and reports failures."""

from __future__ import annotations

import argparse

from metro_atc.bench.lines import run_jobs


def _args() -> argparse.Namespace:
    return argparse.Namespace(incidents=False, regulator="none", planner="ectp",
                              tracker="fuzzy", sim_seed=0, no_brake=True)


def test_pool_outcomes_match_the_serial_ones_in_corpus_order(tmp_path) -> None:
    bad = []
    for k in range(3):
        f = tmp_path / f"bad_{k}.yaml"
        f.write_text(f"name: bad_{k}\nline: [not, a, mapping]\n")
        bad.append(("file", str(f)))
    serial = list(run_jobs(bad, _args(), 1))
    pooled = list(run_jobs(bad, _args(), 2))
    assert [o[2] for o in pooled] == [o[2] for o in serial]
    assert all(row is None and failure.startswith(str(tmp_path / f"bad_{k}"))
               for k, (row, _, failure) in enumerate(pooled))
