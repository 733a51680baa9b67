#!/usr/bin/env bash
# Start `pegs node` beside a Franka driver and three RealSense D455s (realsense2_camera with
# camera_name cam0 / cam1 / cam2, align_depth.enable true). Camera extrinsics come from the tf
# tree: the user publishes world -> camN_link on /tf_static (e.g. a hand-eye calibration), the
# drivers publish camN_link -> ... -> camN_color_optical_frame; joint states from the Franka
# driver's /joint_states. Extra arguments go to the node, e.g.
#   franka_3xd455.sh --ros-args -p correct.gain:=1000.0
# Usage: franka_3xd455.sh [CONFIG.yaml] [-- node arguments]
set -euo pipefail
ROOT=$(cd "$(dirname "$0")/.." && pwd)
CONFIG=$ROOT/config/franka_3xd455.yaml
if [ $# -gt 0 ] && [ "$1" != "--" ]; then CONFIG=$1; shift; fi
if [ "${1:-}" = "--" ]; then shift; fi
cargo build --release --locked --manifest-path "$ROOT/Cargo.toml" >&2
TARGET_DIR=$(cargo metadata --format-version 1 --no-deps --locked --manifest-path "$ROOT/Cargo.toml" | python3 -c 'import json, sys; print(json.load(sys.stdin)["target_directory"])')
cd "$ROOT"
exec "$TARGET_DIR/release/pegs" node --config "$CONFIG" "$@"
