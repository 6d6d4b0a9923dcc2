//! `bevworld train tokenizer` as a user runs it: a short run writes its checkpoint, metrics,
//! curves and weights; the weights drive the reconstruction graph; a second run into the same
//! folder must say `--resume`, and `--resume` continues where the checkpoint left off.

mod common;

use common::{bevworld, bevworld_owned, reconstruct_outputs, text};

use std::path::Path;

fn synth(out: &Path, seed: &str) {
    let output = bevworld(&[
        "synth",
        "--out",
        out.to_str().expect("utf-8"),
        "--camera-size",
        "112x64",
        "--azimuth-step",
        "2",
        "--agents",
        "1",
        "--seconds",
        "1",
        "--seed",
        seed,
    ]);
    assert!(output.status.success(), "{}", text(&output));
}

#[test]
fn a_short_run_trains_checkpoints_resumes_and_its_weights_drive_the_graph() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (train, val, run) = (
        dir.path().join("train"),
        dir.path().join("val"),
        dir.path().join("run"),
    );
    synth(&train, "1");
    synth(&val, "500");
    let args = |steps: &str, resume: bool| {
        let mut args = vec![
            "train".to_string(),
            "tokenizer".into(),
            "--out".into(),
            run.display().to_string(),
            "--data".into(),
            train.display().to_string(),
            "--val".into(),
            val.display().to_string(),
            "--steps".into(),
            steps.into(),
            "--log-every".into(),
            "1".into(),
        ];
        if resume {
            args.push("--resume".into());
        }
        args
    };
    let call = |args: Vec<String>| bevworld_owned(&args);

    let first = call(args("3", false));
    assert!(first.status.success(), "{}", text(&first));
    for file in [
        "tokenizer.bpk",
        "metrics.csv",
        "curves.png",
        "train.yaml",
        "tokenizer.yaml",
        "checkpoints/latest",
    ] {
        assert!(run.join(file).is_file(), "{file} missing");
    }
    let csv = std::fs::read_to_string(run.join("metrics.csv")).expect("csv");
    let phases: Vec<&str> = csv
        .lines()
        .skip(1)
        .map(|l| l.split(',').nth(1).unwrap_or(""))
        .collect();
    assert_eq!(phases, ["train", "train", "train", "val"], "{csv}");
    let val_row: Vec<&str> = csv.lines().last().expect("row").split(',').collect();
    let psnr: f64 = val_row[10].parse().expect("psnr");
    assert!(psnr > 5.0 && psnr < 60.0, "{psnr}");

    let again = call(args("3", false));
    assert_eq!(again.status.code(), Some(1));
    assert!(text(&again).contains("--resume"), "{}", text(&again));

    let resumed = call(args("5", true));
    assert!(resumed.status.success(), "{}", text(&resumed));
    assert!(
        text(&resumed).contains("resumed at step 3"),
        "{}",
        text(&resumed)
    );
    let csv = std::fs::read_to_string(run.join("metrics.csv")).expect("csv");
    let steps: Vec<&str> = csv
        .lines()
        .skip(1)
        .map(|l| l.split(',').next().unwrap_or(""))
        .collect();
    assert_eq!(steps, ["1", "2", "3", "3", "4", "5", "5"], "{csv}");

    // The trained weights run the reconstruction graph.
    let weights = run.join("tokenizer.bpk");
    let out = dir.path().join("recon");
    let mut graph = vec![
        "run".to_string(),
        "configs/graphs/reconstruct.yaml".into(),
        "--no-progress".into(),
        "--set".into(),
        format!("source.data={}", val.display()),
        "--set".into(),
        format!("encode.weights={}", weights.display()),
        "--set".into(),
        format!("render.weights={}", weights.display()),
    ];
    graph.extend(reconstruct_outputs(&out));
    let output = call(graph);
    assert!(output.status.success(), "{}", text(&output));
    assert!(!text(&output).contains("untrained"), "{}", text(&output));
}
