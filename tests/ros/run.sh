#!/usr/bin/env bash
# rclpy integration tests of `pegs node`. Sets up the venv (tests/ros/setup_venv.sh), builds pegs
# and pegs_msgs with colcon (tests/ros/colcon_build.sh, reusing PEGS_BINARY's cargo build), then
# runs pytest on the colcon-installed node and messages inside a fresh network namespace that has
# only the loopback interface (multicast on), so DDS traffic never leaves the machine and parallel
# runs do not see each other.
# Usage: run.sh PEGS_BINARY (target/release/pegs of the cargo build to reuse)
set -euo pipefail
ROOT=$(cd "$(dirname "$0")/../.." && pwd)
PEGS_BIN=$(realpath "$1")
TARGET=$(dirname "$(dirname "$PEGS_BIN")")
VENV=${PEGS_ROS_VENV:-$TARGET/ros-venv}
bash "$ROOT/tests/ros/setup_venv.sh" "$VENV"
INSTALL=$(bash "$ROOT/tests/ros/colcon_build.sh" "$VENV" "$TARGET")
PYVER=$("$VENV/bin/python" -c 'import sys; print(f"python{sys.version_info[0]}.{sys.version_info[1]}")')

SUDO=""
if [ "$(id -u)" != 0 ]; then SUDO="sudo"; fi
NS="pegs-test-$$"
$SUDO ip netns add "$NS"
$SUDO ip netns exec "$NS" ip link set lo up multicast on
$SUDO ip netns exec "$NS" ip route add 224.0.0.0/4 dev lo
# Images of 100s of kB arrive as bursts of datagrams: the default socket buffers drop them.
# These limits are not per namespace; the old values are restored on exit.
SAVED=$(sysctl -n net.core.rmem_max net.core.rmem_default net.core.wmem_max net.core.wmem_default | tr '\n' ' ')
restore() {
  read -r a b c d <<<"$SAVED"
  $SUDO sysctl -q -w net.core.rmem_max="$a" net.core.rmem_default="$b" net.core.wmem_max="$c" net.core.wmem_default="$d" || true
  $SUDO ip netns del "$NS" 2>/dev/null || true
}
trap restore EXIT
$SUDO sysctl -q -w net.core.rmem_max=16777216 net.core.rmem_default=16777216 net.core.wmem_max=16777216 net.core.wmem_default=16777216 \
  || echo "warning: could not raise socket buffers; large images may be dropped"

$SUDO ip netns exec "$NS" env \
  PEGS_BIN="$INSTALL/pegs/lib/pegs/pegs" PEGS_ROOT="$ROOT" PEGS_INSTALL="$INSTALL" \
  PYTHONPATH="$INSTALL/pegs_msgs/lib/$PYVER/site-packages" LD_LIBRARY_PATH="$INSTALL/pegs_msgs/lib" \
  AMENT_PREFIX_PATH="$INSTALL/pegs:$INSTALL/pegs_msgs:$VENV" \
  RMW_IMPLEMENTATION=rmw_fastrtps_cpp ROS_DISTRO=jazzy ROS_DOMAIN_ID=17 \
  FASTRTPS_DEFAULT_PROFILES_FILE="$ROOT/tests/ros/fastdds_loopback.xml" \
  XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-/tmp}" PYTHONUNBUFFERED=1 \
  "$VENV/bin/python" -m pytest -q -x -p no:cacheprovider "$ROOT/tests/ros" "${@:2}"
