//! Detection as a user runs it: `detect.yaml` on a synthetic scene with people, its
//! `results_nusc.json` read back strictly and scored by `eval detector`; the shipped detector
//! refusing another tokenizer's latents by digest; and `train detector` refusing bad flags and
//! configs before any work.

use std::path::Path;

use bevworld_sensors::{Dataset, DatasetOptions};
use bevworld_types::DetectionResults;

use crate::common::{bevworld_owned, read_json, text};

fn path(p: &Path) -> String {
    p.display().to_string()
}

/// A five-second synthetic scene with pedestrians and cyclists: its first keyframes have the
/// whole 3 s future the motion scores need.
fn scene_with_people(data: &Path) {
    let output = bevworld_owned(&[
        "synth".into(),
        "--out".into(),
        path(data),
        "--seed".into(),
        "41".into(),
        "--seconds".into(),
        "5".into(),
        "--camera-size".into(),
        "64x36".into(),
        "--pedestrians".into(),
        "8".into(),
        "--cyclists".into(),
        "3".into(),
    ]);
    assert!(output.status.success(), "{}", text(&output));
}

fn detect(data: &Path, out: &Path, extra: &[String]) -> std::process::Output {
    let mut args = vec![
        "run".to_string(),
        "configs/graphs/detect.yaml".into(),
        "--set".into(),
        format!("data={}", path(data)),
        "--set".into(),
        format!("out={}", path(out)),
        "--no-progress".into(),
    ];
    args.extend_from_slice(extra);
    bevworld_owned(&args)
}

#[test]
fn detect_yaml_writes_every_keyframes_boxes_in_the_submission_format_and_a_picture_per_sweep() {
    let dir = tempfile::tempdir().expect("dir");
    let data = dir.path().join("data");
    scene_with_people(&data);
    let out = dir.path().join("detect");
    let output = detect(&data, &out, &[]);
    assert!(output.status.success(), "{}", text(&output));

    let keyframes = Dataset::open(
        &data,
        &DatasetOptions {
            skip_images: true,
            ..Default::default()
        },
    )
    .expect("opens");
    let samples: std::collections::BTreeSet<String> = (0..keyframes.len())
        .map(|i| keyframes.read(i).expect("frame").sample_token)
        .collect();
    // Read back as strictly as `eval detector` reads any file: every box valid.
    let results = DetectionResults::load(&out.join("results_nusc.json")).expect("a valid file");
    let written: std::collections::BTreeSet<String> = results.results.keys().cloned().collect();
    assert_eq!(written, samples, "every keyframe, and only keyframes, once");
    assert!(results.meta.use_lidar && results.meta.use_camera);
    let trajectories = read_json(&out.join("trajectories.json"));
    for (sample, boxes) in &results.results {
        let listed = trajectories["samples"][sample]
            .as_array()
            .expect("the sample's trajectories");
        assert_eq!(listed.len(), boxes.len(), "one entry per box of {sample}");
        for entry in listed {
            let modes = entry["modes"].as_array().expect("modes");
            assert_eq!(modes.len(), 3, "the detector's three modes");
            assert_eq!(modes[0]["positions"].as_array().map(Vec::len), Some(6));
        }
    }
    let sweeps = Dataset::open(
        &data,
        &DatasetOptions {
            skip_images: true,
            sweeps: true,
            ..Default::default()
        },
    )
    .expect("opens")
    .len();
    let pictures = std::fs::read_dir(&out)
        .expect("out")
        .flatten()
        .filter(|e| e.path().join("detections.png").is_file())
        .count();
    assert_eq!(pictures, sweeps, "a picture per 12 Hz sweep");

    let scored = bevworld_owned(&[
        "eval".into(),
        "detector".into(),
        "--data".into(),
        path(&data),
        "--results".into(),
        path(&out.join("results_nusc.json")),
        "--trajectories".into(),
        path(&out.join("trajectories.json")),
        "--json".into(),
    ]);
    assert!(scored.status.success(), "{}", text(&scored));
    let scores: serde_json::Value =
        serde_json::from_slice(&scored.stdout).expect("eval detector --json");
    let nds = scores["present_classes"]["nd_score"].as_f64().expect("NDS");
    assert!((0.0..=1.0).contains(&nds), "{nds}");
    let motion = &scores["motion"];
    assert!(motion["agents"].as_u64().is_some_and(|n| n > 0), "{motion}");
    let matched = motion["matched"].as_u64().expect("matched");
    assert!(matched <= motion["agents"].as_u64().unwrap_or(0));
    assert!(
        matched > 0,
        "the shipped detector matches some agent of the scene: {motion}"
    );
    let ade = motion["min_ade"].as_f64().expect("minADE");
    let miss = motion["miss_rate"].as_f64().expect("miss rate");
    assert!(
        ade.is_finite() && ade >= 0.0 && (0.0..=1.0).contains(&miss),
        "{motion}"
    );

    // Trajectories of another run (a box less in one sample) are refused, naming the sample.
    let mut other = trajectories.clone();
    let (sample, _) = results
        .results
        .iter()
        .find(|(_, boxes)| !boxes.is_empty())
        .expect("a sample with a detection");
    other["samples"][sample]
        .as_array_mut()
        .expect("boxes")
        .pop();
    let other_path = dir.path().join("other-trajectories.json");
    std::fs::write(&other_path, serde_json::to_vec(&other).expect("json")).expect("written");
    let refused = bevworld_owned(&[
        "eval".into(),
        "detector".into(),
        "--data".into(),
        path(&data),
        "--results".into(),
        path(&out.join("results_nusc.json")),
        "--trajectories".into(),
        path(&other_path),
    ]);
    assert_eq!(refused.status.code(), Some(2), "{}", text(&refused));
    assert!(
        text(&refused).contains(sample.as_str()),
        "{}",
        text(&refused)
    );
}

#[test]
fn the_detector_refuses_the_latents_of_other_tokenizer_weights_by_digest() {
    let dir = tempfile::tempdir().expect("dir");
    let data = dir.path().join("data");
    scene_with_people(&data);
    let out = dir.path().join("detect");
    let output = detect(
        &data,
        &out,
        &[
            "--set".into(),
            "models.tiny.tokenizer.weights=untrained".into(),
        ],
    );
    assert!(
        !output.status.success(),
        "another tokenizer's latents were detected on"
    );
    let message = text(&output);
    assert!(
        message.contains("was trained on the feature of 'tokenizer-tiny' with weights"),
        "{message}"
    );
    assert!(
        !out.join("results_nusc.json").exists(),
        "nothing is written as if it were fine"
    );
}

#[test]
fn train_detector_refuses_bad_flags_and_overlapping_seed_ranges_before_any_work() {
    let dir = tempfile::tempdir().expect("dir");
    let out = path(&dir.path().join("run"));
    for (flags, expected) in [
        (vec!["--frames", "3"], "--frames"),
        (vec!["--input", "lidar"], "bev_stats"),
        (vec!["--init", "imagenet"], "frozen"),
        (
            vec!["--init", "scratch", "--input", "bev_stats"],
            "no encoder",
        ),
        (vec!["--steps", "0"], "--steps 0"),
    ] {
        let mut args = vec![
            "train".to_string(),
            "detector".into(),
            "--out".into(),
            out.clone(),
        ];
        args.extend(flags.iter().map(|f| f.to_string()));
        let output = bevworld_owned(&args);
        assert!(!output.status.success(), "{flags:?} was accepted");
        assert!(
            text(&output).contains(expected),
            "{flags:?}: {}",
            text(&output)
        );
    }
    let config = std::fs::read_to_string("configs/models/train-detector-tiny.yaml")
        .expect("the shipped config")
        .replace("seed: 9200", "seed: 4005");
    let overlapping = dir.path().join("overlap.yaml");
    std::fs::write(&overlapping, config).expect("written");
    let output = bevworld_owned(&[
        "train".into(),
        "detector".into(),
        "--config".into(),
        path(&overlapping),
        "--out".into(),
        out.clone(),
    ]);
    assert!(!output.status.success());
    let message = text(&output);
    assert!(
        message.contains("val.synth.seed") && message.contains("overlap"),
        "{message}"
    );
    // A fine-tuning rate above the heads' own is refused, naming the field.
    let config = std::fs::read_to_string("configs/models/train-detector-tiny.yaml")
        .expect("the shipped config")
        .replace("fine_tune_lr_fraction: 0.1", "fine_tune_lr_fraction: 1.5");
    let too_fast = dir.path().join("too-fast.yaml");
    std::fs::write(&too_fast, config).expect("written");
    let output = bevworld_owned(&[
        "train".into(),
        "detector".into(),
        "--config".into(),
        path(&too_fast),
        "--init".into(),
        "tokenizer".into(),
        "--out".into(),
        out.clone(),
    ]);
    assert!(!output.status.success());
    let message = text(&output);
    assert!(message.contains("fine_tune_lr_fraction"), "{message}");
    assert!(!Path::new(&out).exists(), "nothing made for a refused run");
}
