#!/bin/bash
# A user's non-editable install, used outside the clone: a fresh venv (DIR, default a new
# temporary directory), the pinned requirements (base.txt and ros.txt, or ROS_DISTRO=jazzy:
# floor.txt and ros-jazzy.txt), `pip install .`, then from another directory:
# qfa_node --version, qfa-sim, the shipped files found through the share directory and
# ament_index, and the node started on the shipped parameters file, streaming to a
# SensorDataQoS subscriber of the same venv. ROS_DOMAIN_ID (default 148) isolates it.
# Usage: bash bench/fresh_install.sh [DIR]   (about 2-5 min, most of it pip)
set -euo pipefail
CLONE=$(cd "$(dirname "$0")/.." && pwd)
DIR=${1:-$(mktemp -d)}
mkdir -p "$DIR"
if [ "${ROS_DISTRO:-kilted}" = jazzy ]; then
  REQUIREMENTS="-r $CLONE/requirements/floor.txt -r $CLONE/requirements/ros-jazzy.txt"
else
  REQUIREMENTS="-r $CLONE/requirements/base.txt -r $CLONE/requirements/ros.txt"
fi
export ROS_DOMAIN_ID=${ROS_DOMAIN_ID:-148} ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
run() { echo "\$ $*"; "$@"; echo; }
cd "$DIR"
run python3 -m venv venv
run venv/bin/pip install -q --disable-pip-version-check $REQUIREMENTS
run venv/bin/pip install -q --disable-pip-version-check "$CLONE"
rm -rf "$CLONE/build"  # pip's in-tree build directory
mkdir -p elsewhere && cd elsewhere
VENV=$DIR/venv
run "$VENV/bin/qfa_node" --version
run "$VENV/bin/python" -c 'import qfa_ros; print(qfa_ros.__file__)'
run "$VENV/bin/qfa-sim" static --duration 2 --seed 1
run env AMENT_PREFIX_PATH="$VENV" "$VENV/bin/python" -c \
  'from ament_index_python.packages import get_package_share_directory as share
from qfa_ros.ros.fastdds import shipped_fastdds_profile
print(share("qfa_ros")); print(shipped_fastdds_profile())'
run ls "$VENV/share/qfa_ros" "$VENV/share/qfa_ros/config" "$VENV/share/qfa_ros/launch"
SHARE=$(AMENT_PREFIX_PATH="$VENV" "$VENV/bin/python" -c \
  'from ament_index_python.packages import get_package_share_directory as s; print(s("qfa_ros"))')
echo "\$ $VENV/bin/qfa_node --ros-args --params-file $SHARE/config/qfa.yaml -p state_file:=$PWD/out/calibration.json -p output_dir:=$PWD/out &"
"$VENV/bin/qfa_node" --ros-args --params-file "$SHARE/config/qfa.yaml" \
  -p "state_file:=$PWD/out/calibration.json" \
  -p "output_dir:=$PWD/out" > node.log 2>&1 &
NODE=$!
cat > count.py <<'PY'
import time
import rclpy
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import Imu
rclpy.init()
node = rclpy.create_node('qfa_install_check')
stamps = []
node.create_subscription(Imu, 'imu/data_raw', lambda m: stamps.append(m.header.stamp),
                         qos_profile_sensor_data)
deadline = time.monotonic() + 300
while len(stamps) < 2000 and time.monotonic() < deadline:
    rclpy.spin_once(node, timeout_sec=0.1)
print(f'{len(stamps)} samples on imu/data_raw (SensorDataQoS)')
PY
run "$VENV/bin/python" count.py
kill -INT $NODE; wait $NODE || true
echo "\$ cat node.log"; cut -c1-200 node.log
