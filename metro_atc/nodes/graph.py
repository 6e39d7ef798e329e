"""The whole graph in one process on one SingleThreadedExecutor (``run --single-process``).

Same node classes and topics as the multi-process bring-up; useful for debugging and
profiling (one process to attach to) and on machines where process start-up dominates.
"""

from __future__ import annotations

import argparse
import os
import sys
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator, Sequence

import rclpy
from rclpy.exceptions import ParameterException
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.signals import SignalHandlerOptions

from metro_atc.core.bridge import timetable_for
from metro_atc.core.service.dayrun import load_run_scenario
from metro_atc.exit_codes import Exit
from metro_atc.nodes.ato_controller import AtoController, FleetLink
from metro_atc.nodes.ats_regulator import AtsRegulator
from metro_atc.nodes.brake_diagnostic import BrakeDiagnostic
from metro_atc.nodes.common import NodeConfigError
from metro_atc.nodes.line_simulator import LineSimulator
from metro_atc.nodes.sim_lockstep import lockstep_loop


def _overrides(values: dict[str, Any]) -> list[Parameter]:
    return [Parameter(k, value=v) for k, v in values.items()]


@contextmanager
def stdout_on_stderr() -> Iterator[None]:
    """Point file descriptor 1 at stderr for the block (Python's and the C libraries').

    DDS and rcl log from C++ straight to fd 1 (Fast DDS's ``[XMLPARSER Error] ...
    loadDefaultXMLFile`` in a deleted current directory, for one): in this process that is
    the launcher's stdout, where ``--json`` prints one line after the run.
    """
    sys.stdout.flush()
    saved = os.dup(1)
    os.dup2(2, 1)
    try:
        yield
    finally:
        sys.stdout.flush()
        os.dup2(saved, 1)
        os.close(saved)


def run_single_process(a: argparse.Namespace, train_ids: Sequence[str], out_dir: Path) -> int:
    """Run the scenario with every node in this process; return an exit code.

    While the nodes exist, stdout goes to stderr (:func:`stdout_on_stderr`).
    """
    with stdout_on_stderr():
        return _run_graph(a, train_ids, out_dir)


def _run_graph(a: argparse.Namespace, train_ids: Sequence[str], out_dir: Path) -> int:
    """Build the nodes, run the lockstep, destroy them (see :func:`run_single_process`)."""
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    # SIGINT raises KeyboardInterrupt here; the context is shut down once, at the end
    rclpy.init(args=["metro_atc_graph"], signal_handler_options=SignalHandlerOptions.NO)
    nodes: list[Node] = []
    stage = "line_simulator"
    try:
        common = {"use_sim_time": True, "scenario": a.scenario}
        sim = LineSimulator(parameter_overrides=_overrides(dict(
            common, seed=a.seed, lockstep=not a.free_run, real_time_factor=a.rtf,
            out_dir=str(out_dir), plots=a.plots, max_sim_time_s=float(a.duration))))
        nodes.append(sim)
        stage = "ats_regulator"
        nodes.append(AtsRegulator(parameter_overrides=_overrides(
            dict(common, regulator=a.regulator,
                 **({"weights_file": a.weights_file} if getattr(a, "weights_file", "")
                    else {})))))
        stage = "brake_diagnostic"
        nodes.append(BrakeDiagnostic(parameter_overrides=_overrides(common)))
        stage = "ato_controller"
        scn = load_run_scenario(a.scenario)
        tt = timetable_for(scn)
        shared: dict[str, Any] = {}
        atos = [AtoController(tid, scenario=scn, timetable=tt, shared=shared,
                              parameter_overrides=_overrides(common)) for tid in train_ids]
        nodes.extend(atos)
        if atos:
            FleetLink(atos)  # kept alive by its subscription on atos[0]
    except (NodeConfigError, ParameterException, ValueError) as exc:
        print(f"metro_atc run: error: {stage} cannot start: {exc}", file=sys.stderr)
        for n in nodes:
            n.destroy_node()
        rclpy.try_shutdown()
        return Exit.NODE_FAILED  # as a node that refuses in the multi-process graph
    try:
        executor = SingleThreadedExecutor()
        for n in nodes:
            executor.add_node(n)
        code = 0
        try:
            lockstep_loop(executor, sim, fast_path=False)
        except KeyboardInterrupt:
            code = Exit.INTERRUPTED
        except NodeConfigError as exc:  # the simulator gave up (GraphNotReady)
            print(f"metro_atc run: error: line_simulator: {exc}", file=sys.stderr)
            code = exc.code
        try:
            sim.close()
        except OSError as exc:  # its outputs: the launcher finds no kpis.json or says why
            print(f"metro_atc run: error: line_simulator: {exc}", file=sys.stderr)
            code = code or Exit.OUTPUTS_NOT_WRITTEN
        return int(code)
    finally:
        for n in nodes:
            n.destroy_node()
        rclpy.try_shutdown()
