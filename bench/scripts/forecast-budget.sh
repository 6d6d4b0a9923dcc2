#!/usr/bin/env bash
# This machine's line of the forecast graph's latency budget in bench/results/speed-vs-error.md
# (bench/results/forecast-budget-<kind>.json): the README's main job with the model's views only,
# its per-node times (--metrics) and per-forecast latencies (scores.json), then the page's
# budget table regenerated from every kind's record. About a minute after the build.
#   bench/scripts/forecast-budget.sh
set -euo pipefail
cd "$(dirname "$0")/../.."
OUT=out/forecast-budget
mkdir -p "$OUT"
cargo build --release --bin bevworld
cargo build --release -p bevworld-bench --bin speed_error
# The first run generates the demo scene (out/synth-forecast) when it is missing; the second
# is the one recorded, so that no stage waits on the scene's generation.
for run in first recorded; do
    cargo run --release --bin bevworld -- run configs/graphs/forecast.yaml \
        --set 'methods=[model]' --set "out=$OUT/views" --set "scores_json=$OUT/scores.json" \
        --metrics "$OUT/metrics.json" > "$OUT/$run.log"
done
cargo run --release -p bevworld-bench --bin speed_error -- budget "$OUT/metrics.json" "$OUT/scores.json"
