//! Each annotated car's speed as the agent layer's tracks tell it, and as the detector's
//! velocity head does (`bevworld_bench::agent_tracks`), from a `detect.yaml` run's
//! `results_nusc.json` on a dataset's keyframes. The tracks are `move_agents`' defaults;
//! `--frames` sets how many frames a track reaches back (the current one included) and
//! `--min-speed` the speed from which the layer carries a car, instead of their defaults;
//! `--on-returns MARGIN_M` re-centres every detection on the keyframe's LiDAR returns inside
//! its box grown by that margin (`bevworld_types::agent_returns`) before tracking.
//!
//!   cargo run --release -p bevworld-bench --bin agent_tracks -- \
//!       --data out/synth-wm-val --results out/eval-agents-detect-val-vehicles/results_nusc.json \
//!       --json bench/results/agent-tracks-val-vehicles.json
//!   cargo run --release -p bevworld-bench --bin agent_tracks -- --table LABEL=FILE.json ...

use bevworld_bench::cli::{arg, fail};
use std::path::Path;

use bevworld_bench::agent_tracks::{MATCH_DISTANCE_M, MOVING_FROM_MPS, TrackSpeeds, track_speeds};
use bevworld_sensors::{Dataset, DatasetOptions};
use bevworld_types::{DetectionResults, ReturnsRule};
use bevworld_world_model::nodes::move_agents::MoveAgentsParams;

const USAGE: &str = "usage: agent_tracks --data DIR --results results_nusc.json [--frames N] [--on-returns MARGIN_M] [--min-speed M/S] [--json OUT] | agent_tracks --table LABEL=FILE.json ...";

fn speed(value: Option<f64>) -> String {
    value.map_or("—".into(), |v| format!("{v:.2}"))
}

fn table(runs: &[(String, TrackSpeeds)]) -> String {
    let mut out = String::from(
        "| run | cars | annotated | detected | tracked | carried by the track | carried by the head | track's error, median (m/s) | head's error, median (m/s) | track within 1 m/s |\n|---|---|---|---|---|---|---|---|---|---|\n",
    );
    for (label, speeds) in runs {
        for (class, c) in [("moving", &speeds.moving), ("parked", &speeds.parked)] {
            let share = |n: usize| {
                if c.detected == 0 {
                    "—".to_string()
                } else {
                    format!("{n} ({:.0}%)", 100.0 * n as f64 / c.detected as f64)
                }
            };
            out += &format!(
                "| {label} | {class} | {} | {} | {} | {} | {} | {} | {} | {} |\n",
                c.cars,
                c.detected,
                share(c.tracked),
                share(c.carried_by_track),
                share(c.carried_by_head),
                speed(c.track_error_median_mps),
                speed(c.head_error_median_mps),
                c.track_within_1mps,
            );
        }
    }
    out
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.first().map(String::as_str) == Some("--table") {
        let mut runs = Vec::new();
        for spec in &args[1..] {
            let Some((label, path)) = spec.split_once('=') else {
                fail(format!("'{spec}' is not LABEL=FILE\n{USAGE}"));
            };
            let text = std::fs::read_to_string(path)
                .unwrap_or_else(|e| fail(format!("reading {path}: {e}")));
            let speeds: TrackSpeeds =
                serde_json::from_str(&text).unwrap_or_else(|e| fail(format!("{path}: {e}")));
            runs.push((label.to_string(), speeds));
        }
        if runs.is_empty() {
            fail(USAGE.into());
        }
        print!("{}", table(&runs));
        return;
    }
    let (Some(data), Some(results)) = (arg("--data"), arg("--results")) else {
        fail(USAGE.into());
    };
    let results = DetectionResults::load(Path::new(&results))
        .unwrap_or_else(|e| fail(format!("--results {e}")));
    let options = DatasetOptions {
        skip_images: true,
        ..Default::default()
    };
    let dataset = Dataset::open(Path::new(&data), &options)
        .unwrap_or_else(|e| fail(format!("--data {data}: {e}")));
    let keyframes: Vec<_> = (0..dataset.len())
        .map(|i| {
            dataset
                .read(i)
                .unwrap_or_else(|e| fail(format!("--data {data}: {e}")))
        })
        .collect();
    if keyframes.is_empty() {
        fail(format!("--data {data} has no keyframe"));
    }
    let layer: MoveAgentsParams =
        serde_json::from_str("{}").unwrap_or_else(|e| fail(format!("defaults: {e}")));
    let mut rule = layer.track.rule(layer.min_score);
    if let Some(text) = arg("--frames") {
        rule.frames = match text.parse::<usize>() {
            Ok(n) if (2..=16).contains(&n) => n,
            _ => fail(format!(
                "--frames {text}: not a track length in 2..=16 frames"
            )),
        };
    }
    let min_speed = match arg("--min-speed") {
        Some(text) => match text.parse::<f64>() {
            Ok(v) if v.is_finite() && v >= 0.0 => v,
            _ => fail(format!("--min-speed {text}: not a speed ≥ 0 m/s")),
        },
        None => layer.track.min_speed_mps,
    };
    let returns = arg("--on-returns").map(|text| match text.parse::<f64>() {
        Ok(margin_m) if margin_m.is_finite() && margin_m >= 0.0 => ReturnsRule {
            margin_m,
            above_bottom_m: 0.3,
            min_returns: 3,
        },
        _ => fail(format!("--on-returns {text}: not a margin ≥ 0 m")),
    });
    let speeds = track_speeds(
        &keyframes,
        &results.results,
        &rule,
        returns.as_ref(),
        min_speed,
    );
    eprintln!(
        "cars matched within {MATCH_DISTANCE_M} m; moving from {MOVING_FROM_MPS} m/s annotated"
    );
    print!("{}", table(&[("this run".into(), speeds.clone())]));
    if let Some(out) = arg("--json") {
        let text =
            serde_json::to_string_pretty(&speeds).unwrap_or_else(|e| fail(format!("{out}: {e}")));
        std::fs::write(&out, text + "\n").unwrap_or_else(|e| fail(format!("writing {out}: {e}")));
    }
}
