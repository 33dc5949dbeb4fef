#!/usr/bin/env bash
# Make sure Debian's ROS 1 Python packages are installed for the ROS 1 node tests (tests/ros).
# rospy, rosmaster and the message packages come from Debian 12 (no ROS apt repository); they are
# visible to /usr/bin/python3 only, and the tests run the ROS 1 processes with it. Installing needs
# root (CI runs as root); elsewhere this says what to run and the tests skip with that reason (or
# fail when CI is set). Does nothing when everything is there. rovlab itself and its numpy/numba go into
# .venv-ros1 (made from /usr/bin/python3 with --system-site-packages by `make ros1-env`).
set -euo pipefail

PKGS="python3-rospy python3-rosmaster python3-geometry-msgs python3-sensor-msgs python3-nav-msgs \
python3-std-msgs python3-diagnostic-msgs python3-venv"
if /usr/bin/python3 -c 'import rospy, rosmaster, geometry_msgs.msg, sensor_msgs.msg, nav_msgs.msg, diagnostic_msgs.msg, std_msgs.msg' 2>/dev/null; then
    exit 0
fi
if [ "$(id -u)" -ne 0 ]; then
    echo "ensure-ros1: Debian's ROS 1 packages are missing; the ROS 1 tests need them." >&2
    echo "ensure-ros1: install them with: sudo apt-get install --no-install-recommends $PKGS" >&2
    exit 0
fi
if ! command -v apt-get >/dev/null 2>&1; then
    echo "ensure-ros1: ROS 1 packages are missing and apt-get is not available; install them by hand." >&2
    exit 0
fi
echo "ensure-ros1: installing Debian's ROS 1 Python packages for the ROS 1 tests (apt-get) ..."
export DEBIAN_FRONTEND=noninteractive
apt-get update -qq >/dev/null
# shellcheck disable=SC2086
apt-get install -y -qq --no-install-recommends $PKGS >/dev/null
/usr/bin/python3 -c 'import rospy, rosmaster' && echo "ensure-ros1: rospy installed"
