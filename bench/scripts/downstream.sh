#!/usr/bin/env bash
# The paper's pretraining experiment at our scale: the detection and motion heads trained on
# each BEV product (the pillar statistics, the tokenizer's latent, its fused feature), from one
# keyframe and from two, each for the same number of steps; then the encoder trained with the
# heads, from the tokenizer's weights and from scratch, beside the frozen one; each run scored
# once on the test seeds. Then the page: bench/results/downstream.{json,md}.
#
#   bench/scripts/downstream.sh            # STEPS=1500 per frozen arm, PRETRAIN_STEPS=500 per
#                                          # arm of the pretraining table, by default
#   STEPS=300 bench/scripts/downstream.sh  # a shorter budget, every arm of a table alike
set -euo pipefail
cd "$(dirname "$0")/../.."
STEPS=${STEPS:-1500}
RUNS=${RUNS:-runs/downstream}
CONFIG=${CONFIG:-configs/models/train-detector-tiny.yaml}
cargo build --release --bin bevworld
cargo build --release -p bevworld-bench --bin downstream --bin forecast_detection
BIN=${CARGO_TARGET_DIR:-target}/release
# Trains one arm into the run folder $1 with the flags after it, unless the run has its test
# score already; a run cut short resumes from its newest checkpoint.
train_arm() {
  local run=$1
  shift
  if [[ -f "$run/test/scores.json" ]]; then
    echo "kept $run"
    return
  fi
  local resume=()
  [[ -d "$run/checkpoints" ]] && resume=(--resume)
  "$BIN/bevworld" train detector --config "$CONFIG" --out "$run" "$@" "${resume[@]}"
}
for input in bev_stats latent feature; do
  for frames in 1 2; do
    train_arm "$RUNS/frozen-$input-${frames}f" --input "$input" --frames "$frames" --init frozen \
      --steps "$STEPS"
  done
done
# The paper's pretraining table: the fused feature read through the encoder trained with the
# heads from the shipped tokenizer's weights (tokenizer) and from a fresh initialisation
# (scratch), beside the frozen encoder, all three for PRETRAIN_STEPS steps: an encoder step
# costs about four frozen ones on 2 cores, so these rows have a budget of their own.
PRETRAIN_STEPS=${PRETRAIN_STEPS:-500}
for init in tokenizer scratch frozen; do
  for frames in 1 2; do
    train_arm "$RUNS/pretrain-$init-feature-${frames}f" --input feature --frames "$frames" \
      --init "$init" --steps "$PRETRAIN_STEPS"
  done
done
# The fine-tuned two-frame arm as a user runs it: its encoder's features made by the graph
# (detect.yaml with RUN/tokenizer.bpk), its detector on them, scored by eval detector; the page
# sets this beside the run's own test score.
check="$RUNS/pretrain-tokenizer-feature-2f"
"$BIN/bevworld" run configs/graphs/detect.yaml --set data=out/synth-det-test --set out="$RUNS/graph-check" \
  --set pictures=false --set source.sweeps=false --set "models.tiny.tokenizer.weights=$check/tokenizer.bpk" \
  --set "detector=$check/detector.bpk" --no-progress
"$BIN/bevworld" eval detector --data out/synth-det-test --results "$RUNS/graph-check/results_nusc.json" \
  --json > "$RUNS/graph-check.json"
# The shipped detector in the graph, at 12 Hz replay of its demo scene: its time per frame.
"$BIN/bevworld" run configs/graphs/detect.yaml --set pictures=false --set out="$RUNS/detect-demo" \
  --overwrite --no-progress --metrics "$RUNS/detect-metrics.json"
# The latent one-frame detector on the world model's forecast latents of the test scenes.
"$BIN/forecast_detection" --detector "$RUNS/frozen-latent-1f/detector.bpk" \
  --features out/detector/features-test/latent --data out/synth-det-test \
  --json bench/results/forecast-detection.json
"$BIN/downstream" --runs "$RUNS" --graph-metrics "$RUNS/detect-metrics.json" \
  --forecast bench/results/forecast-detection.json \
  --graph-check "$RUNS/graph-check.json" --graph-check-run pretrain-tokenizer-feature-2f \
  --json bench/results/downstream.json --page bench/results/downstream.md \
  --curves bench/results/downstream-curves.png
# The official devkit on one arm's test file, where it is installed.
PYTHON=${PYTHON:-$HOME/.cache/bevworld/devkit-venv/bin/python}
if [[ -x "$PYTHON" ]]; then
  BIN="$BIN/bevworld" "$PYTHON" bench/scripts/downstream-devkit.py "$RUNS/frozen-latent-2f" out/synth-det-test \
    > bench/results/downstream-devkit.json
else
  echo "no nuscenes-devkit at $PYTHON: the devkit cross-check is skipped"
fi
