#!/usr/bin/env bash
# Issue 51's tokenizer floor (bench/results/tokenizer-vehicles.md): does a tokenizer fine-tuned
# with a quarter of its LiDAR rays on the annotated vehicles draw them where the shipped one
# draws blobs, and does the world model then forecast them better?
#  1. Three fine-tunes of the shipped tokenizer, 1,000 steps each (about 13 min each on 2 cores):
#     `finetune-tokenizer-vehicles-tiny.yaml` (a quarter of the rays on vehicles), the same with
#     a tenth, and with the uniform draw, the ablation.
#  2. Each, and the shipped weights, scored by `eval tokenizer` on the world model's validation
#     scenes (seeds 9100-9101, 80 keyframes): the floor.
#  3. The shipped world model continued 300 steps on the vehicle tokenizer's latents
#     (`finetune-world-model-vehicles-tiny.yaml`; encoding its caches takes about 13 min), the
#     same with the moving-cell loss, and the same continuation on the shipped tokenizer's
#     latents (the control), then the forecasts of each and of the shipped pair on the
#     validation scenes.
#  4. With TEST=1, once the choice is made and instead of 1-3: the floors and the forecasts on
#     the test scenes (9500-9503), touched once for the reported figures.
#   bench/scripts/tokenizer-vehicles.sh [BEVWORLD_BINARY]
#   TEST=1 bench/scripts/tokenizer-vehicles.sh [BEVWORLD_BINARY]
set -euo pipefail
cd "$(dirname "$0")/../.."
BIN="${1:-cargo run --release --}"
TABLES="cargo run --release -p bevworld-bench --bin"
SHIPPED_TOKENIZER=nodes/tokenizer/weights/tokenizer-tiny.bpk
SHIPPED_WM=nodes/world_model/weights/world-model-tiny.bpk
floor() { # SPLIT DATA LABEL WEIGHTS
    $BIN eval tokenizer --data "$2" --weights "$4" --out "out/eval-tokenizer-$1-$3" --json \
        > "bench/results/tokenizer-floor-$1-$3.json"
}
forecast() { # SPLIT DATA LABEL TOKENIZER WORLD_MODEL
    $BIN eval forecast --data "$2" --out "out/eval-forecast-$1-$3" \
        --set "models.tiny.tokenizer.weights=$4" --set "models.tiny.world_model.weights=$5" \
        --set "sensors=[lidar]" --set "methods=[model,latent_ego_warp,oracle]" \
        --json > "bench/results/tokenizer-vehicles-forecast-$1-$3.json"
}
if [ "${TEST:-0}" = 1 ]; then
    floor test out/synth-wm-test shipped "$SHIPPED_TOKENIZER"
    floor test out/synth-wm-test vehicles runs/tok-ft-vehicles/tokenizer.bpk
    $TABLES tokenizer_floor -- shipped=bench/results/tokenizer-floor-test-shipped.json \
        "a quarter of the rays on vehicles=bench/results/tokenizer-floor-test-vehicles.json"
    forecast test out/synth-wm-test control "$SHIPPED_TOKENIZER" runs/wm-ft-vehicles-control/world-model-tiny.bpk
    forecast test out/synth-wm-test vehicles runs/tok-ft-vehicles/tokenizer.bpk runs/wm-ft-vehicles/world-model-tiny.bpk
    $TABLES forecast_tables -- --compare \
        "300 more steps=bench/results/tokenizer-vehicles-forecast-test-control.json" \
        "300 more steps on the vehicle tokenizer=bench/results/tokenizer-vehicles-forecast-test-vehicles.json"
    # The vehicle pair beside its own baselines and floor (the comparison's come from the first).
    $TABLES forecast_tables -- bench/results/tokenizer-vehicles-forecast-test-vehicles.json
    exit 0
fi
for run in vehicles:0.25 vehicles10:0.1 plain:0; do
    IFS=: read -r name share <<<"$run"
    if [ ! -f "runs/tok-ft-$name/tokenizer.bpk" ]; then
        $BIN train tokenizer --config configs/models/finetune-tokenizer-vehicles-tiny.yaml \
            --lidar-vehicle-share "$share" --out "runs/tok-ft-$name"
    fi
done
for weights in shipped:$SHIPPED_TOKENIZER plain:runs/tok-ft-plain/tokenizer.bpk \
    vehicles10:runs/tok-ft-vehicles10/tokenizer.bpk vehicles:runs/tok-ft-vehicles/tokenizer.bpk; do
    IFS=: read -r label path <<<"$weights"
    floor val out/synth-wm-val "$label" "$path"
done
$TABLES tokenizer_floor -- shipped=bench/results/tokenizer-floor-val-shipped.json \
    "1,000 more steps=bench/results/tokenizer-floor-val-plain.json" \
    "1,000 more steps, a tenth of the rays on vehicles=bench/results/tokenizer-floor-val-vehicles10.json" \
    "1,000 more steps, a quarter of the rays on vehicles=bench/results/tokenizer-floor-val-vehicles.json"

# The world model on the vehicle tokenizer's latents, and its control.
if [ ! -f runs/tok-ft-vehicles/tokenizer.stats.json ]; then
    $BIN tokenizer stats --weights runs/tok-ft-vehicles/tokenizer.bpk --data out/synth-train48
fi
if [ ! -f runs/wm-ft-vehicles/world-model-tiny.bpk ]; then
    $BIN train world-model --config configs/models/finetune-world-model-vehicles-tiny.yaml \
        --out runs/wm-ft-vehicles
fi
# The moving cars being the world model's gap on those latents: the same continuation with the
# loss that counts the cells where the future moves over the ego warp (as
# finetune-world-model-moving-tiny.yaml weighs it).
if [ ! -f runs/wm-ft-vehicles-moving/world-model-tiny.bpk ]; then
    $BIN train world-model --config configs/models/finetune-world-model-vehicles-tiny.yaml \
        --moving-weight 4,3 --out runs/wm-ft-vehicles-moving
fi
if [ ! -f runs/wm-ft-vehicles-control/world-model-tiny.bpk ]; then
    $BIN train world-model --config configs/models/finetune-world-model-stop-tiny.yaml \
        --init "$SHIPPED_WM" --out runs/wm-ft-vehicles-control
fi
forecast val out/synth-wm-val shipped "$SHIPPED_TOKENIZER" "$SHIPPED_WM"
forecast val out/synth-wm-val control "$SHIPPED_TOKENIZER" runs/wm-ft-vehicles-control/world-model-tiny.bpk
forecast val out/synth-wm-val vehicles runs/tok-ft-vehicles/tokenizer.bpk runs/wm-ft-vehicles/world-model-tiny.bpk
forecast val out/synth-wm-val vehicles-moving runs/tok-ft-vehicles/tokenizer.bpk \
    runs/wm-ft-vehicles-moving/world-model-tiny.bpk
$TABLES forecast_tables -- --compare shipped=bench/results/tokenizer-vehicles-forecast-val-shipped.json \
    "300 more steps=bench/results/tokenizer-vehicles-forecast-val-control.json" \
    "300 more steps on the vehicle tokenizer=bench/results/tokenizer-vehicles-forecast-val-vehicles.json"
$TABLES forecast_tables -- bench/results/tokenizer-vehicles-forecast-val-vehicles.json
$TABLES forecast_tables -- --compare \
    "300 more steps on the vehicle tokenizer=bench/results/tokenizer-vehicles-forecast-val-vehicles.json" \
    "the same, moving cells counted 5 times=bench/results/tokenizer-vehicles-forecast-val-vehicles-moving.json"
