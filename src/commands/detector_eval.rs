//! `bevworld eval detector`: a detector's boxes (`results_nusc.json`, the nuScenes submission
//! format) scored against a dataset's annotations with the nuScenes detection metrics, as the
//! official devkit scores them: per class AP and true-positive errors, mAP and NDS. Any
//! detector's file can be scored, ours or not; the same file loads in the devkit.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result, bail};
use bevworld_metrics::detection::{
    DetectionConfig, DetectionScores, SampleTruth, TP_METRICS, evaluate, sample_truth,
};
use bevworld_sensors::{Dataset, DatasetOptions};
use bevworld_types::{DetectionResults, SensorFrame};
use clap::Args;

#[derive(Args)]
pub struct DetectorEvalArgs {
    /// The annotated dataset (nuScenes layout: a `bevworld synth` folder or nuScenes itself).
    #[arg(long)]
    pub data: PathBuf,
    /// Table folder name (e.g. `v1.0-mini`) when the dataset holds several.
    #[arg(long)]
    pub version: Option<String>,
    /// Only these scenes (comma-separated); the results must cover exactly their keyframes.
    #[arg(long, value_delimiter = ',')]
    pub scenes: Vec<String>,
    /// The detections, in the nuScenes submission format.
    #[arg(long)]
    pub results: PathBuf,
    /// The detector's trajectories (`trajectories.json` beside the results of
    /// `detect.yaml`): minADE, minFDE and miss rate through the matched detections, beside
    /// constant velocity.
    #[arg(long)]
    pub trajectories: Option<PathBuf>,
    /// Print one JSON object: `official` (the challenge's ten classes, as the devkit scores
    /// them) and `present_classes` (only the classes the dataset annotates).
    #[arg(long)]
    pub json: bool,
}

/// Every keyframe's truth, by sample token, and the keyframes (without their images).
fn truth_of(args: &DetectorEvalArgs) -> Result<(BTreeMap<String, SampleTruth>, Vec<SensorFrame>)> {
    let options = DatasetOptions {
        version: args.version.clone(),
        scenes: args.scenes.clone(),
        skip_images: true,
        ..Default::default()
    };
    let dataset = Dataset::open(&args.data, &options)
        .with_context(|| format!("opening {}", args.data.display()))?;
    let mut truth = BTreeMap::new();
    let mut keyframes = Vec::new();
    for index in 0..dataset.len() {
        let frame = dataset.read(index)?;
        let (sample, sample_truth) = sample_truth(&frame)
            .map_err(|message| anyhow::anyhow!("{}: {message}", args.data.display()))?;
        truth.insert(sample, sample_truth);
        keyframes.push(frame);
    }
    if truth.is_empty() {
        bail!("{} has no keyframe to score", args.data.display());
    }
    Ok((truth, keyframes))
}

pub fn run(args: &DetectorEvalArgs) -> Result<ExitCode> {
    let results = DetectionResults::load(&args.results)
        .map_err(|error| super::refuse(format!("--results {error}")))?;
    let (truth, keyframes) = truth_of(args)?;
    let motion = match &args.trajectories {
        Some(path) => Some(super::detector_motion::score(
            path,
            &results.results,
            &keyframes,
        )?),
        None => None,
    };
    let official = evaluate(&DetectionConfig::default(), &truth, &results.results)
        .with_context(|| format!("scoring {}", args.results.display()))?;
    let mut present: Vec<&str> = truth
        .values()
        .flat_map(|t| &t.boxes)
        .map(|b| b.detection.detection_name.as_str())
        .collect();
    present.sort_unstable();
    present.dedup();
    let on_present = if present.is_empty() {
        None
    } else {
        Some(evaluate(
            &DetectionConfig::for_classes(&present),
            &truth,
            &results.results,
        )?)
    };
    if args.json {
        println!(
            "{}",
            serde_json::json!({
                "samples": truth.len(),
                "official": official,
                "present_classes": on_present,
                "motion": motion,
            })
        );
        return Ok(ExitCode::SUCCESS);
    }
    println!(
        "{} keyframes, {} boxes scored, {} predicted\n",
        truth.len(),
        truth.values().map(|t| t.boxes.len()).sum::<usize>(),
        results.results.values().map(Vec::len).sum::<usize>()
    );
    if let Some(scores) = &on_present {
        println!("{}", markdown(scores));
        println!(
            "\nOn the classes the dataset annotates ({}): mAP {:.4}, NDS {:.4}.",
            present.join(", "),
            scores.mean_ap,
            scores.nd_score
        );
    }
    println!(
        "Official (the challenge's ten classes, as the devkit scores them): mAP {:.4}, NDS {:.4}.",
        official.mean_ap, official.nd_score
    );
    if let Some(m) = &motion {
        println!(
            "Motion, through the detections: minADE {:.3} m, minFDE {:.3} m, miss rate {:.3} over {} of {} agents with a whole future (constant velocity: {:.3} / {:.3} m, miss rate {:.3}).",
            m.min_ade,
            m.min_fde,
            m.miss_rate,
            m.matched,
            m.agents,
            m.constant_velocity_ade,
            m.constant_velocity_fde,
            m.constant_velocity_miss_rate
        );
    }
    Ok(ExitCode::SUCCESS)
}

/// Per class: AP at each threshold, its mean, and the true-positive errors.
fn markdown(scores: &DetectionScores) -> String {
    let thresholds: Vec<&String> = scores
        .label_aps
        .values()
        .next()
        .map(|aps| aps.keys().collect())
        .unwrap_or_default();
    let mut text = String::from("| class |");
    for threshold in &thresholds {
        text.push_str(&format!(" AP@{threshold} m |"));
    }
    text.push_str(" mAP |");
    for metric in TP_METRICS {
        text.push_str(&format!(" {metric} |"));
    }
    text.push_str(&format!(
        "\n|---|{}\n",
        "---|".repeat(thresholds.len() + 1 + TP_METRICS.len())
    ));
    let number = |v: f64| {
        if v.is_nan() {
            "—".to_string()
        } else {
            format!("{v:.3}")
        }
    };
    for (class, aps) in &scores.label_aps {
        text.push_str(&format!("| {class} |"));
        for value in aps.values() {
            text.push_str(&format!(" {} |", number(*value)));
        }
        text.push_str(&format!(" {} |", number(scores.mean_dist_aps[class])));
        for metric in TP_METRICS {
            text.push_str(&format!(
                " {} |",
                number(scores.label_tp_errors[class][metric])
            ));
        }
        text.push('\n');
    }
    text.pop();
    text
}
