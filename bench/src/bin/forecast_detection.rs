//! Does the world model move the other road users? The detector that reads the tokenizer's
//! latent (`bevworld train detector --input latent --frames 1`) runs on the world model's
//! forecast latents at +1 s and +3 s, beside the same detector on the true future keyframe's
//! latent (what the tokenizer sees) and on `latent_ego_warp` (the current latent moved by the
//! ego alone: nothing else moves). All three are scored with the nuScenes detection metrics
//! against the future keyframe's annotations. No whole-scene Chamfer shows this: at 0.5–1 s the
//! forecast is close to the ego warp, which moves only the ego.
//!
//! The contexts are the test set's keyframe latents (three, 0.5 s apart, with the logged ego
//! motion into each and into every future keyframe), forecast as the forecast graph does (one
//! deterministic DDIM step, the residual soft-thresholded with τ = 0.25 falling to 0 at 3 s).
//!
//!   cargo run --release -p bevworld-bench --bin forecast_detection -- \
//!     --detector runs/downstream/frozen-latent-1f/detector.bpk \
//!     --features out/detector/features-test/latent --data out/synth-det-test \
//!     --json bench/results/forecast-detection.json

use bevworld_bench::cli::{arg, fail};
use std::collections::BTreeMap;
use std::path::Path;

use bevworld_heads::{FrameMaps, InputKind, PosedMap, load_detector};
use bevworld_heads_train::{DetectionSet, load_set};
use bevworld_metrics::detection::{DetectionConfig, evaluate};
use bevworld_types::{Detection, EgoAction};
use bevworld_world_model::{DdimConfig, LoadedWorldModel, ResidualShrink};
use burn::prelude::*;
use serde_json::{Value, json};

/// Horizons scored, as indices into the six future keyframes (0.5 s apart).
const HORIZONS: [(usize, f64); 2] = [(1, 1.0), (5, 3.0)];

/// The keyframe indices of each scene of `set`, in time order.
fn scenes(set: &DetectionSet) -> Vec<Vec<usize>> {
    let mut scenes: BTreeMap<&str, Vec<usize>> = BTreeMap::new();
    for (i, frame) in set.frames.iter().enumerate() {
        scenes.entry(frame.scene.as_str()).or_default().push(i);
    }
    scenes.into_values().collect()
}

fn action(set: &DetectionSet, a: usize, b: usize) -> EgoAction {
    let (a, b) = (&set.frames[a], &set.frames[b]);
    EgoAction::between(&a.global_from_ego, a.time_us, &b.global_from_ego, b.time_us).unwrap_or_else(
        || {
            fail(format!(
                "no action between {} and {}",
                a.sample_token, b.sample_token
            ))
        },
    )
}

fn main() {
    let (Some(detector), Some(features), Some(data)) =
        (arg("--detector"), arg("--features"), arg("--data"))
    else {
        fail("usage: forecast_detection --detector DETECTOR.bpk --features DIR --data DIR [--json OUT]".into());
    };
    let device = Device::flex();
    let detector =
        load_detector(Path::new(&detector), &device).unwrap_or_else(|e| fail(e.to_string()));
    let (config, input) = (&detector.meta.config, &detector.meta.input);
    if input.kind != InputKind::Latent || input.frames != 1 {
        fail(format!(
            "the detector reads the {} over {} frame(s); this measure needs one that reads the latent of one frame",
            input.kind.name(),
            input.frames
        ));
    }
    let set = load_set(Path::new(&features), Path::new(&data), config)
        .unwrap_or_else(|e| fail(e.to_string()));
    detector
        .check_features(&set.model, &set.weights_hash)
        .unwrap_or_else(|e| fail(e.to_string()));
    let world = LoadedWorldModel::shipped_tiny(Path::new("."), device.clone())
        .unwrap_or_else(|e| fail(e.to_string()));
    if world.latent_stats.weights_hash != set.weights_hash {
        fail(format!(
            "the world model pairs with tokenizer weights {}, the latents are of {}",
            world.latent_stats.weights_hash, set.weights_hash
        ));
    }
    let rollout = world.rollout();
    let (context, future) = (world.config.context_frames, world.config.future_frames);
    let mut sampler = DdimConfig::deterministic(1, 0);
    sampler.shrink = Some(ResidualShrink {
        tau: 0.25,
        fade_s: 3.0,
    });

    let output_grid = config.output_grid(input);
    let detect = |map: &[f32], frame: usize| -> Vec<Detection> {
        let frame = &set.frames[frame];
        let values = input
            .assemble(
                &PosedMap {
                    values: map,
                    global_from_ego: frame.global_from_ego,
                },
                None,
            )
            .unwrap_or_else(|e| fail(e.to_string()));
        let tensor = Tensor::<4>::from_data(
            TensorData::new(
                values,
                [1, input.channels, input.grid.height, input.grid.width],
            ),
            &device,
        );
        let outputs = detector.model.forward(tensor);
        let read = |t: Tensor<4>| t.into_data().try_to_vec::<f32>().unwrap_or_default();
        let (heatmap, boxes, motion) = (
            read(outputs.heatmap),
            read(outputs.boxes),
            read(outputs.motion),
        );
        config
            .decode(
                &output_grid,
                &FrameMaps {
                    heatmap: &heatmap,
                    boxes: &boxes,
                    motion: &motion,
                },
            )
            .iter()
            .map(|a| a.to_detection(&frame.sample_token, &frame.global_from_ego))
            .collect()
    };

    // Per horizon and method, the detections of each forecast's future keyframe. A future
    // keyframe is the target of several contexts only at different horizons, so each
    // (horizon, method) holds each sample at most once.
    let methods = ["forecast", "latent_ego_warp", "true_latent"];
    let mut results: BTreeMap<(usize, &str), BTreeMap<String, Vec<Detection>>> = BTreeMap::new();
    let mut windows = 0;
    for scene in scenes(&set) {
        // Context frames k − 2, k − 1, k, each with the action into it: k − 3 must exist.
        for k in context..scene.len().saturating_sub(future) {
            let frames: Vec<usize> = (k + 1 - context..=k).map(|j| scene[j]).collect();
            let context_maps: Vec<Vec<f32>> =
                frames.iter().map(|&i| set.frames[i].map.clone()).collect();
            let context_actions: Vec<EgoAction> = (k + 1 - context..=k)
                .map(|j| action(&set, scene[j - 1], scene[j]))
                .collect();
            let future_actions: Vec<EgoAction> = (k + 1..=k + future)
                .map(|j| action(&set, scene[j - 1], scene[j]))
                .collect();
            let out = rollout
                .run(&context_maps, &context_actions, &future_actions, &sampler)
                .unwrap_or_else(|e| fail(e.to_string()));
            windows += 1;
            for (index, _) in HORIZONS {
                let target = scene[k + 1 + index];
                let token = set.frames[target].sample_token.clone();
                for (method, map) in [
                    ("forecast", &out.future[index]),
                    ("latent_ego_warp", &out.ego_warped[index]),
                    ("true_latent", &set.frames[target].map),
                ] {
                    results
                        .entry((index, method))
                        .or_default()
                        .insert(token.clone(), detect(map, target));
                }
            }
        }
    }
    let classes: Vec<&str> = config.classes.iter().map(String::as_str).collect();
    let metric = DetectionConfig::for_classes(&classes);
    let mut horizons = Vec::new();
    println!("| horizon | method | mAP | NDS | mATE | mAVE |\n|---|---|---|---|---|---|");
    for (index, seconds) in HORIZONS {
        let mut row = serde_json::Map::new();
        row.insert("horizon_s".into(), json!(seconds));
        for method in methods {
            let predictions = &results[&(index, method)];
            let truth = predictions
                .keys()
                .filter_map(|t| set.truth.get(t).map(|truth| (t.clone(), truth.clone())))
                .collect();
            let scores =
                evaluate(&metric, &truth, predictions).unwrap_or_else(|e| fail(e.to_string()));
            println!(
                "| +{seconds} s | {method} | {:.3} | {:.3} | {:.3} | {:.3} |",
                scores.mean_ap,
                scores.nd_score,
                scores.tp_errors["trans_err"],
                scores.tp_errors["vel_err"]
            );
            row.insert(
                method.into(),
                json!({"samples": predictions.len(), "map": scores.mean_ap, "nds": scores.nd_score,
                       "tp_errors": scores.tp_errors, "class_ap": scores.mean_dist_aps}),
            );
        }
        horizons.push(Value::Object(row));
    }
    let figures = json!({
        "detector": detector.path.display().to_string(),
        "detector_weights_hash": detector.meta.weights_hash,
        "data": data,
        "windows": windows,
        "sampler": {"steps": 1, "shrink": {"tau": 0.25, "fade_s": 3.0}},
        "horizons": horizons,
    });
    if let Some(path) = arg("--json") {
        let text = serde_json::to_string_pretty(&figures).unwrap_or_default();
        std::fs::write(&path, text + "\n").unwrap_or_else(|e| fail(format!("{path}: {e}")));
    }
}
