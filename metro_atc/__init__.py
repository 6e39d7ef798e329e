"""metro_atc: a ROS 2 Jazzy node graph emulating a metro signalling / ATC system.

ROS-free algorithm and physics code lives in :mod:`metro_atc.core`; ROS nodes live in
:mod:`metro_atc.nodes`.
"""

__version__ = "0.1.0"
