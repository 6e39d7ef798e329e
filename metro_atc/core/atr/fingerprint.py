"""Content hash of an ATR line: what the traffic model and the regulators depend on (ROS-free).

AOC/DHP weights belong to a line.  Two lines with the same station count
can have different running times, dwell models or passenger rates, so weights are tied to
the sha256 of the canonical JSON of exactly the inputs that the traffic model
(:mod:`metro_atc.core.atr.traffic`), the training problem
(:class:`metro_atc.core.atr.problems.AtrProblem`) and the regulators read from a
:class:`metro_atc.core.atr.blue_line.LineData`:

station count, scheduled / minimum / maximum running times [s], fixed dwell and its
minimum [s], holding limit [s], peak boarding rates [pax/h], boarding time per passenger
[s/pax], peak headway [s], platform re-occupation time [s], mean departure delay [s],
crowding gain [-] and full-train boarding time [s], plus ``MODEL_VERSION`` (bumped when the
traffic model's equations change, so weights trained on the old equations no longer match).

Names, station codes, distances and the daily periods are not inputs of the model and do
not enter the hash.  Floats are rounded to 1e-6 (of their SI unit) before hashing, so that
the hash does not depend on the last bit of a float computed on another machine.
"""

from __future__ import annotations

import hashlib
import json
from typing import Any, Dict

import numpy as np

from metro_atc.core.atr.blue_line import LineData

MODEL_VERSION = "metro_atc.atr.traffic/1"
"""Version of the traffic-model equations (part of every line hash)."""

_ARRAYS = ("run_s", "run_min_s", "run_max_s", "dwell_fixed_s", "dwell_fixed_min_s",
           "boarding_pax_h")
_SCALARS = ("hold_max_s", "t_board_s", "headway_s", "separation_min_s", "disturbance_mean_s",
            "crowding_gain", "board_max_s")


def _num(x: float) -> float:
    v = round(float(x), 6)
    return 0.0 if v == 0.0 else v  # -0.0 and 0.0 hash alike


def traffic_model_inputs(line: LineData) -> Dict[str, Any]:
    """The traffic-model inputs of ``line`` as plain JSON values (module docstring)."""
    out: Dict[str, Any] = {"model": MODEL_VERSION, "n_stations": int(line.n_stations)}
    for name in _ARRAYS:
        out[name] = [_num(v) for v in np.asarray(getattr(line, name), dtype=float).ravel()]
    for name in _SCALARS:
        out[name] = _num(getattr(line, name))
    return out


def line_hash(line: LineData) -> str:
    """sha256 (hex) of the canonical JSON of :func:`traffic_model_inputs`."""
    text = json.dumps(traffic_model_inputs(line), sort_keys=True, separators=(",", ":"),
                      allow_nan=False)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()
