#!/usr/bin/env bash
# The figures of bench/results/forecast.md, from a clean checkout:
#   bench/scripts/forecast.sh [BEVWORLD_BINARY]
# 1. forecasts on the held-out test scenes (seeds 9500-9503, the world model's test range,
#    made by `bevworld train world-model --prepare-only` or here) and on the validation scenes
#    (9100-9101) at 1 and 4 DDIM steps and with the residual shrink's settings, the only
#    settings chosen on them;
# 2. action control on branched scenes, branched at 2 s: validation seeds 9850-9853, held-out
#    test seeds 9800-9807, the model and the ego-warp baseline;
# 3. the live graph's latencies at 12 Hz.
set -euo pipefail
cd "$(dirname "$0")/../.."
BIN="${1:-cargo run --release --}"
for split in val:9100:2 test:9500:4; do
    IFS=: read -r name seed scenes <<<"$split"
    if [ ! -d "out/synth-wm-$name" ]; then
        $BIN synth --out "out/synth-wm-$name" --seed "$seed" --scenes "$scenes" --seconds 20 --camera-size 224x126
    fi
done
for steps in 1 4; do
    $BIN eval forecast --data out/synth-wm-val --out "out/eval-forecast-val-s$steps" --steps "$steps" \
        --set shrink=null
done
for tau in 0.15 0.25 0.4; do
    $BIN eval forecast --data out/synth-wm-val --out "out/eval-forecast-val-tau$tau" \
        --set "shrink={tau: $tau, fade_s: 3.0}" --set "methods=[model]"
done
$BIN eval forecast --data out/synth-wm-test --out out/eval-forecast-test \
    --plot bench/results/forecast-chamfer.png --json > bench/results/forecast-test.json
# The README's demo scene (made by its main command), with the agents' split.
if [ ! -d out/synth-forecast ]; then
    $BIN run configs/graphs/forecast.yaml --no-progress
fi
$BIN eval forecast --data out/synth-forecast --out out/eval-forecast-demo \
    --json > bench/results/forecast-demo.json
# The tables the page quotes, generated from those files.
for split in test demo; do
    cargo run --release -p bevworld-bench --bin forecast_tables -- "bench/results/forecast-$split.json"
done
for split in val:9850:4 test:9800:8; do
    IFS=: read -r name seed scenes <<<"$split"
    if [ ! -d "out/synth-control-$name" ]; then
        $BIN synth --out "out/synth-control-$name" --seed "$seed" --scenes "$scenes" --seconds 5.5 \
            --camera-size 224x126 --branch-at 2
    fi
done
$BIN eval control --data out/synth-control-val --out out/eval-control-val
$BIN eval control --data out/synth-control-test --picture bench/results/control.png \
    --out out/eval-control-test --json > bench/results/control-test.json
$BIN eval control --data out/synth-control-test --method latent_ego_warp \
    --out out/eval-control-test-warp --json > bench/results/control-test-warp.json
$BIN eval control --data out/synth-control-test --method oracle \
    --out out/eval-control-test-oracle --json > bench/results/control-test-oracle.json
cargo run --release -p bevworld-bench --bin control_tables -- \
    shipped=bench/results/control-test.json "latent ego warp=bench/results/control-test-warp.json" \
    oracle=bench/results/control-test-oracle.json
$BIN run configs/graphs/forecast.yaml --metrics out/forecast/metrics.json
$BIN run configs/graphs/forecast_live.yaml --metrics out/forecast-live/metrics.json
