#!/usr/bin/env bash
# Build pegs and run the main job (`pegs demo`) on a fresh machine. Only the Rust toolchain is
# assumed. Output: demo_out/trajectory.csv, summary.json, start.png, end.png, and the diagnosis
# story on a concealed scenario: story.md and story/ (report, model, plots).
set -euo pipefail
cd "$(dirname "$0")/.."
cargo run --release --locked -- demo --config config/pegs.yaml --out demo_out "$@"
