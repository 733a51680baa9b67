#!/usr/bin/env bash
# Build pegs and run only its rclpy integration tests (tests/ros) in a loopback-only netns.
# Extra arguments go to pytest, e.g. ros_tests.sh -k parameters -s
set -euo pipefail
ROOT=$(cd "$(dirname "$0")/.." && pwd)
cargo build --release --locked --manifest-path "$ROOT/Cargo.toml"
TARGET_DIR=$(cargo metadata --format-version 1 --no-deps --locked --manifest-path "$ROOT/Cargo.toml" | python3 -c 'import json, sys; print(json.load(sys.stdin)["target_directory"])')
exec bash "$ROOT/tests/ros/run.sh" "$TARGET_DIR/release/pegs" "$@"
