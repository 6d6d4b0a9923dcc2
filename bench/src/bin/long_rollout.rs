//! Error growth of an autoregressive rollout: the shipped world model chained for 20 s along
//! the logged ego motion of held-out scenes, each forecast's last frames the next one's
//! context, scored against the tokenizer's latent of the frame that really came (standardised
//! latent L1) at every 0.5 s. The ego-warp baseline is chained the same way (each round warps
//! the last frame of the previous round's warp); copy-last keeps the last observed frame.
//!
//! Reads keyframe latents exported by the graph (`export_latents.yaml`); the script makes them:
//!
//!   bench/scripts/long-rollout.sh
//!   cargo run --release -p bevworld-bench --bin long_rollout -- out/long-rollout/latents

use bevworld_types::mean_abs_difference;
use std::path::{Path, PathBuf};

use bevworld_bench::{markdown_table, results_dir, write_results};
use bevworld_plot::{Panel, Series, panels_png};
use bevworld_sinks::npy::read_npy_f32;
use bevworld_types::{EgoAction, Pose};
use bevworld_world_model::{DdimConfig, LoadedWorldModel};
use burn::prelude::*;
use glam::{DMat4, DVec4};

/// How long each rollout runs.
const SECONDS: f64 = 20.0;

fn pose(rows: &serde_json::Value) -> Pose {
    let r = |i: usize, j: usize| rows[i][j].as_f64().unwrap_or(f64::NAN);
    Pose::from_mat4(DMat4::from_cols(
        DVec4::new(r(0, 0), r(1, 0), r(2, 0), r(3, 0)),
        DVec4::new(r(0, 1), r(1, 1), r(2, 1), r(3, 1)),
        DVec4::new(r(0, 2), r(1, 2), r(2, 2), r(3, 2)),
        DVec4::new(r(0, 3), r(1, 3), r(2, 3), r(3, 3)),
    ))
}

/// One scene's keyframes in time order: latent, pose, time.
struct Scene {
    name: String,
    latents: Vec<Vec<f32>>,
    /// `actions[k]`: the ego motion from keyframe k to k + 1 (the action into k + 1).
    actions: Vec<EgoAction>,
}

fn scenes(dir: &Path) -> Vec<Scene> {
    let index: serde_json::Value = serde_json::from_slice(
        &std::fs::read(dir.join("index.json")).expect("the latents' index.json"),
    )
    .expect("index");
    let mut by_scene: std::collections::BTreeMap<String, Vec<&serde_json::Value>> =
        Default::default();
    for frame in index["frames"].as_array().expect("frames") {
        by_scene
            .entry(frame["scene"].as_str().unwrap_or_default().to_string())
            .or_default()
            .push(frame);
    }
    by_scene
        .into_iter()
        .map(|(name, mut frames)| {
            frames.sort_by_key(|f| f["timestamp_us"].as_i64());
            let latents = frames
                .iter()
                .map(|f| {
                    let file = dir.join(f["file"].as_str().expect("file"));
                    read_npy_f32(&std::fs::read(&file).expect("latent file"))
                        .expect("latent")
                        .1
                })
                .collect();
            let poses: Vec<(Pose, i64)> = frames
                .iter()
                .map(|f| {
                    (
                        pose(&f["global_from_ego"]),
                        f["timestamp_us"].as_i64().unwrap_or(0),
                    )
                })
                .collect();
            let actions = poses
                .windows(2)
                .map(|w| EgoAction::between(&w[0].0, w[0].1, &w[1].0, w[1].1).expect("action"))
                .collect();
            Scene {
                name,
                latents,
                actions,
            }
        })
        .collect()
}

fn main() {
    let root = bevworld_bench::manifest_dir().join("..");
    let latents_dir = std::env::args()
        .nth(1)
        .map_or_else(|| root.join("out/long-rollout/latents"), PathBuf::from);
    let loaded =
        LoadedWorldModel::shipped_tiny(&root, Device::flex()).expect("shipped world model");
    let (config, stats, rollout) = (&loaded.config, &loaded.latent_stats, loaded.rollout());
    let (p, n) = (config.context_frames, config.future_frames);
    let interval = config.frame_interval_s;
    let frames_ahead = (SECONDS / interval).round() as usize;
    let standardised = |latent: &[f32]| {
        let mut values = latent.to_vec();
        stats.stats.standardize(&mut values);
        values
    };

    // errors[method][k]: the L1 at (k + 1) · interval, one entry per scene.
    let methods = ["model", "latent_ego_warp", "latent_copy_last"];
    let mut errors: Vec<Vec<Vec<f64>>> = vec![vec![Vec::new(); frames_ahead]; methods.len()];
    let mut used = Vec::new();
    for scene in scenes(&latents_dir) {
        // Context: keyframes 1..=p (their actions are the motions into them); then 20 s.
        if scene.latents.len() < 1 + p + frames_ahead {
            println!(
                "{}: {} keyframes, too short for {SECONDS} s",
                scene.name,
                scene.latents.len()
            );
            continue;
        }
        used.push(scene.name.clone());
        let truth = |k: usize| standardised(&scene.latents[p + k]); // k = 1..: keyframe p + k
        let action_into = |frame: usize| scene.actions[frame - 1];
        let mut model_context: Vec<Vec<f32>> = scene.latents[1..=p].to_vec();
        let mut warp_context = model_context.clone();
        let mut done = 0;
        let mut round = 0u64;
        while done < frames_ahead {
            let first = p + done + 1; // the keyframe of the first future frame
            let context_actions: Vec<EgoAction> = (first - p..first).map(&action_into).collect();
            let future: Vec<EgoAction> = (first..first + n).map(&action_into).collect();
            let sampler = DdimConfig::deterministic(1, round);
            let model = rollout
                .run(&model_context, &context_actions, &future, &sampler)
                .expect("forecast");
            let warped = rollout
                .run(&warp_context, &context_actions, &future, &sampler)
                .expect("warp");
            // The last observed frame, for the whole 20 s.
            let copied = scene.latents[p].clone();
            for k in 0..n.min(frames_ahead - done) {
                let truth = truth(done + k + 1);
                errors[0][done + k]
                    .push(mean_abs_difference(&standardised(&model.future[k]), &truth));
                errors[1][done + k].push(mean_abs_difference(
                    &standardised(&warped.ego_warped[k]),
                    &truth,
                ));
                errors[2][done + k].push(mean_abs_difference(&standardised(&copied), &truth));
            }
            model_context = model.future[n - p..].to_vec();
            warp_context = warped.ego_warped[n - p..].to_vec();
            done += n;
            round += 1;
        }
        println!("{}: rolled out {SECONDS} s", scene.name);
    }
    assert!(
        !used.is_empty(),
        "no scene long enough in {}",
        latents_dir.display()
    );

    let mean = |values: &[f64]| values.iter().sum::<f64>() / values.len().max(1) as f64;
    let spread = |values: &[f64]| {
        let m = mean(values);
        (values.iter().map(|v| (v - m) * (v - m)).sum::<f64>() / values.len().max(1) as f64).sqrt()
    };
    let shown = [1usize, 2, 6, 12, 20, 30, 40];
    let rows: Vec<Vec<String>> = shown
        .iter()
        .filter(|&&k| k <= frames_ahead)
        .map(|&k| {
            let mut row = vec![format!("+{:.1} s", k as f64 * interval)];
            for errors in &errors {
                let at = &errors[k - 1];
                row.push(format!("{:.3} ± {:.3}", mean(at), spread(at)));
            }
            row
        })
        .collect();
    let table = markdown_table(
        &[
            "time ahead",
            "model (chained)",
            "latent_ego_warp (chained)",
            "latent_copy_last",
        ],
        &rows,
    );
    let curves: Vec<Vec<(f64, f64)>> = errors
        .iter()
        .map(|errors| {
            errors
                .iter()
                .enumerate()
                .map(|(k, at)| ((k + 1) as f64 * interval, mean(at)))
                .collect()
        })
        .collect();
    let png = results_dir().join("long-rollout.png");
    panels_png(
        &png,
        &[Panel {
            title: "Latent L1 of a 20 s rollout",
            x_label: "seconds ahead",
            log_y: false,
            series: methods
                .iter()
                .zip(&curves)
                .map(|(label, points)| Series { label, points })
                .collect(),
        }],
    )
    .expect("plot");
    let notes = format!(
        "\nScenes: {}. Standardised latent L1 (mean ± spread over scenes) of the forecast frame \
         against the tokenizer's latent of the logged keyframe at that time; the model forecasts \
         3 s from its own last three forecast frames, along the logged ego motion, with one \
         DDIM step.\n\n![error against time](long-rollout.png)\n",
        used.join(", ")
    );
    write_results(
        "long-rollout",
        "Error growth of a 20 s autoregressive rollout",
        "bench/scripts/long-rollout.sh",
        &table,
        &notes,
        &serde_json::json!({
            "scenes": used,
            "interval_s": interval,
            "methods": methods,
            "mean_l1": errors.iter().map(|e| e.iter().map(|at| mean(at)).collect::<Vec<_>>()).collect::<Vec<_>>(),
        }),
    );
}
