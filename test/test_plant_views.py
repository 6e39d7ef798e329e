"""The plant views the line simulator publishes: the same values as LineSim.states()."""

from __future__ import annotations

import math

import numpy as np
import pytest

from metro_atc.core.line.scenario import load_scenario
from metro_atc.core.plant.driver import simple_driver
from metro_atc.core.plant.line import LineSim
from metro_atc.core.plant.views import FLEET_KEYS, dwelling_in_service, fleet_state_rows
from metro_atc.nodes.wire import cdr, fleet_state


def _check(sim: LineSim, rng: np.random.Generator) -> int:
    """Compare the views with states() for the active trains, all and a random subset."""
    st = sim.states()
    active = np.flatnonzero(np.asarray(sim.active_mask(), dtype=bool))
    subset = np.sort(rng.choice(sim.n, size=rng.integers(0, sim.n + 1), replace=False))
    for rows in (active, np.arange(sim.n), subset, subset[::-1].copy()):
        got = fleet_state_rows(sim, rows)
        assert set(got) == set(FLEET_KEYS)
        for key in FLEET_KEYS:
            want = np.asarray(st[key])[rows]
            assert got[key].dtype == want.dtype, key
            np.testing.assert_array_equal(got[key], want, err_msg=key)
    dwell = np.flatnonzero((st["mode"] == 1) & st["in_service"])  # TrainState.MODE_DWELL
    assert dwelling_in_service(sim) == [(int(i), int(st["current_station"][i])) for i in dwell]
    return len(dwell)


@pytest.mark.parametrize("scenario,every", [("mini", 7), ("taipei_blue", 23)])
def test_fleet_state_rows_are_the_states_entries(scenario: str, every: int) -> None:
    """Over a whole run (waiting, running, dwelling, turning back, done trains; commanded
    departures and running times), every view equals the states' entries."""
    sim = LineSim(load_scenario(scenario), seed=3)
    rng = np.random.default_rng(0)
    dwelling_seen = 0
    k = 0
    while not sim.done and k < 3000:
        if k % every == 0:
            dwelling_seen += _check(sim, rng)
            for i, j in dwelling_in_service(sim)[:2]:
                if j < sim.n_st - 1:  # an ATS command: departure and running time
                    sim.set_departure(i, j, float(sim.t) + 5.0, 90.0, math.nan)
        sim.step(simple_driver(sim))
        k += 1
    _check(sim, rng)
    assert dwelling_seen > 0


def test_fleet_state_rows_cdr_is_fleet_state_cdr() -> None:
    """The bytes built from the rows are those built from the full state arrays."""
    sim = LineSim(load_scenario("taipei_blue"), seed=0)
    for _ in range(1500):
        sim.step(simple_driver(sim))
    idx = np.flatnonzero(np.asarray(sim.active_mask(), dtype=bool))
    assert idx.size > 2
    ids = [f"train_{i:02d}" for i in idx]
    builder = fleet_state.Builder(cdr.string_seq(ids), idx.size)
    echo = np.arange(idx.size) % 2 == 0
    want = fleet_state.from_core(builder, idx, sim.states(), 1500, float(sim.t), echo)
    got = fleet_state.from_core_rows(builder, idx.size, fleet_state_rows(sim, idx), 1500,
                                     float(sim.t), echo)
    assert got == want
