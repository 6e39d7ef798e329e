"""The Foxglove / Lichtblick layout of the live view and of a run's bag (``docs/live_view.md``).

``config/foxglove_layout.json`` is this module's output for the default scenario
(``python -m metro_atc.live_layout > config/foxglove_layout.json``; a test checks that it
is); ``--scenario NAME`` writes the layout of another line (one time-distance series per
train).  Panels:

* time-distance plot of all trains: ``/line/trains.position[k]`` per train k (the order of
  ``/line/layout.train_id``), against the header stamp (simulation time);
* speed vs limit of one train (``/train_01/state``: ``speed_mps`` and the ATP
  ``supervision_speed_mps``; another train: change the topic in the panel's settings);
* the static speed limits along the line (``/line/layout``, against chainage);
* ``/diagnostics`` (diagnostics summary) and the event log (``/line/event_log``, a log
  panel: one line per arrival or departure).

Panel types and settings are those of Foxglove's layout files (Lichtblick reads the same).
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any, Sequence

from metro_atc.nodes.wire.line_view import EVENT_LOG_TOPIC, LAYOUT_TOPIC, TRAINS_TOPIC

DEFAULT_SCENARIO = "taipei_blue"
"""The scenario whose layout ships as ``config/foxglove_layout.json``."""
SPEED_TRAIN = "train_01"
"""The train of the speed vs limit plot."""


def _plot(title: str, paths: list[dict[str, Any]], **extra: Any) -> dict[str, Any]:
    """A Plot panel's settings."""
    cfg: dict[str, Any] = {"title": title, "paths": paths, "showLegend": True,
                           "legendDisplay": "left", "showPlotValuesInLegend": True,
                           "showXAxisLabels": True, "showYAxisLabels": True,
                           "isSynced": True, "xAxisVal": "timestamp",
                           "sidebarDimension": 200}
    cfg.update(extra)
    return cfg


def _series(path: str, label: str) -> dict[str, Any]:
    """One series against the message's header stamp (simulation time)."""
    return {"value": path, "enabled": True, "timestampMethod": "headerStamp", "label": label}


def layout(train_ids: Sequence[str]) -> dict[str, Any]:
    """The Foxglove layout file's JSON object for a line run by ``train_ids``."""
    time_distance = _plot(
        "time-distance: chainage of each train [m]",
        [_series(f"{TRAINS_TOPIC}.position[{k}]", t) for k, t in enumerate(train_ids)])
    speed = _plot(
        f"{SPEED_TRAIN}: speed and ATP limit [m/s]",
        [_series(f"/{SPEED_TRAIN}/state.speed_mps", "speed"),
         _series(f"/{SPEED_TRAIN}/state.supervision_speed_mps", "ATP limit")])
    limits = _plot(
        "static speed limits [m/s] along the line [m]",
        [{"value": f"{LAYOUT_TOPIC}.speed_limit_mps[:]", "enabled": True,
          "timestampMethod": "receiveTime", "label": "limit from start"}],
        xAxisVal="currentCustom",
        xAxisPath={"value": f"{LAYOUT_TOPIC}.speed_limit_start_m[:]", "enabled": True})
    config = {
        "Plot!timedistance": time_distance,
        "Plot!speedlimit": speed,
        "Plot!lineprofile": limits,
        "DiagnosticSummary!diagnostics": {"minLevel": 0, "pinnedIds": [],
                                          "hardwareIdFilter": "",
                                          "topicToRender": "/diagnostics",
                                          "sortByLevel": True},
        "RosOut!eventlog": {"searchTerms": [], "minLogLevel": 1,
                            "topicToRender": EVENT_LOG_TOPIC},
    }
    tree = {"direction": "row", "splitPercentage": 62,
            "first": {"direction": "column", "splitPercentage": 55,
                      "first": "Plot!timedistance",
                      "second": {"direction": "row", "splitPercentage": 50,
                                 "first": "Plot!speedlimit", "second": "Plot!lineprofile"}},
            "second": {"direction": "column", "splitPercentage": 45,
                       "first": "DiagnosticSummary!diagnostics",
                       "second": "RosOut!eventlog"}}
    return {"configById": config, "globalVariables": {}, "userNodes": {},
            "playbackConfig": {"speed": 1.0}, "layout": tree}


def layout_text(scenario: str = DEFAULT_SCENARIO) -> str:
    """The layout file's text for ``scenario`` (its trains in timetable order)."""
    from metro_atc.core.service.dayrun import load_run_scenario
    from metro_atc.launcher import scenario_train_ids
    ids = list(scenario_train_ids(load_run_scenario(scenario)))
    return json.dumps(layout(ids), indent=2) + "\n"


def main(argv: Sequence[str] | None = None) -> int:
    """Print the layout of ``--scenario`` (default the shipped one's) on stdout."""
    p = argparse.ArgumentParser(prog="python -m metro_atc.live_layout",
                                description="print the Foxglove / Lichtblick layout of a line")
    p.add_argument("--scenario", default=DEFAULT_SCENARIO)
    a = p.parse_args(argv)
    from metro_atc.core.line.scenario import ScenarioError
    try:
        sys.stdout.write(layout_text(a.scenario))
    except ScenarioError as exc:
        print(f"metro_atc.live_layout: error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
