"""Checkpoint and resume of a :class:`LineSim` (ROS-free; format in :mod:`..checkpoint`).

The dynamic state of every component (fleet, ATP, brakes, energy, stations and their event
log, incidents, sensors and their RNG, the clock, the plot trace) is captured by the generic
walker of :mod:`metro_atc.core.checkpoint`; the static parts below are rebuilt from the
scenario by ``LineSim(scn, seed)`` and not stored.  A checkpoint is tied to the scenario's
content and the seed: :func:`load_line` refuses one made for another.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from metro_atc.core.checkpoint import capture, content_hash, read, restore, save_tree

from .line import LineSim

STATIC_ATTRS = ("scn", "description", "p", "geometry", "service", "curve", "tables",
                "station_names", "station_codes", "station_positions_m", "train_ids")
"""Attributes of :class:`LineSim` rebuilt from the scenario (never stored)."""


def scenario_hash(sim: LineSim) -> str:
    """Identity of the scenario content and seed a checkpoint belongs to."""
    return content_hash(sim.scn, sim.seed)


def static_parts(sim: LineSim) -> dict[str, Any]:
    """The static objects of ``sim`` by name (see :data:`STATIC_ATTRS`)."""
    return {a: getattr(sim, a) for a in STATIC_ATTRS}


def capture_line(sim: LineSim) -> tuple[dict[str, Any], list[np.ndarray]]:
    """The dynamic state of ``sim`` (tree, arrays)."""
    return capture(sim, static_parts(sim))


def restore_line(sim: LineSim, tree: dict[str, Any], arrays: dict[str, np.ndarray]) -> None:
    """Load a :func:`capture_line` into a ``LineSim`` built from the same scenario and seed."""
    restore(sim, tree, arrays, static_parts(sim))


def save_line(path: Path, sim: LineSim, **header: Any) -> Path:
    """Write ``sim``'s checkpoint to ``path`` atomically (header: step, t, extra fields)."""
    tree, arrays = capture_line(sim)
    return save_tree(path, tree, arrays, scenario_hash=scenario_hash(sim),
                     t=float(sim.t), step_count=int(sim.step_count), **header)


def load_line(path: Path, sim: LineSim) -> dict[str, Any]:
    """Restore ``sim`` from ``path``; refuses a checkpoint of another scenario or seed."""
    head, arrays = read(path, scenario_hash=scenario_hash(sim))
    restore_line(sim, head["tree"], arrays)
    return head
