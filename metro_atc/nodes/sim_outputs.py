"""The line_simulator's files at the end of a run: the finished file and the run's outputs.

:func:`write_finished_file` tells the launcher that the run is over (it then stops the other
nodes while the simulator writes its outputs); :func:`write_outputs` writes ``events.csv``,
``kpis.json`` and (optionally) the plots into the output directory.  A failure is logged,
the KPIs written if they can be, then raised (the node exits with
:data:`metro_atc.exit_codes.Exit.OUTPUTS_NOT_WRITTEN`).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Sequence

from metro_atc.jsonsafe import json_safe


def write_finished_file(path: str, loop_wall_s: float | None, loop_sim_s: float,
                        logger: Any) -> None:
    """Write the finished file ``path`` (if set): the run is over, its last samples delivered.

    The launcher then stops the other nodes while this one writes its outputs (issue
    13: their shutdown no longer follows this node's). The file holds the stepping
    loop's wall and simulated time, ``{"loop_wall_s": s, "loop_sim_s": s}`` (its speed
    without its start-up and end: the figure to set beside a co-simulation's own loop;
    wall times stay out of kpis.json, which two runs write identically). A file that
    cannot be written is logged (``logger``); the launcher then stops the nodes after this
    one.
    """
    if not path:
        return
    try:
        tmp = Path(path + ".tmp")
        tmp.write_text(json.dumps({"loop_wall_s": loop_wall_s, "loop_sim_s": loop_sim_s}))
        tmp.replace(path)  # seen whole or not at all
    except OSError as exc:
        logger.warning(f"finished_file {path}: {exc}")


def regulator_label(seen: dict[str, int]) -> str:
    """The ``regulator`` of a run's KPIs: the regulators whose departure commands ran.

    ``seen``: regulator name -> departure commands applied; names joined by commas, or
    ``none (no departure commands)``.
    """
    return ",".join(sorted(seen)) if seen else "none (no departure commands)"


def write_outputs(out_dir: str, line: Any, kpis: dict[str, Any], with_plots: bool,
                  planned: dict[int, Any], logger: Any,
                  dispatched: Sequence[tuple[Any, int]] = (), events: bool = True) -> None:
    """Write the run's outputs into ``out_dir`` ('' : none); raise OSError if any is missing.

    ``line``: the plant (its event log); ``kpis``: the run's KPIs (``kpis.json``);
    ``with_plots``: the PNG plots too (:func:`metro_atc.plots.write_outputs`, which writes
    the KPIs itself), else ``events.csv``; ``planned``: the speed profiles the ATOs
    published (train -> station -> (positions [m], speeds [m/s])); ``dispatched``: the
    dispatcher's applied commands and their station index (events.csv rows). A failure of
    the CSV or plots is logged (``logger``), the KPIs are written all the same, then an
    OSError names what is missing (the node's exit code says the outputs were not
    written).
    """
    if not out_dir:
        return
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OSError(f"outputs not written: {out}: {exc.strerror or exc}") from None
    failed = ""
    try:
        from metro_atc import plots
        if with_plots:
            plots.write_outputs(line, out, kpis=kpis, planned=planned, dispatched=dispatched)
            return
        if events:
            plots.write_events_csv(line, out / "events.csv", dispatched)
    except Exception as exc:  # noqa: BLE001 - outputs must not hide the KPIs
        failed = f"{'plots/events.csv' if with_plots else 'events.csv'} in {out}: {exc}"
        logger.error(f"writing outputs to {out} failed: {exc}")
    try:
        (out / "kpis.json").write_text(json.dumps(json_safe(kpis), indent=2, sort_keys=True))
    except OSError as exc:
        raise OSError(f"outputs not written: {out / 'kpis.json'}: {exc.strerror or exc}") \
            from None
    if failed:
        raise OSError(f"outputs not written: {failed}")
