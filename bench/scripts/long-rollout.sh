#!/usr/bin/env bash
# bench/results/long-rollout.{md,json,png}: the shipped world model chained for 20 s on two
# held-out scenes (test seeds 9502 and 9503, 24 s each), against chained latent baselines.
#   bench/scripts/long-rollout.sh [BEVWORLD_BINARY]
set -euo pipefail
cd "$(dirname "$0")/../.."
BIN="${1:-cargo run --release --}"
DATA=out/long-rollout/synth
LATENTS=out/long-rollout/latents
if [ ! -d "$DATA" ]; then
    $BIN synth --out "$DATA" --seed 9502 --scenes 2 --seconds 24 --camera-size 224x126
fi
if [ ! -f "$LATENTS/index.json" ]; then
    $BIN run configs/graphs/export_latents.yaml --set "data=$DATA" \
        --set "out=$LATENTS" --no-progress
fi
cargo run --release -p bevworld-bench --bin long_rollout -- "$LATENTS"
