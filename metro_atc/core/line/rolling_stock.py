"""Rolling stock of a scenario: the preset named by the scenario with its overrides (SI)."""

from __future__ import annotations

import dataclasses
from typing import Any

from metro_atc.core.line.scenario import Scenario
from metro_atc.core.line.vehicle import THSR_700T, TAIPEI_MRT_6CAR, TrainParams

KMH = 1.0 / 3.6
"""km/h -> m/s."""

PRESETS: dict[str, TrainParams] = {"taipei_mrt_6car": TAIPEI_MRT_6CAR, "thsr_700t": THSR_700T}
"""Rolling-stock presets by scenario name."""


def train_params_for(scn: Scenario) -> TrainParams:
    """Rolling stock of a scenario: preset with the scenario overrides applied."""
    p = PRESETS[scn.trains.preset]
    over: dict[str, Any] = {}
    if scn.trains.mass_kg is not None:
        over["mass_kg"] = scn.trains.mass_kg
    if scn.trains.length_m is not None:
        over["length_m"] = scn.trains.length_m
    if scn.trains.max_speed_kmh is not None:
        over["max_speed_mps"] = scn.trains.max_speed_kmh * KMH
    if scn.trains.capacity_pax is not None:
        over["capacity_pax"] = scn.trains.capacity_pax
    e = scn.energy
    if e.traction_efficiency is not None:
        over["traction_efficiency"] = e.traction_efficiency
    if e.regen_efficiency is not None:
        over["regen_efficiency"] = e.regen_efficiency
    if e.aux_power_kw is not None:
        over["aux_power_w"] = e.aux_power_kw * 1e3
    return dataclasses.replace(p, **over) if over else p
