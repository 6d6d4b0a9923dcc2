#!/usr/bin/env bash
# Issue 51's `stop`: the recipe's world model (`bevworld train world-model --out runs/wm-tiny`)
# fine-tuned 300 steps with the branched training scenes driven six ways (`stop` among them),
# the weights shipped since, beside the same fine-tune with the five manoeuvres
# (`finetune-world-model-plain-tiny.yaml`) and the recipe's weights, scored on action control
# with six manoeuvres: validation seeds 9850-9853 (chosen on), and seeds 9900-9907 that no run
# had seen, touched once for the reported figure. About 45 min on 2 cores after the recipe's
# run, most of it making and encoding the six-way branched training scenes (first run only).
#   bench/scripts/world-model-stop.sh [BEVWORLD_BINARY]
set -euo pipefail
cd "$(dirname "$0")/../.."
BIN="${1:-cargo run --release --}"
for run in stop plain; do
    if [ ! -f "runs/wm-ft-$run/world-model-tiny.bpk" ]; then
        $BIN train world-model --config "configs/models/finetune-world-model-$run-tiny.yaml" \
            --out "runs/wm-ft-$run"
    fi
done
for split in val:9850:4 fresh:9900:8; do
    IFS=: read -r name seed scenes <<<"$split"
    if [ ! -d "out/synth-control6-$name" ]; then
        $BIN synth --out "out/synth-control6-$name" --seed "$seed" --scenes "$scenes" \
            --seconds 5.5 --camera-size 224x126 --branch-at 2 \
            --manoeuvres keep,left,right,faster,slower,stop
    fi
    for weights in recipe:runs/wm-tiny/world-model-tiny.bpk \
        plain:runs/wm-ft-plain/world-model-tiny.bpk stop:runs/wm-ft-stop/world-model-tiny.bpk; do
        IFS=: read -r label path <<<"$weights"
        $BIN eval control --data "out/synth-control6-$name" --out "out/eval-control6-$name-$label" \
            --set "models.tiny.world_model.weights=$path" \
            --json > "bench/results/control6-$name-$label.json"
    done
    for method in warp:latent_ego_warp oracle:oracle; do
        IFS=: read -r label flag <<<"$method"
        $BIN eval control --data "out/synth-control6-$name" --out "out/eval-control6-$name-$label" \
            --method "$flag" --json > "bench/results/control6-$name-$label.json"
    done
    # The table of bench/results/world-model-training.md ("Stopping"), from those files.
    cargo run --release -p bevworld-bench --bin control_tables -- \
        "recipe=bench/results/control6-$name-recipe.json" \
        "five manoeuvres=bench/results/control6-$name-plain.json" \
        "with stop=bench/results/control6-$name-stop.json" \
        "latent ego warp=bench/results/control6-$name-warp.json" \
        "oracle=bench/results/control6-$name-oracle.json"
done
# Does stopping cost the forecast? The validation scenes (9100-9101), as the moving-loss
# fine-tunes were scored (bench/scripts/world-model-moving-loss.sh writes the other two files).
$BIN eval forecast --data out/synth-wm-val --out out/eval-forecast-val-stop \
    --set models.tiny.world_model.weights=runs/wm-ft-stop/world-model-tiny.bpk \
    --set "sensors=[lidar]" --set "methods=[model,latent_ego_warp,oracle]" \
    --json > bench/results/world-model-stop-val.json
cargo run --release -p bevworld-bench --bin forecast_tables -- --compare \
    recipe=bench/results/world-model-moving-loss-val-recipe.json \
    "five manoeuvres=bench/results/world-model-moving-loss-val-plain.json" \
    "with stop=bench/results/world-model-stop-val.json"
