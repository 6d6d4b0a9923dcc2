#!/usr/bin/env bash
# The best of K draws of the world model (bench/results/forecast.md, "Draws"): on the held-out
# test scenes (seeds 9500-9503, made here if missing) and the README's demo scene, K = 8 draws
# per forecast at 1 and 10 DDIM steps, beside the point forecast (draw 0) and the latent
# references. Only the sweeps are rendered: the Chamfer distance and the agents' scores read
# them. About 25 min at 1 step and 45 min at 10 on 2 cores.
#   bench/scripts/forecast-draws.sh [BEVWORLD_BINARY]
set -euo pipefail
cd "$(dirname "$0")/../.."
BIN="${1:-cargo run --release --}"
if [ ! -d out/synth-wm-test ]; then
    $BIN synth --out out/synth-wm-test --seed 9500 --scenes 4 --seconds 20 --camera-size 224x126
fi
if [ ! -d out/synth-forecast ]; then
    $BIN run configs/graphs/forecast.yaml --no-progress
fi
for steps in 1 10; do
    for split in test:out/synth-wm-test demo:out/synth-forecast; do
        IFS=: read -r name data <<<"$split"
        $BIN eval forecast --data "$data" --out "out/eval-forecast-draws-$name-s$steps" \
            --steps "$steps" --samples 8 --set "sensors=[lidar]" \
            --set "methods=[model,latent_ego_warp,oracle]" \
            --json > "bench/results/forecast-draws-$name-s$steps.json"
        cargo run --release -p bevworld-bench --bin forecast_tables -- \
            "bench/results/forecast-draws-$name-s$steps.json"
    done
done
