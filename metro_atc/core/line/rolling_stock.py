"""Rolling stock of a scenario: the preset named by the scenario with its overrides (SI)."""

from __future__ import annotations


from metro_atc.core.line.scenario import Scenario
from metro_atc.core.line.vehicle import (THSR_700T, TAIPEI_MRT_6CAR, TrainParams,
                                         train_params_from_spec)

KMH = 1.0 / 3.6
"""km/h -> m/s."""

PRESETS: dict[str, TrainParams] = {"taipei_mrt_6car": TAIPEI_MRT_6CAR, "thsr_700t": THSR_700T}
"""Rolling-stock presets by scenario name."""


def train_params_for(scn: Scenario) -> TrainParams:
    """Rolling stock of a scenario: its preset with the scenario's data applied."""
    return train_params_from_spec(PRESETS[scn.trains.preset], scn.trains, scn.energy)
