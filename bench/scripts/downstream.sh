#!/usr/bin/env bash
# The paper's pretraining experiment at our scale: the detection and motion heads trained on
# each BEV product (the pillar statistics, the tokenizer's latent, its fused feature), from one
# keyframe and from two, each for the same number of steps; each scored once on the test
# seeds. Then the page: bench/results/downstream.{json,md}.
#
#   bench/scripts/downstream.sh            # STEPS=1500 per arm by default
#   STEPS=300 bench/scripts/downstream.sh  # a shorter budget, every arm alike
set -euo pipefail
cd "$(dirname "$0")/../.."
STEPS=${STEPS:-1500}
RUNS=${RUNS:-runs/downstream}
CONFIG=${CONFIG:-configs/models/train-detector-tiny.yaml}
cargo build --release --bin bevworld
cargo build --release -p bevworld-bench --bin downstream --bin forecast_detection
BIN=${CARGO_TARGET_DIR:-target}/release
for input in bev_stats latent feature; do
  for frames in 1 2; do
    run="$RUNS/frozen-$input-${frames}f"
    if [[ -f "$run/test/scores.json" ]]; then
      echo "kept $run"
      continue
    fi
    resume=()
    [[ -d "$run/checkpoints" ]] && resume=(--resume)
    "$BIN/bevworld" train detector --config "$CONFIG" --input "$input" --frames "$frames" \
      --init frozen --steps "$STEPS" --out "$run" "${resume[@]}"
  done
done
# The shipped detector in the graph, at 12 Hz replay of its demo scene: its time per frame.
"$BIN/bevworld" run configs/graphs/detect.yaml --set pictures=false --set out="$RUNS/detect-demo" \
  --overwrite --no-progress --metrics "$RUNS/detect-metrics.json"
# The latent one-frame detector on the world model's forecast latents of the test scenes.
"$BIN/forecast_detection" --detector "$RUNS/frozen-latent-1f/detector.bpk" \
  --features out/detector/features-test/latent --data out/synth-det-test \
  --json bench/results/forecast-detection.json
"$BIN/downstream" --runs "$RUNS" --graph-metrics "$RUNS/detect-metrics.json" \
  --forecast bench/results/forecast-detection.json \
  --json bench/results/downstream.json --page bench/results/downstream.md
# The official devkit on one arm's test file, where it is installed.
PYTHON=${PYTHON:-$HOME/.cache/bevworld/devkit-venv/bin/python}
if [[ -x "$PYTHON" ]]; then
  BIN="$BIN/bevworld" "$PYTHON" bench/scripts/downstream-devkit.py "$RUNS/frozen-latent-2f" out/synth-det-test \
    > bench/results/downstream-devkit.json
else
  echo "no nuscenes-devkit at $PYTHON: the devkit cross-check is skipped"
fi
