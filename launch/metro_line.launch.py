"""Bring up the metro_atc graph on a full ROS 2 Jazzy install (``ros2 launch``).

    ros2 launch metro_atc metro_line.launch.py scenario:=taipei_blue regulator:=lqr

The same processes as ``python -m metro_atc run`` (both take them from
:func:`metro_atc.launcher.graph_processes`): the line simulator, the ATS, the brake
diagnosis, the ATO nodes composed ``ato_per_process`` to a process, and with ``record:=DIR``
the bag recorder (the lockstep then waits for it). The whole launch shuts down when the
line simulator exits (scenario end), as ``run`` does.
"""

from pathlib import Path

from launch import LaunchDescription
from launch.actions import (DeclareLaunchArgument, OpaqueFunction, RegisterEventHandler,
                            Shutdown)
from launch.event_handlers import OnProcessExit
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from metro_atc.core.atr.registry import REGULATORS

ARGUMENTS = {
    "scenario": ("taipei_blue", "embedded scenario name or path to a scenario YAML"),
    "regulator": ("none", "ATS regulator: " + REGULATORS.help()),
    "seed": ("0", "random seed of disturbances and sensor noise"),
    "lockstep": ("true", "deterministic lockstep (true) or free-run at real_time_factor"),
    "real_time_factor": ("10.0", "free-run pacing: simulated seconds per wall second"),
    "duration": ("0.0", "stop after this much simulated time [s] (0: scenario end)"),
    "out_dir": ("", "directory for kpis.json, events.csv and plots ('' : none)"),
    "plots": ("true", "write PNG plots into out_dir"),
    "ato_per_process": ("30", "ATO nodes composed per OS process"),
    "record": ("", "record every topic to this rosbag2 MCAP directory ('' : no)"),
    "checkpoints": ("false", "keep resume checkpoints/journals in out_dir/checkpoints (a "
                    "respawned node takes up where the run was); clear that directory "
                    "before reusing out_dir"),
}
"""Launch arguments: name -> (default, description)."""


def _true(text: str) -> bool:
    return text.strip().lower() in ("true", "1", "yes", "on")


def _nodes(context, *args, **kwargs):
    """Create the node actions once the launch arguments are known."""
    from metro_atc.core.line.scenario import load_scenario
    from metro_atc.launcher import graph_processes, scenario_train_ids

    a = {k: LaunchConfiguration(k).perform(context) for k in ARGUMENTS}
    procs = graph_processes(
        a["scenario"], scenario_train_ids(load_scenario(a["scenario"])),
        regulator=a["regulator"], seed=int(a["seed"]), lockstep=_true(a["lockstep"]),
        rtf=float(a["real_time_factor"]), duration_s=float(a["duration"]),
        out_dir=a["out_dir"], plots=_true(a["plots"]),
        ato_per_process=int(a["ato_per_process"]), record_dir=a["record"] or None,
        checkpoint_dir=str(Path(a["out_dir"]) / "checkpoints")
        if a["out_dir"] and _true(a["checkpoints"]) else "")
    # every node but the simulator is respawned (as ``run`` does; the simulator's exit ends
    # the launch); with checkpoints:=true they take up where the run was
    actions = [Node(package="metro_atc", executable=p.executable, output="screen",
                    parameters=([p.params_file] if p.params_file else []) + [p.params],
                    respawn=p.executable != "line_simulator", respawn_max_retries=3)
               for p in procs]
    actions.append(RegisterEventHandler(OnProcessExit(
        target_action=actions[0],
        on_exit=[Shutdown(reason="line_simulator exited (scenario end)")])))
    return actions


def generate_launch_description():
    """Launch arguments (see ARGUMENTS) and the graph."""
    return LaunchDescription(
        [DeclareLaunchArgument(k, default_value=d, description=text)
         for k, (d, text) in ARGUMENTS.items()] + [OpaqueFunction(function=_nodes)])
