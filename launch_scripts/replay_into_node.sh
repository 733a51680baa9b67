#!/usr/bin/env bash
# Play a pegs recording (a rosbag2 directory with MCAP storage, or an .mcap file) into a
# running-for-real `pegs node` over DDS, restamped to the wall clock, and print the node's
# statistics at the end. Needs the ROS venv of the tests (tests/ros/setup_venv.sh).
# Usage: replay_into_node.sh RECORDING CONFIG.yaml [VENV]
set -euo pipefail
ROOT=$(cd "$(dirname "$0")/.." && pwd)
REC=$(realpath "$1"); CONFIG=$(realpath "$2")
TARGET_DIR=$(cargo metadata --format-version 1 --no-deps --locked --manifest-path "$ROOT/Cargo.toml" | python3 -c 'import json, sys; print(json.load(sys.stdin)["target_directory"])')
VENV=${3:-$TARGET_DIR/ros-venv}
cargo build --release --locked --manifest-path "$ROOT/Cargo.toml" >&2
bash "$ROOT/tests/ros/setup_venv.sh" "$VENV" >&2
export RMW_IMPLEMENTATION=rmw_fastrtps_cpp
STATS=$(mktemp)
"$TARGET_DIR/release/pegs" node --config "$CONFIG" --stats "$STATS" &
NODE=$!
sleep 2
"$VENV/bin/python" "$ROOT/launch_scripts/play_recording.py" "$REC"
sleep 1
kill -INT "$NODE"; wait "$NODE" || true
cat "$STATS"
