#!/usr/bin/env bash
# Source ROS and the fohssv overlay, then run the given command.
set -e
# shellcheck disable=SC1090
source "/opt/ros/${ROS_DISTRO}/setup.bash"
source /fohssv/ros2_ws/install/setup.bash
exec "$@"
