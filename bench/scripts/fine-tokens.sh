#!/usr/bin/env bash
# Issue 51's sparse fine tokens, measured on the validation scenes (seeds 9100-9101) only:
# the shipped world model extended by a fine stage (world-model-fine-tiny.yaml) and fine-tuned
# 300 steps, beside its ablation (the same 300 steps without the fine stage) and the shipped
# weights, each forecast through the graph (sweeps only: the Chamfer distance and the agents'
# scores read them). Then the selection's statistics on the validation cache and the fine
# stage's cost. About 80 min on 2 cores.
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
forecast() { # NAME CONFIG WEIGHTS [EXTRA FLAGS]
    local name=$1 config=$2 weights=$3
    shift 3
    $BIN eval forecast --data out/synth-wm-val --out "out/eval-forecast-val-$name" \
        --set "models.tiny.world_model.config=$config" --set "models.tiny.world_model.weights=$weights" \
        --set "sensors=[lidar]" --set "methods=[model,latent_ego_warp,oracle]" "$@" \
        --json > "bench/results/fine-tokens-val-$name.json"
}
forecast shipped configs/models/world-model-tiny.yaml nodes/world_model/weights/world-model-tiny.bpk
forecast coarse configs/models/world-model-tiny.yaml runs/wm-ft-coarse/world-model-tiny.bpk
forecast fine configs/models/world-model-fine-tiny.yaml runs/wm-ft-fine/world-model-fine-tiny.bpk
# Where the fine model loses: its own weights with no token opened (the rule's threshold out
# of reach), and both fine-tunes sampled without the residual shrink.
sed 's/threshold: 6.0,/threshold: 1.0e9,/' configs/models/world-model-fine-tiny.yaml \
    > out/world-model-fine-off.yaml
forecast fine-off out/world-model-fine-off.yaml runs/wm-ft-fine/world-model-fine-tiny.bpk
forecast coarse-noshrink configs/models/world-model-tiny.yaml runs/wm-ft-coarse/world-model-tiny.bpk \
    --set rollout.shrink=null
forecast fine-noshrink configs/models/world-model-fine-tiny.yaml runs/wm-ft-fine/world-model-fine-tiny.bpk \
    --set rollout.shrink=null
# Another rule: fewer tokens opened by weak changes, and the neighbours of strong ones.
if [ -z "$(ls runs/wm-ft-fine-t10d1/*.bpk 2>/dev/null)" ]; then
    $BIN train world-model --config configs/models/finetune-world-model-fine-tiny.yaml \
        --fine-select 10,1 --out runs/wm-ft-fine-t10d1
fi
forecast fine-t10d1 runs/wm-ft-fine-t10d1/model-config.yaml \
    runs/wm-ft-fine-t10d1/world-model-fine-tiny.bpk
# The selection on the validation cache, and the fine stage's cost beside the coarse model's.
cargo run --release -p bevworld-bench --bin fine_tokens -- measure
cargo run --release -p bevworld-bench --bin fine_tokens -- page
