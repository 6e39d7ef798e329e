# Source me:  source env.sh
# Gives a shell where `python -m metro_atc ...`, the node executables and pytest work:
# the project virtualenv (ROS 2 Jazzy from PyPI wheels), the colcon install space, and the
# DDS defaults of this project (discovery stays on loopback unless you set otherwise).
_METRO_ATC_ROOT="$(cd "$(dirname "${BASH_SOURCE[0]:-$0}")" && pwd)"
if [ -f /opt/ros/jazzy/setup.bash ] && [ ! -x "$_METRO_ATC_ROOT/.venv/bin/python" ]; then
  # a real ROS 2 Jazzy install
  source /opt/ros/jazzy/setup.bash
else
  source "$_METRO_ATC_ROOT/.venv/bin/activate"
  source "$_METRO_ATC_ROOT/.venv/local_setup.bash"
fi
source "$_METRO_ATC_ROOT/install/local_setup.bash"
export ROS_AUTOMATIC_DISCOVERY_RANGE="${ROS_AUTOMATIC_DISCOVERY_RANGE:-LOCALHOST}"
# Fast DDS profile with a short participant announcement period (faster discovery on
# loopback). Set FASTRTPS_DEFAULT_PROFILES_FILE yourself to override, or to "" to disable.
if [ -z "${FASTRTPS_DEFAULT_PROFILES_FILE+x}" ]; then
  export FASTRTPS_DEFAULT_PROFILES_FILE="$_METRO_ATC_ROOT/config/fastdds_profile.xml"
fi
export PYTHONDONTWRITEBYTECODE=1
unset _METRO_ATC_ROOT
