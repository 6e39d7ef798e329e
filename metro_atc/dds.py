"""DDS and configuration defaults of the project (ROS-free: runs before ``rclpy.init``)."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path


def config_dir() -> Path:
    """The directory with the default parameter files (installed share/ or the source tree)."""
    try:
        from ament_index_python.packages import get_package_share_directory
        d = Path(get_package_share_directory("metro_atc")) / "config"
        if d.is_dir():
            return d
    except Exception:  # noqa: BLE001 - not installed: use the source tree
        pass
    return Path(__file__).resolve().parent.parent / "config"


def dds_defaults() -> None:
    """Apply the project's DDS defaults unless the user configured DDS: loopback only.

    With Fast DDS and neither ``FASTRTPS_DEFAULT_PROFILES_FILE`` nor
    ``ROS_AUTOMATIC_DISCOVERY_RANGE`` set (a shell without ``env.sh``), the installed
    loopback profile ``config/fastdds_profile.xml`` is used with the discovery range
    ``SYSTEM_DEFAULT`` (the rmw's ``LOCALHOST`` mode adds sockets on every interface);
    otherwise the range defaults to ``LOCALHOST``.  ``SKIP_DEFAULT_XML_FILE=1`` unless the
    current directory has a ``DEFAULT_FASTRTPS_PROFILES.xml`` (see below).  Must run
    before ``rclpy.init``.
    """
    env = os.environ
    if "FASTRTPS_DEFAULT_PROFILES_FILE" not in env and \
            "ROS_AUTOMATIC_DISCOVERY_RANGE" not in env and \
            env.get("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp") == "rmw_fastrtps_cpp":
        profile = config_dir() / "fastdds_profile.xml"
        if profile.is_file():
            env["FASTRTPS_DEFAULT_PROFILES_FILE"] = str(profile)
            env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "SYSTEM_DEFAULT"
    env.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    if not _default_xml_in_cwd():
        # Fast DDS also loads DEFAULT_FASTRTPS_PROFILES.xml from the current directory; in a
        # deleted directory (a removed temporary one) that look-up fails and Fast DDS logs
        # "[XMLPARSER Error] getcwd failed" / "realpath failed ... loadDefaultXMLFile" on
        # *stdout* (breaking ``--json``). With no such file there is nothing to load.
        env.setdefault("SKIP_DEFAULT_XML_FILE", "1")


def _default_xml_in_cwd() -> bool:
    """The current directory exists and holds a ``DEFAULT_FASTRTPS_PROFILES.xml``."""
    try:
        return (Path.cwd() / "DEFAULT_FASTRTPS_PROFILES.xml").is_file()
    except OSError:  # the current directory was deleted
        return False


SHM_CLEAN_TIMEOUT_S = 30.0
"""Wall-clock limit of one ``fastdds shm clean`` [s]."""


def clean_killed_shm() -> int | None:
    """Remove the Fast DDS shared-memory files that killed processes left; how many segments.

    A Fast DDS participant maps ``/dev/shm/fastrtps_<id>`` and holds a lock on its ``_el``
    file while it lives; a clean exit removes both, a SIGKILL leaves them (0.5 MiB each, for
    good).  Fast DDS's own tool ``fastdds shm clean`` removes the segments and ports whose
    lock nobody holds (their owner is dead; a live process's are kept): it is run here (the
    one next to this interpreter, else on ``PATH``).  None when the tool is not there or
    failed.
    """
    bin_dir = str(Path(os.path.realpath(sys.executable)).parent)
    tool = shutil.which("fastdds", path=os.pathsep.join(
        [str(Path(sys.executable).parent), bin_dir, os.environ.get("PATH", "")]))
    if tool is None:
        return None
    try:
        r = subprocess.run([tool, "shm", "clean"], capture_output=True, text=True,
                           timeout=SHM_CLEAN_TIMEOUT_S, stdin=subprocess.DEVNULL)
    except (OSError, subprocess.SubprocessError):
        return None
    m = re.search(r"(\d+) zombie segments cleaned", r.stdout)
    return int(m[1]) if r.returncode == 0 and m else None
