#!/bin/sh
# The handler image FROM ros:jazzy (Dockerfile.jazzy): ROS 2's environment, then that of
# edgerv_msgs (the typed verdicts, installed by CMake into /opt/edgerv_msgs, no colcon:
# its prefix, libraries and Python package named here), then edgerv with the arguments.
set -e
. /opt/ros/jazzy/setup.sh
prefix=/opt/edgerv_msgs
python=$(python3 -c 'import sys; print(f"python{sys.version_info[0]}.{sys.version_info[1]}")')
export AMENT_PREFIX_PATH="$prefix${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}"
export LD_LIBRARY_PATH="$prefix/lib${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}"
export PYTHONPATH="$prefix/lib/$python/site-packages${PYTHONPATH:+:$PYTHONPATH}"
exec edgerv "$@"
