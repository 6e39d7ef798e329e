"""Bring up the metro_atc graph on a full ROS 2 Jazzy install (``ros2 launch``).

    ros2 launch metro_atc metro_line.launch.py scenario:=taipei_blue regulator:=lqr

One ``ato_controller`` process per train is started here (namespaced ``/train_NN``); the
tested bring-up without ``launch`` is ``python -m metro_atc run`` (same executables).
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def _nodes(context, *args, **kwargs):
    """Create the node actions once the launch arguments are known."""
    from metro_atc.launcher import scenario_train_ids
    from metro_atc.core.line.scenario import load_scenario

    scenario = LaunchConfiguration("scenario").perform(context)
    regulator = LaunchConfiguration("regulator").perform(context)
    cfg = os.path.join(get_package_share_directory("metro_atc"), "config")
    common = {"use_sim_time": True, "scenario": scenario}
    actions = [
        Node(package="metro_atc", executable="line_simulator", name="line_simulator",
             parameters=[os.path.join(cfg, "line_simulator.yaml"), common]),
        Node(package="metro_atc", executable="ats_regulator", name="ats_regulator",
             parameters=[os.path.join(cfg, "ats_regulator.yaml"), common,
                         {"regulator": regulator}]),
        Node(package="metro_atc", executable="brake_diagnostic", name="brake_diagnostic",
             parameters=[os.path.join(cfg, "brake_diagnostic.yaml"), common]),
    ]
    for tid in scenario_train_ids(load_scenario(scenario)):
        actions.append(Node(package="metro_atc", executable="ato_controller",
                            name="ato_controller", namespace=tid,
                            parameters=[os.path.join(cfg, "ato_controller.yaml"), common,
                                        {"train_ids": [tid]}]))
    return actions


def generate_launch_description():
    """Launch arguments: scenario, regulator."""
    return LaunchDescription([
        DeclareLaunchArgument("scenario", default_value="taipei_blue"),
        DeclareLaunchArgument("regulator", default_value="none",
                              description="none | lqr | dhp | aoc"),
        OpaqueFunction(function=_nodes),
    ])
