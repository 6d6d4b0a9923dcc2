#!/usr/bin/env bash
# The speed-error page, bench/results/speed-vs-error.{md,json,png}, from a clean checkout:
#   bench/scripts/speed-vs-error.sh [BEVWORLD_BINARY]
# 1. held-out contexts: test seeds 9500 and 9501, 10 s each (out/synth-speed-test);
# 2. `eval forecast` at 1, 2, 4, 8, 16 and 50 DDIM steps, and at 1 step with every horizon
#    rendered (about 15 minutes on 2 cores, most of it the 50-step run);
# 3. the bench binary: the tables, the cache's saving, the plot.
set -euo pipefail
cd "$(dirname "$0")/../.."
BIN="${1:-cargo run --release --}"
DATA=out/synth-speed-test
RUNS=out/speed-vs-error
if [ ! -d "$DATA" ]; then
    $BIN synth --out "$DATA" --seed 9500 --scenes 2 --seconds 10 --camera-size 224x126
fi
mkdir -p "$RUNS"
for steps in 1 2 4 8 16 50; do
    $BIN eval forecast --data "$DATA" --out "$RUNS/eval-s$steps" --steps "$steps" --json \
        > "$RUNS/steps-$steps.json"
done
$BIN eval forecast --data "$DATA" --out "$RUNS/eval-all" --steps 1 \
    --horizons 0.5,1,1.5,2,2.5,3 --json > "$RUNS/horizons-all.json"
cargo run --release -p bevworld-bench --bin speed_error -- "$RUNS"
