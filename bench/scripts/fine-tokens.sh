#!/usr/bin/env bash
# Issue 51's sparse fine tokens, measured on the validation scenes (seeds 9100-9101) only:
# the shipped world model extended by a fine stage (world-model-fine-tiny.yaml) and fine-tuned
# 300 steps, beside its ablation (the same 300 steps without the fine stage) and the shipped
# weights, each forecast through the graph (sweeps only: the Chamfer distance and the agents'
# scores read them). Then the selection's statistics on the validation cache and the fine
# stage's cost. About 45 min on 2 cores.
#   bench/scripts/fine-tokens.sh [BEVWORLD_BINARY]
set -euo pipefail
cd "$(dirname "$0")/../.."
BIN="${1:-cargo run --release --}"
for arm in fine coarse; do
    if [ ! -f "runs/wm-ft-$arm/train-config.yaml" ] || [ -z "$(ls runs/wm-ft-$arm/*.bpk 2>/dev/null)" ]; then
        $BIN train world-model --config "configs/models/finetune-world-model-$arm-tiny.yaml" \
            --out "runs/wm-ft-$arm"
    fi
done
forecast() { # NAME CONFIG WEIGHTS
    $BIN eval forecast --data out/synth-wm-val --out "out/eval-forecast-val-$1" \
        --set "models.tiny.world_model.config=$2" --set "models.tiny.world_model.weights=$3" \
        --set "sensors=[lidar]" --set "methods=[model,latent_ego_warp,oracle]" \
        --json > "bench/results/fine-tokens-val-$1.json"
}
forecast shipped configs/models/world-model-tiny.yaml nodes/world_model/weights/world-model-tiny.bpk
forecast coarse configs/models/world-model-tiny.yaml runs/wm-ft-coarse/world-model-tiny.bpk
forecast fine configs/models/world-model-fine-tiny.yaml runs/wm-ft-fine/world-model-fine-tiny.bpk
# The selection on the validation cache, and the fine stage's cost beside the coarse model's.
cargo run --release -p bevworld-bench --bin fine_tokens -- measure
cargo run --release -p bevworld-bench --bin fine_tokens -- page
