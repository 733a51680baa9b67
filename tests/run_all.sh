#!/usr/bin/env bash
# Set up and run every pegs test on a fresh machine (Rust toolchain, Python 3 and git assumed).
# Installs Mesa's lavapipe so the wgpu renderer runs on the CPU, and the ffmpeg tool that decodes
# the real recording's videos (../shared/data/pusht_real). Physics and rendering tests run in
# release mode: they simulate seconds of motion and render real images.
set -euo pipefail
cd "$(dirname "$0")/.."

# The ROS 2 tests (tests/ros) also need a C/C++ toolchain (message bindings), venv and `ip netns`.
if ! ls /usr/share/vulkan/icd.d/lvp_icd*.json >/dev/null 2>&1 || ! command -v ffmpeg >/dev/null \
   || ! command -v g++ >/dev/null || ! command -v make >/dev/null || ! command -v ip >/dev/null \
   || ! python3 -c 'import ensurepip' 2>/dev/null; then
  SUDO=""
  if [ "$(id -u)" != 0 ]; then SUDO="sudo"; fi
  $SUDO apt-get update -qq
  $SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends mesa-vulkan-drivers libvulkan1 ffmpeg \
    g++ make iproute2 python3-venv >/dev/null
fi
# Mesa wants a private runtime directory; without one it prints a harmless error on every start.
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-$(mktemp -d)}"
chmod 700 "$XDG_RUNTIME_DIR"

cargo test --release --locked
# The node from Python: rclpy (ROS 2 Jazzy from PyPI) in a loopback-only network namespace.
TARGET_DIR=$(cargo metadata --format-version 1 --no-deps --locked | python3 -c 'import json, sys; print(json.load(sys.stdin)["target_directory"])')
bash tests/ros/run.sh "$TARGET_DIR/release/pegs"
