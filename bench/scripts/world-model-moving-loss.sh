#!/usr/bin/env bash
# Issue 51's "a loss that counts what moves", measured on the validation scenes (seeds
# 9100-9101) only: the recipe's world model (`bevworld train world-model --out runs/wm-tiny`,
# shipped until the stop fine-tune) fine-tuned 300 steps with the moving-weighted loss and, as
# its ablation, 300 steps with the plain loss, each forecast through the graph beside the
# recipe's weights (sweeps only: the Chamfer distance and the agents' scores read them).
# About 35 min on 2 cores after the recipe's run.
#   bench/scripts/world-model-moving-loss.sh [BEVWORLD_BINARY]
set -euo pipefail
cd "$(dirname "$0")/../.."
BIN="${1:-cargo run --release --}"
for loss in moving plain; do
    if [ ! -f "runs/wm-ft-$loss/world-model-tiny.bpk" ]; then
        $BIN train world-model --config "configs/models/finetune-world-model-$loss-tiny.yaml" \
            --out "runs/wm-ft-$loss"
    fi
done
for weights in recipe:runs/wm-tiny/world-model-tiny.bpk \
    moving:runs/wm-ft-moving/world-model-tiny.bpk plain:runs/wm-ft-plain/world-model-tiny.bpk; do
    IFS=: read -r name path <<<"$weights"
    $BIN eval forecast --data out/synth-wm-val --out "out/eval-forecast-val-$name" \
        --set "models.tiny.world_model.weights=$path" --set "sensors=[lidar]" \
        --set "methods=[model,latent_ego_warp,oracle]" \
        --json > "bench/results/world-model-moving-loss-val-$name.json"
done
# The table of bench/results/world-model-training.md, generated from those files.
cargo run --release -p bevworld-bench --bin forecast_tables -- --compare \
    recipe=bench/results/world-model-moving-loss-val-recipe.json \
    "moving loss=bench/results/world-model-moving-loss-val-moving.json" \
    "plain loss=bench/results/world-model-moving-loss-val-plain.json"
