#!/usr/bin/env bash
# Track the real T-block recording (../shared/data/pusht_real): import it into a recording and a
# replay configuration, then replay it. Output in real_out/: objects.csv, metrics.json (start
# alignment, table fit, silhouette IoU per camera), silhouette_iou.csv and contact_sheet.png.
# Needs the ffmpeg tool (apt-get install ffmpeg). Extra arguments go to `pegs replay`.
set -euo pipefail
cd "$(dirname "$0")/.."
DATA="${PEGS_REAL_DATA:-../shared/data/pusht_real}"
mkdir -p real_out
cargo run --release --locked -- import embodied-gaussians "$DATA" --out real_out/recording --config-out real_out/config.yaml
cargo run --release --locked -- replay real_out/recording --config real_out/config.yaml --out real_out "$@"
