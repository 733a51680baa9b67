#!/usr/bin/env bash
# Build pegs as a ROS 2 user does: a colcon workspace with this repository in src/, built by
# colcon-ros-cargo (pegs, through cargo-ament-build) and ament_cmake (pegs_msgs, msg/). The
# workspace lives in TARGET/colcon-ws and its cargo build directory is TARGET itself, so the
# release build the tests already made is reused, not repeated.
# Usage: colcon_build.sh VENV TARGET   (prints the install directory)
set -euo pipefail
VENV=$(cd "$1" && pwd)
TARGET=$(cd "$2" && pwd)
ROOT=$(cd "$(dirname "$0")/../.." && pwd)
TOOLS=$TARGET/cargo-tools
if [ ! -x "$TOOLS/bin/cargo-ament-build" ]; then
  cargo install --quiet --locked --root "$TOOLS" cargo-ament-build@0.1.11 >&2
fi
WS=$TARGET/colcon-ws
mkdir -p "$WS/src" "$WS/build"
ln -sfn "$ROOT" "$WS/src/pegs"
[ -L "$WS/build/pegs" ] || { rm -rf "$WS/build/pegs"; ln -s "$TARGET" "$WS/build/pegs"; }
cd "$WS"
# colcon does not look inside a package for others: both are named.
PATH=$VENV/bin:$TOOLS/bin:$PATH AMENT_PREFIX_PATH=$VENV \
  "$VENV/bin/colcon" build --base-paths src/pegs src/pegs/msg --cargo-args --release \
  --cmake-args -DPython3_EXECUTABLE="$VENV/bin/python" -DBUILD_TESTING=OFF -Wno-dev \
  > "$WS/build.log" 2>&1 || { tail -40 "$WS/build.log" >&2; exit 1; }
echo "$WS/install"
