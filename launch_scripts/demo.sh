#!/usr/bin/env bash
# Build pegs and run the main job (`pegs demo`) on a fresh machine. Only the Rust toolchain is
# assumed. Output: demo_out/trajectory.csv and demo_out/summary.json.
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release --locked
./target/release/pegs demo --config config/pegs.yaml --out demo_out "$@"
