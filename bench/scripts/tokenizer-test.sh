#!/usr/bin/env bash
# The tokenizer's test-range figures (bench/results/tokenizer-training.md, "Test range"): camera
# PSNR and SSIM and LiDAR Chamfer on the tokenizer's held-out test scenes, seeds 9200-9207
# (8 scenes of 4 s, 64 keyframes, made here), which no tokenizer setting was chosen on, and on
# the validation scenes 9000-9001 that the recipe was tuned on, for comparison.
#   bench/scripts/tokenizer-test.sh [WEIGHTS [BEVWORLD_BINARY]]
# WEIGHTS defaults to the shipped nodes/tokenizer/weights/tokenizer-tiny.bpk. Prints each
# split's table and writes both summaries to bench/results/tokenizer-test-<weights>.json.
set -euo pipefail
cd "$(dirname "$0")/../.."
WEIGHTS="${1:-nodes/tokenizer/weights/tokenizer-tiny.bpk}"
BIN="${2:-cargo run --release --}"
if [ ! -d out/synth-tokenizer-test ]; then
    $BIN synth --out out/synth-tokenizer-test --seed 9200 --scenes 8 --seconds 4 --camera-size 224x126
fi
if [ ! -d out/synth-val ]; then
    $BIN synth --out out/synth-val --seed 9000 --scenes 2 --seconds 4 --camera-size 224x126
fi
NAME="$(basename "$WEIGHTS" .bpk)"
for split in val:out/synth-val test:out/synth-tokenizer-test; do
    IFS=: read -r name data <<<"$split"
    $BIN eval tokenizer --data "$data" --weights "$WEIGHTS" --out "out/eval-tokenizer-$name-$NAME"
done
{
    printf '{"weights": "%s",\n"val": ' "$WEIGHTS"
    cat "out/eval-tokenizer-val-$NAME/summary.json"
    printf ',\n"test": '
    cat "out/eval-tokenizer-test-$NAME/summary.json"
    printf '}\n'
} > "bench/results/tokenizer-test-$NAME.json"
