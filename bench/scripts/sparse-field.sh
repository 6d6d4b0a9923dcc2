#!/usr/bin/env bash
# Issue 55's empty-space skipping (bench/results/sparse-field.md): does a decoder fine-tuned
# with the sparsity prior empty the air, and does skipping then pay, at the same quality?
#  1. `finetune-tokenizer-sparse-tiny.yaml`: the shipped tokenizer's decoder, 1,000 steps with
#     the prior at its weight 0.01 (about 11 minutes on 2 cores), and the same at 0.1.
#  2. Each, and the shipped weights, scored by `eval tokenizer` on the validation scenes
#     (seeds 9000-9001) and timed by the render benchmark (`--bin tokenizer`) on the real
#     nuScenes keyframe: occupied voxels, samples skipping evaluates, dense against skipping,
#     the render's parts, and where the kept LiDAR samples lie.
#  3. The page, from the JSON files (`--bin sparse_field`).
#   bench/scripts/sparse-field.sh [BEVWORLD_BINARY]
set -euo pipefail
cd "$(dirname "$0")/../.."
BIN="${1:-cargo run --release --}"
BENCH="cargo run --release -p bevworld-bench --bin"
CONFIG=configs/models/finetune-tokenizer-sparse-tiny.yaml
if [ ! -d out/synth-val ]; then
    $BIN synth --out out/synth-val --seed 9000 --scenes 2 --seconds 4 --camera-size 224x126
fi
mkdir -p out/weights
# NAME WEIGHT: a fine-tune, its weights copied to out/weights/NAME.bpk.
finetune() {
    if [ ! -f "runs/$1/tokenizer.bpk" ]; then
        $BIN train tokenizer --config "$CONFIG" --density-sparsity "$2" --out "runs/$1"
    fi
    cp "runs/$1/tokenizer.bpk" "out/weights/$1.bpk"
}
finetune tokenizer-sparse 0.01
finetune tokenizer-sparse-0.1 0.1
# NAME WEIGHTS: validation quality and the render benchmark (bench/results/NAME.json).
measure() {
    $BIN eval tokenizer --data out/synth-val --weights "$2" --out "out/eval-sparse-val-$1" --json \
        > "bench/results/sparse-field-val-$1.json"
    TOKENIZER_WEIGHTS="$2" TOKENIZER_RESULTS="$1" $BENCH tokenizer
}
measure tokenizer nodes/tokenizer/weights/tokenizer-tiny.bpk
measure tokenizer-sparse out/weights/tokenizer-sparse.bpk
measure tokenizer-sparse-0.1 out/weights/tokenizer-sparse-0.1.bpk
$BENCH sparse_field -- shipped=tokenizer "prior 0.01=tokenizer-sparse" "prior 0.1=tokenizer-sparse-0.1"
