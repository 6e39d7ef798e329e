"""A service day named like a scenario: what ``run --scenario <day>`` runs (ROS-free).

A *day* is a period table (:mod:`metro_atc.core.service.day`: periods, termini with their
layouts, depots, fleet) for the line of a one-way scenario (the table's ``line``).  The
shipped days are the ``metro_atc/data/<name>_periods.yaml`` tables (``taipei_blue_day``);
a path to such a table names a day of the user's.  The graph runs it with the same objects
as the ROS-free day: the simulator node a :class:`metro_atc.core.service.dayplant.DayPlant`
(:func:`day_plant`), the ATO nodes the fleet plant's scenario (:func:`fleet_scenario_of`,
a slot and a train id per train of the circulation).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Any, Tuple

from metro_atc.core.line.scenario import Scenario, ScenarioError, load_scenario
from metro_atc.core.safe_yaml import load_yaml_file

from .day import DayPlan, load_day

if TYPE_CHECKING:  # the day plant (its regulators: scipy) is imported when a day is built
    from .dayplant import DayPlant

SUFFIX = "_periods"
"""A shipped day ``<name>`` is the period table ``metro_atc/data/<name>_periods.yaml``."""
TRIP_TIMES = ("plan", "plant")
"""Trip times of the day's circulation (:func:`metro_atc.core.service.dayplant.day_layout`).

A day runs with ``plant`` unless told: the plant's own timetable (its scheduled running
times and nominal dwells).  The period table's (``plan``: Lin 2010a, eq. 5/10 on the ATR
line data) are shorter than the plant's line can run, so every trip would end late and the
lateness grow from turnback to turnback."""


def _data_dir() -> Path:
    return Path(str(resources.files("metro_atc").joinpath("data")))


@functools.lru_cache(maxsize=1)
def day_names() -> Tuple[str, ...]:
    """Names of the shipped days (``metro_atc/data/*_periods.yaml``; read once)."""
    d = _data_dir()
    return tuple(sorted(p.stem[:-len(SUFFIX)] for p in d.glob(f"*{SUFFIX}.yaml")))


def day_table(name_or_path: str) -> Path | None:
    """The period table a run's ``scenario`` names, or None when it names no day.

    A shipped day's name, or the path of a YAML file whose top level has ``periods`` and
    ``termini`` (a period table; anything else is a one-way scenario file).
    """
    key = str(name_or_path)
    if key in day_names():
        return _data_dir() / f"{key}{SUFFIX}.yaml"
    p = Path(key)
    if p.suffix in (".yaml", ".yml") and p.is_file():
        try:
            raw = load_yaml_file(p)
        except Exception:  # noqa: BLE001 - not readable here: the scenario loader says why
            return None
        if isinstance(raw, dict) and "periods" in raw and "termini" in raw:
            return p
    return None


@dataclass(frozen=True)
class DayRun:
    """A day to run: its name, period table, the one-way scenario of its line and stock."""

    name: str
    plan: DayPlan
    scenario: Scenario
    trip_times: str = "plant"


def load_day_run(name_or_path: str, trip_times: str = "plant") -> DayRun:
    """The day ``name_or_path`` names (:func:`day_table`); ValueError in one line.

    The line and stock: the one-way scenario named by the table's ``line``.
    """
    table = day_table(name_or_path)
    if table is None:
        raise ValueError(f"{name_or_path!r} is not a service day (shipped: "
                         f"{', '.join(day_names())}, or a period table's path)")
    if trip_times not in TRIP_TIMES:
        raise ValueError(f"trip_times must be one of {', '.join(TRIP_TIMES)}, got "
                         f"{trip_times!r}")
    plan = load_day(table)
    return DayRun(plan.name, plan, load_scenario(plan.line.name), trip_times)


def day_plant(run: DayRun, seed: int = 0, planner: str = "ectp", tracker: str = "fuzzy",
              records: bool = True, regulator: str = "none") -> DayPlant:
    """The day's plant (:func:`metro_atc.core.service.dayplant.service_day`).

    ``regulator``: the ATS regulator of both directions (``none``: the timetable).
    """
    from .dayplant import service_day
    return service_day(run.scenario, run.plan, planner, tracker, seed,
                       trip_times=run.trip_times, records=records, regulator=regulator)


def fleet_scenario_of(run: DayRun) -> Scenario:
    """The scenario of the day's fleet plant (its train ids and line: what an ATO runs)."""
    from .dayplant import STABLE_AFTER_S, day_layout, fleet_scenario
    loop, circ = day_layout(run.scenario, run.plan, STABLE_AFTER_S, run.trip_times)
    return fleet_scenario(loop.scenario, len({b.train for b in circ.blocks}))


def last_arrival_s(run: DayRun) -> float:
    """The day's last planned arrival [s] (the last trip of its circulation)."""
    from .dayplant import STABLE_AFTER_S, day_layout
    _, circ = day_layout(run.scenario, run.plan, STABLE_AFTER_S, run.trip_times)
    return max(t.arrival_s for b in circ.blocks for t in b.trips)


def load_run_scenario(name_or_path: str) -> Scenario:
    """The scenario a run's ``scenario`` names: a one-way scenario or a day's fleet plant.

    A day (:func:`day_table`): :func:`fleet_scenario_of` (its train ids are the ones the
    simulator publishes); anything else :func:`load_scenario`.  ScenarioError in one line.
    """
    if day_table(name_or_path) is None:
        return load_scenario(name_or_path)
    try:
        return fleet_scenario_of(load_day_run(name_or_path))
    except ScenarioError:
        raise
    except ValueError as exc:
        raise ScenarioError(str(exc)) from None


def describe(run: DayRun, dp: Any = None) -> str:
    """One line: the day, its periods, termini and fleet (for the run's first line)."""
    p = run.plan
    fleet = "" if dp is None else f", {len(dp.trains)} trains in the circulation"
    return (f"service day {run.name}: line {run.scenario.name}, {len(p.periods)} periods "
            f"{p.periods[0].start_s / 3600:.0f}:00-{p.periods[-1].end_s / 3600:.0f}:00, "
            f"termini {p.termini[0].station} ({p.termini[0].layout.name}) and "
            f"{p.termini[1].station} ({p.termini[1].layout.name}), trip times "
            f"{run.trip_times}{fleet}")


__all__ = ["DayRun", "SUFFIX", "TRIP_TIMES", "day_names", "day_plant", "day_table",
           "describe", "fleet_scenario_of", "last_arrival_s", "load_day_run",
           "load_run_scenario"]
