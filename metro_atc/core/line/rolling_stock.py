"""Rolling stock of a scenario: the preset named by the scenario with its overrides (SI)."""

from __future__ import annotations


from metro_atc.core.line.scenario import Scenario
from metro_atc.core.line.vehicle import PRESETS, TrainParams, train_params_of_section

__all__ = ["KMH", "PRESETS", "train_params_for"]

KMH = 1.0 / 3.6
"""km/h -> m/s."""


def train_params_for(scn: Scenario) -> TrainParams:
    """Rolling stock of a scenario: its preset with the scenario's data applied."""
    return train_params_of_section(scn.trains, scn.energy)
