"""Parameters mean what they say, and /diagnostics levels mean something (in-process nodes).

Static parameters are read-only (a runtime change is refused with a reason), dynamic ones
are applied by the on-set callback, enumerations carry their values in the descriptor.
The changes go through the parameter services, as ``ros2 param set`` sends them.
"""

from __future__ import annotations

from typing import Any, Iterator

import pytest

from metro_atc.nodes.common import OK, WARN


@pytest.fixture
def graph(ros_domain: int) -> Iterator[dict[str, Any]]:
    """The simulator, ATS and one ATO of ``mini`` plus a parameter client, one executor."""
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter
    from rclpy.parameter_client import AsyncParameterClient

    from metro_atc.nodes.ato_controller import AtoController
    from metro_atc.nodes.ats_regulator import AtsRegulator
    from metro_atc.nodes.line_simulator import LineSimulator

    ctx = Context()
    rclpy.init(context=ctx, domain_id=ros_domain)
    mini = [Parameter("scenario", value="mini")]
    nodes = {"sim": LineSimulator(context=ctx, parameter_overrides=mini),
             "ats": AtsRegulator(context=ctx, parameter_overrides=mini),
             "ato": AtoController("train_01", context=ctx, parameter_overrides=mini),
             "client": rclpy.create_node("param_client", context=ctx)}
    ex = SingleThreadedExecutor(context=ctx)
    for n in nodes.values():
        ex.add_node(n)

    def set_param(target: str, name: str, value: Any) -> Any:
        cli = AsyncParameterClient(nodes["client"], target)
        assert cli.wait_for_services(timeout_sec=10.0)
        fut = cli.set_parameters([Parameter(name, value=value)])
        ex.spin_until_future_complete(fut, timeout_sec=10.0)
        assert fut.done()
        return fut.result().results[0]

    try:
        yield dict(nodes, set=set_param, executor=ex)
    finally:
        ex.shutdown()
        for n in nodes.values():
            n.destroy_node()
        ctx.try_shutdown()


def test_static_parameters_are_refused_with_a_reason(graph: dict[str, Any]) -> None:
    """seed, regulator, planner: read-only at runtime; nothing changes."""
    for target, name, value in (("/line_simulator", "seed", 5),
                                ("/ats_regulator", "regulator", "lqr"),
                                ("/ats_regulator", "regulator", "bogus"),
                                ("/train_01/ato_controller", "planner", "dp")):
        r = graph["set"](target, name, value)
        assert not r.successful and r.reason, (target, name)
    assert graph["sim"].get_parameter("seed").value == 0
    assert graph["ats"].get_parameter("regulator").value == "none"
    assert graph["ato"].get_parameter("planner").value == "ectp"


def test_dynamic_parameters_take_effect(graph: dict[str, Any]) -> None:
    """step_timeout_s, diagnostics_period_s, log_level: applied at once; bad values refused."""
    import rclpy.logging

    sim = graph["sim"]
    r = graph["set"]("/line_simulator", "step_timeout_s", 2.5)
    assert r.successful and sim.params.step_timeout_s == 2.5
    r = graph["set"]("/line_simulator", "diagnostics_period_s", 0.25)
    assert r.successful and sim.params.rt.timer.timer_period_ns == 250_000_000
    r = graph["set"]("/line_simulator", "step_timeout_s", 1e6)  # out of the declared range
    assert not r.successful and sim.params.step_timeout_s == 2.5
    r = graph["set"]("/ats_regulator", "log_level", "debug")
    assert r.successful
    assert graph["ats"].get_logger().get_effective_level() == \
        rclpy.logging.LoggingSeverity.DEBUG
    r = graph["set"]("/ats_regulator", "log_level", "loud")
    assert not r.successful and "one of" in r.reason


def test_enumerations_carry_their_values(graph: dict[str, Any]) -> None:
    """The descriptors of regulator, planner, tracker, log_level list the allowed values."""
    from metro_atc.core.ato.registry import PLANNERS, TRACKERS
    from metro_atc.core.atr.registry import REGULATORS

    d = graph["ats"].describe_parameter("regulator")
    assert d.read_only and all(r in d.additional_constraints for r in REGULATORS)
    d = graph["ato"].describe_parameter("planner")
    assert all(p in d.additional_constraints for p in PLANNERS)
    d = graph["ato"].describe_parameter("tracker")
    assert all(t in d.additional_constraints for t in TRACKERS)
    d = graph["sim"].describe_parameter("log_level")
    assert not d.read_only and "debug" in d.additional_constraints


def test_lockstep_health_warns_on_misses_and_slow_real_time(graph: dict[str, Any]) -> None:
    """/diagnostics of the simulator: OK when running, WARN on a miss or a low RTF."""
    import time

    sim = graph["sim"]
    sim.started = True
    sim.health()
    sim.advance(sim.publish_step(), timed_out=False)
    time.sleep(0.01)
    st = sim.health()[0]
    assert st.level == OK and st.hardware_id == "line"
    keys = {kv.key for kv in st.values}
    assert {"real_time_factor", "lockstep_misses", "step_time_ms"} <= keys
    sim.advance(sim.publish_step(), timed_out=True)  # nobody sent a command: a miss
    assert sim.health()[0].level == WARN
    sim.advance(sim.publish_step(), timed_out=False)
    assert sim.health()[0].level == OK  # the next period: a step, no miss
    assert sim.health()[0].level == WARN  # a period without any step: stalled
    graph["set"]("/line_simulator", "min_real_time_factor", 1e6)
    sim.advance(sim.publish_step(), timed_out=False)
    st = sim.health()[0]
    assert st.level == WARN and "real-time factor" in st.message
    ato = graph["ato"].health()[0]
    assert ato.name == "ato_controller: train_01" and ato.hardware_id == "train_01"
    assert graph["ats"].health()[0].level == OK
