"""Operator plots: only trains that ran, incidents shaded, the energy breakdown adds up."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from metro_atc.core.plant.driver import simple_driver
from metro_atc.core.plant.line import LineSim
from metro_atc.core.line.scenario import IncidentSpec, load_scenario
from metro_atc.plots import energy_terms, plot_energy, plot_train_graph, ran_trains


EFF = 0.8
"""Substation-to-wheel traction efficiency set in the test scenario."""


def _sim(stop_s: float) -> LineSim:
    """``mini`` with a TSR window and a breakdown, stepped to ``stop_s`` by the simple driver."""
    scn = load_scenario("mini")
    scn = dataclasses.replace(scn, energy=dataclasses.replace(scn.energy,
                                                              traction_efficiency=EFF),
                              incidents=[
        IncidentSpec(kind="tsr", at_s=60.0, duration_s=240.0, start_m=1200.0, end_m=1700.0,
                     limit_kmh=30.0),
        IncidentSpec(kind="breakdown", train="train_01", at_s=150.0, duration_s=20.0)])
    sim = LineSim(scn, seed=0)
    while not sim.done and sim.t < stop_s:
        sim.step(simple_driver(sim))
    return sim


def test_only_trains_that_ran_and_incident_shading(tmp_path: Path) -> None:
    """A run stopped before train_02 enters draws train_01 only, with the TSR and breakdown."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sim = _sim(120.0)
    first_dep = float(np.nanmin(sim.service.sched_dep[1]))
    assert first_dep > 120.0, "scenario changed: train_02 should start after 120 s"
    assert ran_trains(sim) == [0]
    captured = {}
    real_savefig = plt.Figure.savefig

    def grab(fig: plt.Figure, *a: object, **k: object) -> None:
        captured["ax"] = fig.axes[0]
        real_savefig(fig, *a, **k)

    plt.Figure.savefig = grab  # type: ignore[method-assign]
    try:
        plot_train_graph(sim, tmp_path / "tg.png")
    finally:
        plt.Figure.savefig = real_savefig  # type: ignore[method-assign]
    ax = captured["ax"]
    labels = [t.get_text() for t in ax.texts]
    assert "T01" in labels and "T02" not in labels
    assert any("TSR 30 km/h" in t for t in labels)
    assert [t.get_text() for t in ax.get_yticklabels()][0].endswith(sim.station_names[0])
    assert ax.get_xlim()[1] < 5.0  # minutes: the axis ends with the run, not the timetable


def test_energy_breakdown_adds_up(tmp_path: Path) -> None:
    """traction + conversion + auxiliaries - regeneration = substation net, per train."""
    sim = _sim(1e9)
    e = energy_terms(sim)
    lhs = e["traction"] + e["conversion"] + e["auxiliaries"] + e["regen_returned"]
    np.testing.assert_allclose(lhs, e["net"], rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(e["conversion"], e["traction"] * (1.0 / EFF - 1.0), rtol=1e-9,
                               atol=1e-9)
    assert (e["braking_losses"] >= -1e-9).all() and (e["regen_returned"] <= 0.0).all()
    k = sim.kpis()["energy"]
    assert abs(e["net"].sum() - k["substation_net_kwh"]) < 1e-6
    plot_energy(sim, tmp_path / "energy.png")
    assert (tmp_path / "energy.png").stat().st_size > 10_000


def test_dispatched_tsr_drawn_like_a_scripted_one(tmp_path: Path) -> None:
    """A TSR a dispatcher imposed (and lifted) is shaded on the train graph and the speed
    plot with its limit, from its from_s to its lift, as the scripted one is."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from metro_atc.core.dispatcher_commands import (KIND_TSR_IMPOSE, KIND_TSR_LIFT, Command,
                                                    Dispatcher)
    from metro_atc.plots import _tsr_windows, plot_speed_profile
    sim = LineSim(load_scenario("mini"), seed=0)
    d = Dispatcher(sim)
    assert d.submit(Command(KIND_TSR_IMPOSE, start_m=300.0, end_m=700.0, speed_mps=12.5,
                            from_s=140.0, tsr_id="works"))[0]
    while sim.t < 200.0:
        if abs(sim.t - 180.0) < 1e-9:
            assert d.submit(Command(KIND_TSR_LIFT, tsr_id="works"))[0]
        d.apply_due(sim.step_count)
        sim.step(simple_driver(sim))
    assert _tsr_windows(sim, 1e9) == [(300.0, 700.0, 140.0, 180.0, 45.0)]
    texts: list[list[str]] = []
    real_savefig = plt.Figure.savefig

    def grab(fig: plt.Figure, *a: object, **k: object) -> None:
        texts.append([t.get_text() for t in fig.axes[0].texts])
        real_savefig(fig, *a, **k)

    plt.Figure.savefig = grab  # type: ignore[method-assign]
    try:
        plot_train_graph(sim, tmp_path / "tg.png")
        plot_speed_profile(sim, 0, tmp_path / "sp.png")
    finally:
        plt.Figure.savefig = real_savefig  # type: ignore[method-assign]
    assert any("TSR 45 km/h" in t for t in texts[0])
    assert any("TSR 45 km/h" in t and "2-3 min" in t for t in texts[1])
