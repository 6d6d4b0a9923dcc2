//! Hard cases that need the shipped weights and the graph:
//!
//! - a 20-second rollout, each forecast's last frames the next one's context, stays finite and
//!   at the scale of the training latents;
//! - the rollout node counts forecasts conditioned on actions outside the training range.
//!
//! Each crate's own hard cases are in its `tests/hard_cases.rs` (the world model's sampler,
//! actions and backends; the tokenizer's rendering extremes; the latent statistics).

use crate::common;

use std::path::Path;

use common::{bevworld_owned, export_latents, node, read_json, repo, text};

use bevworld_sinks::npy::read_npy_f32;
use bevworld_types::manoeuvre::constant_turn;
use bevworld_world_model::manoeuvre::Manoeuvre;
use bevworld_world_model::{DdimConfig, LoadedWorldModel};
use burn::prelude::*;

fn path(p: &Path) -> String {
    p.display().to_string()
}

/// A synthetic scene no set holds (seed 9701), 2 s: four keyframes.
fn scene(dir: &Path) -> std::path::PathBuf {
    let data = dir.join("synth");
    let output = bevworld_owned(&[
        "synth".into(),
        "--out".into(),
        path(&data),
        "--seed".into(),
        "9701".into(),
        "--seconds".into(),
        "2".into(),
        "--camera-size".into(),
        "224x126".into(),
    ]);
    assert!(output.status.success(), "{}", text(&output));
    data
}

/// The bound on a forecast frame's per-channel RMS, standardised: the training latents have
/// exactly 1 (zero mean, unit deviation), and a rollout that stays a driving scene stays within
/// this factor of it, above and below.
const SCALE_FACTOR: f64 = 3.0;

#[test]
fn a_twenty_second_rollout_stays_finite_and_at_the_training_latents_scale() {
    let dir = tempfile::tempdir().expect("dir");
    let data = scene(dir.path());
    let latents = dir.path().join("latents");
    let frames = export_latents(&data, &latents);
    let loaded = LoadedWorldModel::shipped_tiny(&repo(), Device::flex()).expect("weights");
    let config = &loaded.config;
    let p = config.context_frames;
    let mut context: Vec<Vec<f32>> = frames[frames.len() - p..]
        .iter()
        .map(|f| {
            let file = latents.join(f["file"].as_str().expect("file"));
            read_npy_f32(&std::fs::read(file).expect("npy"))
                .expect("latent")
                .1
        })
        .collect();
    let rollout = loaded.rollout();
    let stats = &loaded.latent_stats;
    // Driving on at 8 m/s with a gentle curve, the whole way.
    let interval = config.frame_interval_s;
    let cruise = constant_turn(8.0, 0.05, interval);
    let mut actions = vec![cruise; p];
    let channels = stats.stats.mean.len();
    let mut seconds = 0.0;
    let mut round = 0u64;
    let mut worst = (1.0f64, 1.0f64);
    while seconds < 20.0 {
        let future = Manoeuvre::Keep.actions(&cruise, config.future_frames, interval);
        let sampler = DdimConfig::deterministic(1, round);
        let output = rollout
            .run(&context, &actions, &future, &sampler)
            .expect("forecast");
        for (k, frame) in output.future.iter().enumerate() {
            assert!(
                frame.iter().all(|v| v.is_finite()),
                "non-finite at {:.1} s",
                seconds + (k + 1) as f64 * interval
            );
            let mut standardised = frame.clone();
            stats.stats.standardize(&mut standardised);
            let cells = standardised.len() / channels;
            for (c, channel) in standardised.chunks(cells).enumerate() {
                let rms =
                    (channel.iter().map(|v| f64::from(v * v)).sum::<f64>() / cells as f64).sqrt();
                worst = (worst.0.min(rms), worst.1.max(rms));
                assert!(
                    rms < SCALE_FACTOR && rms > 1.0 / SCALE_FACTOR,
                    "channel {c} at {:.1} s has RMS {rms:.3} against the training latents' 1",
                    seconds + (k + 1) as f64 * interval
                );
            }
        }
        let n = output.future.len();
        context = output.future[n - p..].to_vec();
        actions = future[n - p..].to_vec();
        seconds += n as f64 * interval;
        round += 1;
    }
    assert!(seconds >= 20.0);
    println!(
        "20 s rollout: per-channel RMS of the standardised forecasts from {:.3} to {:.3}",
        worst.0, worst.1
    );
}

#[test]
fn the_rollout_node_counts_forecasts_outside_the_training_range() {
    let dir = tempfile::tempdir().expect("dir");
    let data = scene(dir.path());
    let out = dir.path().join("forecast");
    let metrics = dir.path().join("metrics.json");
    let run = |action_list: &str| {
        bevworld_owned(&[
            "run".into(),
            "configs/graphs/forecast.yaml".into(),
            "--set".into(),
            format!("source.data={}", path(&data)),
            "--set".into(),
            format!("files.out={}", path(&out)),
            "--set".into(),
            format!("scores.json={}", path(&out.join("scores.json"))),
            "--set".into(),
            "history.log_future=false".into(),
            "--set".into(),
            "rollout.actions=list".into(),
            "--set".into(),
            format!("rollout.action_list={action_list}"),
            "--set".into(),
            "rollout.horizons=[0.5]".into(),
            "--set".into(),
            "render.sensors=[lidar]".into(),
            "--metrics".into(),
            path(&metrics),
            "--no-progress".into(),
        ])
    };
    let figures = |output: std::process::Output| -> (f64, f64) {
        assert!(output.status.success(), "{}", text(&output));
        let report = read_json(&metrics);
        let rollout = node(&report, "rollout");
        (
            rollout["extra"]["forecasts"].as_f64().expect("forecasts"),
            rollout["extra"]["forecasts_outside_training"]
                .as_f64()
                .expect("flagged"),
        )
    };
    // 30 m/s for 3 s: four times the training set's mean speed.
    let (forecasts, flagged) = figures(run("[[30,0],[30,0],[30,0],[30,0],[30,0],[30,0]]"));
    assert!(forecasts >= 1.0);
    assert_eq!(flagged, forecasts, "every forecast at 30 m/s is flagged");
    // Standing still lies below the slowest speed of the training set (1.6 m/s).
    let (forecasts, flagged) = figures(run("[[0,0],[0,0],[0,0],[0,0],[0,0],[0,0]]"));
    assert_eq!(flagged, forecasts, "standing still is flagged");
    // Ordinary driving is not.
    let (forecasts, flagged) = figures(run("[[7,0],[7,0],[7,0],[7,0],[7,0],[7,0]]"));
    assert!(forecasts >= 1.0);
    assert_eq!(flagged, 0.0);
    // The rendered sweeps of the flagged forecasts are finite clouds (written as PLY).
    let ply: Vec<std::path::PathBuf> = walk(&out)
        .into_iter()
        .filter(|p| p.file_name().is_some_and(|n| n == "LIDAR_TOP.ply"))
        .collect();
    assert!(!ply.is_empty());
    for file in ply {
        let points = bevworld_sinks::ply::read_ply(&file).expect("ply");
        assert!(
            points
                .iter()
                .all(|p| p.x.is_finite() && p.y.is_finite() && p.z.is_finite())
        );
    }
}

fn walk(dir: &Path) -> Vec<std::path::PathBuf> {
    let mut found = Vec::new();
    if let Ok(entries) = std::fs::read_dir(dir) {
        for entry in entries.flatten() {
            let path = entry.path();
            if path.is_dir() {
                found.extend(walk(&path));
            } else {
                found.push(path);
            }
        }
    }
    found
}
