#!/usr/bin/env bash
# Set up and run every pegs test on a fresh machine (Rust toolchain, Python 3 and git assumed).
# Installs Mesa's lavapipe so the wgpu renderer runs on the CPU, and the ffmpeg tool that decodes
# the real recording's videos (../shared/data/pusht_real); the full tier also makes a venv with
# MuJoCo and rosbags (tests/mujoco) that records scenes pegs did not simulate or render. Physics
# and rendering tests run in release mode: they simulate seconds of motion and render real images.
#
#   bash tests/run_all.sh                  the full tier (CI): formatting, lints, every test, the
#                                          rclpy tests of the node
#   bash tests/run_all.sh --fast           the fast tier: formatting, lints and the tests not
#                                          marked slow (every module, a few minutes once built)
#   bash tests/run_all.sh --all-concealed  the full tier with every concealed-physics scenario
#                                          diagnosed end to end (as for the README's table)
set -euo pipefail
cd "$(dirname "$0")/.."
TIER=full
for arg in "$@"; do
  case "$arg" in
    --fast) TIER=fast ;;
    --all-concealed) export PEGS_CONCEALED=all ;;
    *) echo "unknown option $arg (use --fast or --all-concealed)" >&2; exit 2 ;;
  esac
done

# The ROS 2 tests (tests/ros) also need a C/C++ toolchain (message bindings, colcon), venv and `ip netns`.
if ! ls /usr/share/vulkan/icd.d/lvp_icd*.json >/dev/null 2>&1 || ! command -v ffmpeg >/dev/null \
   || ! command -v g++ >/dev/null || ! command -v make >/dev/null || ! command -v ip >/dev/null \
   || ! python3 -c 'import ensurepip' 2>/dev/null; then
  SUDO=""
  if [ "$(id -u)" != 0 ]; then SUDO="sudo"; fi
  $SUDO apt-get update -qq
  $SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends mesa-vulkan-drivers libvulkan1 ffmpeg \
    g++ make iproute2 python3-venv >/dev/null
fi
# The tests write their recordings (up to a gigabyte per run) under the system temp directory:
# this run gets its own, removed when every test passed and kept, with its path said, when one failed.
SCRATCH=$(mktemp -d "${TMPDIR:-/tmp}/pegs-tests.XXXXXX")
export TMPDIR="$SCRATCH"
trap 'status=$?; if [ "$status" = 0 ]; then rm -rf "$SCRATCH"; else echo "tests failed: their files are kept in $SCRATCH" >&2; fi' EXIT
# Mesa wants a private runtime directory; without one it prints a harmless error on every start.
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-$(mktemp -d)}"
chmod 700 "$XDG_RUNTIME_DIR"

# rustfmt defaults and clippy without warnings.
if ! cargo fmt --version >/dev/null 2>&1 || ! cargo clippy --version >/dev/null 2>&1; then
  rustup component add rustfmt clippy
fi
cargo fmt --check
cargo clippy --release --locked --all-targets -- -D warnings

start=$(date +%s)
if [ "$TIER" = fast ]; then
  cargo test --release --locked
  echo "fast tier: tests took $(( $(date +%s) - start )) s"
  exit 0
fi
TARGET_DIR=$(cargo metadata --format-version 1 --no-deps --locked | python3 -c 'import json, sys; print(json.load(sys.stdin)["target_directory"])')
# Recordings pegs did not make (tests/mujoco.rs): MuJoCo and rosbags from PyPI in their own venv.
bash tests/mujoco/setup_venv.sh "$TARGET_DIR/mujoco-venv"
export PEGS_MUJOCO_PYTHON="$TARGET_DIR/mujoco-venv/bin/python"
cargo test --release --locked -- --include-ignored
echo "full tier: Rust tests took $(( $(date +%s) - start )) s"
# The node from Python: rclpy (ROS 2 Jazzy from PyPI) in a loopback-only network namespace.
bash tests/ros/run.sh "$TARGET_DIR/release/pegs"
echo "full tier: all tests took $(( $(date +%s) - start )) s"
