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
# DDS stays on loopback (Fast DDS profile: shared memory + UDP bound to 127.0.0.1 only, no
# multicast; ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST when you bring your own profile).
# METRO_ATC_DDS=multihost opens it: default transports on every interface,
# multicast discovery, ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET. Set
# FASTRTPS_DEFAULT_PROFILES_FILE yourself to override the profile, or to "" to disable it.
if [ "${METRO_ATC_DDS:-loopback}" = "multihost" ]; then
  export ROS_AUTOMATIC_DISCOVERY_RANGE="${ROS_AUTOMATIC_DISCOVERY_RANGE:-SUBNET}"
  _METRO_ATC_PROFILE="$_METRO_ATC_ROOT/config/fastdds_profile_multihost.xml"
elif [ -z "${FASTRTPS_DEFAULT_PROFILES_FILE+x}" ]; then
  # the profile binds to loopback itself; the rmw's LOCALHOST mode would add a UDP transport
  # with sockets on 0.0.0.0 and on every interface address
  export ROS_AUTOMATIC_DISCOVERY_RANGE="${ROS_AUTOMATIC_DISCOVERY_RANGE:-SYSTEM_DEFAULT}"
  _METRO_ATC_PROFILE="$_METRO_ATC_ROOT/config/fastdds_profile.xml"
fi
export ROS_AUTOMATIC_DISCOVERY_RANGE="${ROS_AUTOMATIC_DISCOVERY_RANGE:-LOCALHOST}"
if [ -z "${FASTRTPS_DEFAULT_PROFILES_FILE+x}" ] && [ -n "${_METRO_ATC_PROFILE:-}" ]; then
  export FASTRTPS_DEFAULT_PROFILES_FILE="$_METRO_ATC_PROFILE"
fi
unset _METRO_ATC_PROFILE
export PYTHONDONTWRITEBYTECODE=1
unset _METRO_ATC_ROOT
