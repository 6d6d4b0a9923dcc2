#!/usr/bin/env bash
# Issue 51's agent layer (bench/results/agents.md): can the forecast's cars be moved as the ego
# warp moves the static world, rigidly, by where they go?
#  1. The bound (`latent_box_warp`): the ego-warped latent with each annotated vehicle carried
#     from its box now to its true future box (or along its annotated velocity), on the
#     world model's validation scenes (seeds 9100-9101), for the shipped pair and for the
#     vehicle pair of bench/scripts/tokenizer-vehicles.sh (its runs must exist), and the
#     margin around the boxes (0.5, 1.25, 2.5 m); and the same carried on the model's forecast
#     instead of the ego warp (what the agent layer gives with a perfect motion head).
#  2. A detector and motion head on the vehicle tokenizer's fused feature, trained on the world
#     model's training scenes (`train-detector-vehicles-tiny.yaml`, two frames; about 11 min),
#     and the same with the moving agents' velocity and motion counted ten times
#     (`--moving-weight 10`).
#  3. The agent layer (`forecast_agents.yaml`: `detect`, then `move_agents`) on the validation
#     scenes: the shipped pair with the shipped detector, the vehicle pair with its own (each
#     detected car of score 0.3 or more follows its most probable mode).
#  4. What the two detectors' motion outputs say of the cars they find on the validation
#     keyframes (agents-detector-motion.py).
#  5. The agent layer with each car carried at the velocity of its track across the context
#     frames' detections (`agents.follow=track`), for the three detectors, and with the
#     speed under which a track stands at 0 and 4 m/s instead of 2; then each annotated car's
#     speed as the tracks and the velocity head tell it (`agent_tracks`, at 2 and 4 m/s).
#  6. Each car's velocity read from its LiDAR returns instead of the detections' positions
#     (`agent_tracks --on-returns MARGIN`: each track's returns registered frame onto frame),
#     margins 0.5 and 1 m, tracks of 2, 3 and 5 frames.
#  7. With TEST=1, instead of 1-6: the bound and the chosen agent layers (the weighted
#     detector following its velocity, and following the tracks) on the test scenes
#     (9500-9503), once.
#   bench/scripts/agents.sh [BEVWORLD_BINARY]
#   TEST=1 bench/scripts/agents.sh [BEVWORLD_BINARY]
set -euo pipefail
cd "$(dirname "$0")/../.."
BIN="${1:-cargo run --release --}"
TABLES="cargo run --release -p bevworld-bench --bin forecast_tables --"
TS=nodes/tokenizer/weights/tokenizer-tiny.bpk
WS=nodes/world_model/weights/world-model-tiny.bpk
DS=nodes/heads/weights/detector-tiny.bpk
TV=runs/tok-ft-vehicles/tokenizer.bpk
WV=runs/wm-ft-vehicles/world-model-tiny.bpk
DV=runs/det-vehicles/detector.bpk
DM=runs/det-vehicles-moving/detector.bpk
bound() { # SPLIT LABEL TOKENIZER WORLD_MODEL MARGIN MOTION [BASE]
    $BIN eval forecast --data "out/synth-wm-$1" --out "out/eval-agents-bound-$1-$2" \
        --set "models.tiny.tokenizer.weights=$3" --set "models.tiny.world_model.weights=$4" \
        --set "sensors=[lidar]" --set "methods=[model,latent_ego_warp,latent_box_warp,oracle]" \
        --set "views.box_margin_m=$5" --set "views.box_motion=$6" \
        --set "views.box_base=${7:-latent_ego_warp}" \
        --json > "bench/results/agents-bound-$1-$2.json"
}
layer() { # SPLIT LABEL TOKENIZER WORLD_MODEL DETECTOR FOLLOW MIN_SCORE [--set ...]
    $BIN eval forecast --graph configs/graphs/forecast_agents.yaml --data "out/synth-wm-$1" \
        --out "out/eval-agents-$1-$2" \
        --set "models.tiny.tokenizer.weights=$3" --set "models.tiny.world_model.weights=$4" \
        --set "detector=$5" --set "agents.follow=$6" --set "min_score=$7" --set "sensors=[lidar]" \
        --set "methods=[model,model_with_agents,latent_ego_warp,oracle]" "${@:8}" \
        --json > "bench/results/agents-$1-$2.json"
}
if [ "${TEST:-0}" = 1 ]; then
    bound test shipped $TS $WS 1.25 future_box
    bound test vehicles $TV $WV 1.25 future_box
    bound test vehicles-velocity $TV $WV 1.25 velocity
    bound test shipped-on-model $TS $WS 1.25 future_box model
    bound test vehicles-on-model $TV $WV 1.25 future_box model
    layer test vehicles-moving-velocity $TV $WV $DM velocity 0.3
    layer test vehicles-track $TV $WV $DV track 0.3
    $BIN run configs/graphs/detect.yaml --set "models.tiny.tokenizer.weights=$TV" \
        --set "detector=$DV" --set data=out/synth-wm-test --set source.sweeps=false \
        --set out=out/eval-agents-detect-test-vehicles --set pictures=false --overwrite
    for v in 2 4; do
        cargo run --release -p bevworld-bench --bin agent_tracks -- --data out/synth-wm-test \
            --results out/eval-agents-detect-test-vehicles/results_nusc.json \
            --min-speed $v --json "bench/results/agent-tracks-test-vehicles-s$v.json"
    done
    cargo run --release -p bevworld-bench --bin agent_tracks -- --data out/synth-wm-test \
        --results out/eval-agents-detect-test-vehicles/results_nusc.json --on-returns 1.0 \
        --min-speed 2 --json bench/results/agent-tracks-test-vehicles-returns-s2.json
    for f in bench/results/agents-bound-test-*.json bench/results/agents-test-*.json; do
        $TABLES "$f"
    done
    exit 0
fi
bound val shipped $TS $WS 1.25 future_box
bound val shipped-velocity $TS $WS 1.25 velocity
for margin in 0.5 1.25 2.5; do
    bound val "vehicles-m$margin" $TV $WV $margin future_box
done
bound val vehicles-velocity $TV $WV 1.25 velocity
bound val vehicles-on-model $TV $WV 1.25 future_box model
[ -f "$DV" ] || $BIN train detector --config configs/models/train-detector-vehicles-tiny.yaml \
    --input feature --frames 2 --out runs/det-vehicles
[ -f "$DM" ] || $BIN train detector --config configs/models/train-detector-vehicles-tiny.yaml \
    --input feature --frames 2 --moving-weight 10 --out runs/det-vehicles-moving
layer val shipped $TS $WS $DS mode 0.3
layer val vehicles $TV $WV $DV mode 0.3
layer val vehicles-moving $TV $WV $DM mode 0.3
layer val vehicles-moving-velocity $TV $WV $DM velocity 0.3
motion() { # LABEL TOKENIZER DETECTOR
    $BIN run configs/graphs/detect.yaml --set "models.tiny.tokenizer.weights=$2" \
        --set "detector=$3" --set data=out/synth-wm-val --set source.sweeps=false \
        --set "out=out/eval-agents-detect-val-$1" --set pictures=false --overwrite
    bench/scripts/agents-detector-motion.py "out/eval-agents-detect-val-$1" 0.3 \
        > "bench/results/agents-detector-val-$1.json"
}
motion shipped $TS $DS
motion vehicles $TV $DV
motion vehicles-moving $TV $DM
layer val vehicles-track $TV $WV $DV track 0.3
layer val vehicles-track-s0 $TV $WV $DV track 0.3 --set agents.track.min_speed_mps=0
layer val vehicles-track-s4 $TV $WV $DV track 0.3 --set agents.track.min_speed_mps=4
layer val vehicles-moving-track $TV $WV $DM track 0.3
layer val shipped-track $TS $WS $DS track 0.3
SPEEDS="cargo run --release -p bevworld-bench --bin agent_tracks --"
for v in 2 4; do
    $SPEEDS --data out/synth-wm-val --results out/eval-agents-detect-val-vehicles/results_nusc.json \
        --min-speed $v --json "bench/results/agent-tracks-val-vehicles-s$v.json"
done
returns() { # LABEL [agent_tracks flags]
    $SPEEDS --data out/synth-wm-val --results out/eval-agents-detect-val-vehicles/results_nusc.json \
        --min-speed 2 "${@:2}" --json "bench/results/agent-tracks-val-vehicles-returns$1-s2.json"
}
for f in 2 5 9; do # the detections' positions, longer and shorter tracks
    $SPEEDS --data out/synth-wm-val --results out/eval-agents-detect-val-vehicles/results_nusc.json \
        --frames $f --min-speed 2 --json "bench/results/agent-tracks-val-vehicles-f$f-s2.json"
done
returns "" --on-returns 1.0
returns -m0.5 --on-returns 0.5
returns -f2 --on-returns 1.0 --frames 2
returns -f5 --on-returns 1.0 --frames 5
for f in bench/results/agents-bound-val-*.json bench/results/agents-val-*.json; do
    $TABLES "$f"
done
