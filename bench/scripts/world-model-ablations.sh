#!/usr/bin/env bash
# The world model's ablations, as short runs from the committed tiny configs (results in
# bench/results/world-model-training.md). Each writes runs/ablation-<name>/ and prints its
# final validation table; the validation-set scores below are then re-measured at 1, 4 and 50
# DDIM steps with `bevworld eval world-model`.
#   bench/scripts/world-model-ablations.sh [BEVWORLD_BINARY]
set -euo pipefail
cd "$(dirname "$0")/../.."
BIN="${1:-cargo run --release --}"
run() {
    local name=$1
    shift
    rm -rf "runs/ablation-$name"
    $BIN train world-model --out "runs/ablation-$name" "$@" | tail -6
}
# Stage 3 alone, 250 steps: the v target over the ego-warp residual (shipped), the same with
# the warp as an input of the future frames, the paper's epsilon target, v on the latent
# itself, and the warp's weight in the base faded to 0 at 2 s and at 3 s. The committed stage 3
# draws from every sixth sweep (`stride: 6`); the page's figures predate it (keyframe windows).
run v-residual --stages 3 --stage-steps 250
run v-residual-warp-input --stages 3 --stage-steps 250 --ego-warp-input true
run epsilon-residual --stages 3 --stage-steps 250 --target epsilon
run v-latent --stages 3 --stage-steps 250 --residual false
run fade2 --stages 3 --stage-steps 250 --ego-warp-fade 2
run fade3 --stages 3 --stage-steps 250 --ego-warp-fade 3
# The paper's three stages against stage 3 alone, at about the same time (the three-stage
# split costs what 250 stage-3 steps do).
run three-stages --stages 1,2,3 --stage-steps 100,80,150
for name in v-residual-warp-input v-residual epsilon-residual v-latent fade2 fade3 three-stages; do
    for steps in 1 4 50; do
        echo "== $name, DDIM $steps steps"
        $BIN eval world-model --weights "runs/ablation-$name/world-model-tiny.bpk" \
            --model "runs/ablation-$name/model-config.yaml" --steps "$steps" --stride 4
    done
done
# The rendered cost of a lower latent L1: Chamfer, PSNR and SSIM on the validation scenes for
# the plain residual, warp-input and fade-2 runs, through the forecast graph with their weights,
# sampled as drawn (without the rollout's residual shrink, which the page's figures predate).
for name in v-residual v-residual-warp-input fade2; do
    echo "== $name, rendered"
    $BIN eval forecast --data out/synth-wm-val --out "runs/ablation-$name/eval-forecast" \
        --set "models.tiny.world_model.config=runs/ablation-$name/model-config.yaml" \
        --set "models.tiny.world_model.weights=runs/ablation-$name/world-model-tiny.bpk" \
        --set shrink=null
done
