#!/usr/bin/env bash
# The main job on the bundled default: a generated office building and a 600-keyframe walk
# with a drifting front-end, corrected online and offline, measured against ground truth and
# the seed paper's baselines, with a Rerun recording. Usage: scripts/demo.sh [OUTDIR]
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/setup_env.sh
OUT="${1:-demo_out}"
mkdir -p "$OUT"
start=$(date +%s)
bimgraph simulate -o "$OUT/seq" --scenario office --sensor planes --keyframes 600 --seed 1
bimgraph run "$OUT/seq" -o "$OUT/online" --mode online --rrd "$OUT/demo.rrd"
bimgraph run "$OUT/seq" -o "$OUT/offline" --mode offline
bimgraph eval "$OUT/online" "$OUT/offline" --gt "$OUT/seq"
echo
echo "demo finished in $(( $(date +%s) - start )) s. Outputs in $OUT/online and $OUT/offline (formats: docs/formats.md)."
echo "Open the recording with:  $(dirname "$(command -v bimgraph)")/rerun $OUT/demo.rrd"
