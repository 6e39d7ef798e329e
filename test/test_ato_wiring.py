"""The ato_controller node and the ROS-free closed loop wire the ATO identically.

``bench lines`` measures :func:`metro_atc.core.closed_loop.run_closed_loop`; it measures
what the graph runs only if every train's OnboardAto is built from the same parts.  Both
take them from :func:`metro_atc.core.ato.wiring.ato_wiring`; here the node's parts (an
in-process ``AtoController``) and the closed loop's (a run of zero simulated seconds) are
compared, part by part, bit for bit, on the embedded lines and a generated one.
"""

from __future__ import annotations

from typing import Any, Callable, Iterator

import pytest

from metro_atc.core.ato.wiring import MmasSettings, ato_wiring, planner_params
from metro_atc.core.closed_loop import run_closed_loop
from metro_atc.core.line.scenario import Scenario, load_scenario
from metro_atc.core.linegen import load_generated

SCENARIOS: dict[str, Callable[[], Scenario]] = {
    "taipei_blue": lambda: load_scenario("taipei_blue"),
    "mini": lambda: load_scenario("mini"),
    "thsr": lambda: load_scenario("thsr"),
    "generated_7": lambda: load_generated(7, incidents=True),
}


@pytest.fixture
def node_wiring(ros_domain: int) -> Iterator[Callable[..., dict[str, Any]]]:
    """Build an in-process AtoController of a scenario; return its wiring's summary."""
    import rclpy
    from rclpy.context import Context
    from rclpy.parameter import Parameter

    from metro_atc.nodes.ato_controller import AtoController

    ctx = Context()
    rclpy.init(context=ctx, domain_id=ros_domain)
    nodes: list[Any] = []

    def build(scn: Scenario, planner: str, tracker: str) -> dict[str, Any]:
        from metro_atc.core.bridge import timetable_for
        tid = timetable_for(scn).train_ids[-1]
        node = AtoController(tid, scenario=scn, shared={}, context=ctx, parameter_overrides=[
            Parameter("planner", value=planner), Parameter("tracker", value=tracker)])
        nodes.append(node)
        assert node.onboard.core.planner == planner
        assert node.onboard.core.tracker_name == tracker
        summary: dict[str, Any] = node.wiring.summary()
        return summary

    try:
        yield build
    finally:
        for n in nodes:
            n.destroy_node()
        ctx.try_shutdown()


@pytest.mark.parametrize("name", list(SCENARIOS))
def test_node_and_closed_loop_build_the_same_ato(name: str, node_wiring: Any) -> None:
    """Same train, track, stops, limits, TSRs, ATP model, period, planner and tracker."""
    scn = SCENARIOS[name]()
    planner, tracker = ("mmas", "pi") if name == "mini" else ("ectp", "fuzzy")
    res = run_closed_loop(scn, planner=planner, tracker=tracker, duration_s=0.0)
    assert res.ato is not None
    loop = res.ato.summary()
    node = node_wiring(scn, planner, tracker)
    assert node == loop, {k: (node[k], loop[k]) for k in node if node[k] != loop[k]}
    assert loop["planner"] == planner and loop["tracker"] == tracker


def test_the_comparison_sees_a_difference() -> None:
    """A wiring of another line, planner or MMAS setting differs (the test can fail)."""
    mini = ato_wiring(load_scenario("mini"))
    assert ato_wiring(load_scenario("thsr")).summary() != mini.summary()
    assert ato_wiring(load_scenario("mini"), tracker="pi").summary() != mini.summary()
    a = ato_wiring(load_scenario("mini"), "mmas")
    b = ato_wiring(load_scenario("mini"), "mmas", mmas=MmasSettings(n_ants=10))
    assert a.summary() != b.summary()
    assert ato_wiring(load_scenario("mini")).summary() == mini.summary()


def test_planner_params_only_for_mmas() -> None:
    """The MMAS settings go to the planner; the others take no extra parameters."""
    assert planner_params("ectp", MmasSettings(n_ants=3)) == {}
    assert planner_params("mmas") == {"n_ants": 50, "n_iterations": 100, "n_sections": 50}
    with pytest.raises(ValueError, match="unknown planner"):
        planner_params("nope")
