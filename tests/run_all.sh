#!/usr/bin/env bash
# Set up and run every pegs test on a fresh machine (Rust toolchain, Python 3 and git assumed).
# Physics and rendering tests run in release mode: they simulate seconds of motion.
set -euo pipefail
cd "$(dirname "$0")/.."
cargo test --release --locked
