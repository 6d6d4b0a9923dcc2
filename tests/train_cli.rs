//! `bevworld train tokenizer` as a user runs it: a short run writes its checkpoint, metrics,
//! curves and weights; the weights drive the reconstruction graph; a second run into the same
//! folder must say `--resume`, and `--resume` continues where the checkpoint left off.

use crate::common;

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

/// `bevworld train tokenizer` into `run`, on `data` and validated on `val`, for `steps` steps,
/// logging every step, followed by `extra`.
fn train_args(run: &Path, data: &Path, val: &Path, steps: &str, extra: &[&str]) -> Vec<String> {
    let mut args: Vec<String> = ["train", "tokenizer", "--out"].map(String::from).to_vec();
    args.push(run.display().to_string());
    args.push("--data".into());
    args.push(data.display().to_string());
    args.push("--val".into());
    args.push(val.display().to_string());
    args.push("--steps".into());
    args.push(steps.into());
    args.extend(["--log-every".into(), "1".into()]);
    args.extend(extra.iter().map(|a| a.to_string()));
    args
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
        let extra: &[&str] = if resume { &["--resume"] } else { &[] };
        train_args(&run, &train, &val, steps, extra)
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
    // The committed config ships the weights' moving average: the last iterate is scored
    // first, then the average, whose row is the run's last.
    assert_eq!(
        phases,
        ["train", "train", "train", "val_iterate", "val"],
        "{csv}"
    );
    assert!(run.join("checkpoints/step-0000003/ema.bpk").is_file());
    let val_row: Vec<&str> = csv.lines().last().expect("row").split(',').collect();
    let psnr: f64 = val_row[10].parse().expect("psnr");
    assert!(psnr > 5.0 && psnr < 60.0, "{psnr}");

    let again = call(args("3", false));
    assert_eq!(again.status.code(), Some(1));
    assert!(text(&again).contains("--resume"), "{}", text(&again));

    // A checkpoint edited after it was written is refused, naming the file, and the run
    // folder is left as it was.
    let checkpoint = run.join("checkpoints/step-0000003");
    let state_path = checkpoint.join("state.json");
    let state = std::fs::read_to_string(&state_path).expect("state");
    std::fs::write(&state_path, state.replace("\"step\": 3", "\"step\": 999")).expect("edit");
    let edited = call(args("5", true));
    assert_eq!(edited.status.code(), Some(1), "{}", text(&edited));
    assert!(text(&edited).contains("state.json"), "{}", text(&edited));
    assert!(
        !text(&edited).contains("resumed at step"),
        "{}",
        text(&edited)
    );
    std::fs::write(&state_path, &state).expect("restore");
    let model_file = checkpoint.join("model.bpk");
    let model_bytes = std::fs::read(&model_file).expect("model");
    let mut flipped = model_bytes.clone();
    let middle = flipped.len() / 2;
    flipped[middle] ^= 0x01;
    std::fs::write(&model_file, &flipped).expect("flip");
    let corrupt = call(args("5", true));
    assert_eq!(corrupt.status.code(), Some(1), "{}", text(&corrupt));
    assert!(text(&corrupt).contains("model.bpk"), "{}", text(&corrupt));
    std::fs::write(&model_file, &model_bytes).expect("restore");
    // Without --resume, a run over a checkpoint, even a broken one, is refused.
    std::fs::write(&model_file, &flipped).expect("flip");
    let over = call(args("3", false));
    assert_eq!(over.status.code(), Some(1), "{}", text(&over));
    assert!(text(&over).contains("--resume"), "{}", text(&over));
    std::fs::write(&model_file, &model_bytes).expect("restore");

    // The run folder's own configs resume it, and survive being read and rewritten.
    let model_yaml = std::fs::read_to_string(run.join("tokenizer.yaml")).expect("model config");
    let mut resume_args = args("5", true);
    resume_args.extend([
        "--config".into(),
        run.join("train.yaml").display().to_string(),
    ]);
    let resumed = call(resume_args);
    assert!(resumed.status.success(), "{}", text(&resumed));
    assert_eq!(
        std::fs::read_to_string(run.join("tokenizer.yaml")).expect("model config"),
        model_yaml
    );
    let recorded = std::fs::read_to_string(run.join("train.yaml")).expect("train config");
    assert!(recorded.contains("steps: 5"), "{recorded}");
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
    assert_eq!(
        steps,
        ["1", "2", "3", "3", "3", "4", "5", "5", "5"],
        "{csv}"
    );

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
        format!("models.tiny.tokenizer.weights={}", weights.display()),
    ];
    graph.extend(reconstruct_outputs(&out));
    let output = call(graph);
    assert!(output.status.success(), "{}", text(&output));
    assert!(!text(&output).contains("untrained"), "{}", text(&output));

    // Validation scores the frames as the graph does: the same camera images (the graph's
    // are 8-bit PNGs, hence the PSNR's tolerance), and every ray of the sweep, the returns
    // beyond the rays' far plane among them, as 4D-Occ's protocol renders every ray that has
    // a return. The graph's CSV keeps 5 decimals of the Chamfer; its columns are read by name.
    let column_mean = |csv: &str, name: &str| -> f64 {
        let column = csv
            .lines()
            .next()
            .expect("header")
            .split(',')
            .position(|c| c == name)
            .expect("column name");
        let values: Vec<f64> = csv
            .lines()
            .skip(1)
            .map(|l| {
                l.split(',')
                    .nth(column)
                    .expect("column")
                    .parse()
                    .expect("number")
            })
            .collect();
        values.iter().sum::<f64>() / values.len() as f64
    };
    let per_frame = std::fs::read_to_string(out.join("metrics.csv")).expect("graph metrics");
    let (graph_psnr, graph_chamfer) = (
        column_mean(&per_frame, "psnr_db"),
        column_mean(&per_frame, "chamfer_m2"),
    );
    let run_csv = std::fs::read_to_string(run.join("metrics.csv")).expect("csv");
    let last: Vec<f64> = run_csv
        .lines()
        .last()
        .expect("row")
        .split(',')
        .skip(10)
        .take(3)
        .map(|v| v.parse().expect("number"))
        .collect();
    let (val_psnr, val_chamfer) = (last[0], last[2]);
    assert!(
        (val_psnr - graph_psnr).abs() < 0.02,
        "validation {val_psnr} dB, graph {graph_psnr} dB"
    );
    assert!(
        (val_chamfer - graph_chamfer).abs() <= (1e-4 * graph_chamfer).max(2e-5),
        "validation {val_chamfer} m², graph {graph_chamfer} m²"
    );
}

#[test]
fn an_ablation_run_stops_on_its_schedule_keeps_its_modality_and_checks_targets() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (data, run) = (dir.path().join("data"), dir.path().join("run"));
    synth(&data, "2");
    let args = |extra: &[&str]| train_args(&run, &data, &data, "10", extra);
    let rows = || -> Vec<Vec<String>> {
        std::fs::read_to_string(run.join("metrics.csv"))
            .expect("csv")
            .lines()
            .skip(1)
            .map(|l| l.split(',').map(String::from).collect())
            .collect()
    };

    // L→L, its LiDAR rays drawn by range: no PSNR is measured, so requiring one fails; the run
    // still ends at step 2 of 10.
    let first = bevworld_owned(&args(&[
        "--until",
        "2",
        "--modalities",
        "lidar",
        "--require-psnr",
        "10",
        "--lidar-draw",
        "by_range",
        "--ema-decay",
        "off",
    ]));
    assert_eq!(first.status.code(), Some(1), "{}", text(&first));
    // `off` ships the last iterate: no moving average is recorded, validated or checkpointed.
    let recorded = std::fs::read_to_string(run.join("train.yaml")).expect("train config");
    assert!(!recorded.contains("ema_decay"), "{recorded}");
    assert!(run.join("checkpoints/step-0000002/model.bpk").is_file());
    assert!(!run.join("checkpoints/step-0000002/ema.bpk").exists());
    assert!(
        text(&first).contains("target missed: PSNR ≥ 10 dB required, none measured"),
        "{}",
        text(&first)
    );
    let logged = rows();
    let steps: Vec<&str> = logged.iter().map(|r| r[0].as_str()).collect();
    assert_eq!(steps, ["1", "2", "2"]);
    let val = &logged[2];
    // psnr_db (column 10) is empty, chamfer_m2 (column 12) measured.
    assert_eq!((val[1].as_str(), val[10].as_str()), ("val", ""));
    assert!(val[12].parse::<f64>().is_ok_and(|c| c > 0.0), "{val:?}");
    let model = bevworld_tokenizer::TokenizerConfig::from_yaml_file(&run.join("tokenizer.yaml"))
        .expect("the run's model config reads back");
    assert_eq!(model.modalities, [bevworld_tokenizer::Modality::Lidar]);

    // Resuming it with the committed config's moving average is refused: the run has none.
    let averaged = bevworld_owned(&args(&["--resume", "--until", "3"]));
    assert_eq!(averaged.status.code(), Some(1));
    assert!(
        text(&averaged).contains("without a moving average")
            && text(&averaged).contains("--ema-decay off"),
        "{}",
        text(&averaged)
    );

    // Resumed without --modalities, the run stays L→L; a loose Chamfer bound passes.
    let second = bevworld_owned(&args(&[
        "--resume",
        "--until",
        "3",
        "--require-chamfer",
        "1e9",
        "--lidar-draw",
        "by_range",
        "--ema-decay",
        "off",
    ]));
    assert!(second.status.success(), "{}", text(&second));
    let last = rows().pop().expect("row");
    assert_eq!(
        (last[0].as_str(), last[1].as_str(), last[10].as_str()),
        ("3", "val", "")
    );

    // Resuming it as another ablation is refused, naming the run's modalities.
    let switched = bevworld_owned(&args(&["--resume", "--modalities", "camera"]));
    assert_eq!(switched.status.code(), Some(1));
    assert!(
        text(&switched).contains("trained [Lidar]"),
        "{}",
        text(&switched)
    );

    for (value, said) in [
        (
            "1.5",
            "--ema-decay: ema_decay: 1.5 (accepted: a number in (0, 1)",
        ),
        ("fast", "--ema-decay: 'fast' is neither a number nor 'off'"),
    ] {
        let refused = bevworld_owned(&train_args(
            &dir.path().join("refused"),
            &data,
            &data,
            "10",
            &["--ema-decay", value],
        ));
        assert_eq!(refused.status.code(), Some(1));
        assert!(text(&refused).contains(said), "{}", text(&refused));
        assert!(!dir.path().join("refused").exists());
    }

    let bad = bevworld_owned(&args(&["--modalities", "radar"]));
    assert_eq!(bad.status.code(), Some(1));
    assert!(
        text(&bad).contains("--modalities: unknown modality 'radar'"),
        "{}",
        text(&bad)
    );
    // A dataset that is not there fails before the run folder is made.
    let elsewhere = dir.path().join("elsewhere");
    let missing = dir.path().join("missing");
    let output = bevworld(&[
        "train",
        "tokenizer",
        "--out",
        elsewhere.to_str().expect("utf-8"),
        "--data",
        missing.to_str().expect("utf-8"),
        "--val",
        data.to_str().expect("utf-8"),
    ]);
    assert_eq!(output.status.code(), Some(1), "{}", text(&output));
    assert!(text(&output).contains("missing"), "{}", text(&output));
    assert!(!elsewhere.exists(), "{}", text(&output));

    let bad = bevworld_owned(&args(&["--lidar-draw", "nearest"]));
    assert_eq!(bad.status.code(), Some(1));
    assert!(
        text(&bad).contains("--lidar-draw: 'nearest' is neither 'uniform' nor 'by_range'"),
        "{}",
        text(&bad)
    );
}

#[test]
fn a_run_on_another_ray_grid_records_it_and_resumes_on_it() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (data, run) = (dir.path().join("data"), dir.path().join("run"));
    synth(&data, "3");
    let args = |extra: &[&str]| train_args(&run, &data, &data, "4", extra);
    let stride_of_run = || {
        bevworld_tokenizer::TokenizerConfig::from_yaml_file(&run.join("tokenizer.yaml"))
            .expect("the run's model config reads back")
            .render
            .camera_stride
    };

    // A stride the images cannot take is refused before anything is written.
    let bad = bevworld_owned(&args(&["--camera-stride", "3"]));
    assert_refused_before_writing(
        &bad,
        &run,
        "--camera-stride: render.camera_stride: 3 must be a power of two",
    );

    // The 1/2 grid (the tiny config's is 1/4) is what the run's model config records.
    let first = bevworld_owned(&args(&["--camera-stride", "2", "--until", "1"]));
    assert!(first.status.success(), "{}", text(&first));
    assert_eq!(stride_of_run(), 2);

    // Resumed without the flag, the run stays on its grid (its weights fit no other); naming
    // another grid is refused.
    let switched = bevworld_owned(&args(&["--resume", "--camera-stride", "4"]));
    assert_eq!(switched.status.code(), Some(1), "{}", text(&switched));
    assert!(
        text(&switched).contains("trained on the 1/2 ray grid"),
        "{}",
        text(&switched)
    );
    let second = bevworld_owned(&args(&["--resume", "--until", "2"]));
    assert!(second.status.success(), "{}", text(&second));
    assert!(
        text(&second).contains("resumed at step 1"),
        "{}",
        text(&second)
    );
    assert_eq!(stride_of_run(), 2);
}

/// A loss weight's flag (`--lidar-distortion`, `--lidar-termination`): a negative weight is
/// refused naming the flag and the config field before anything is written; a run records the
/// weight in its `train.yaml`; the term's column holds a value in `range` in every training row
/// when the weight is above 0, and is empty in validation rows and when it is 0.
fn a_loss_weight_flag_is_checked_recorded_and_logged(
    flag: &str,
    field: &str,
    column: &str,
    range: std::ops::Range<f64>,
) {
    let dir = tempfile::tempdir().expect("tempdir");
    let data = dir.path().join("data");
    synth(&data, "4");
    let args = |run: &Path, weight: &str| {
        let flag = format!("--{flag}={weight}");
        train_args(run, &data, &data, "2", &[flag.as_str()])
    };

    let run = dir.path().join("run");
    let bad = bevworld_owned(&args(&run, "-1"));
    assert_refused_before_writing(&bad, &run, &format!("--{flag}: loss.{field}: -1"));

    for (weight, on) in [("0.25", true), ("0", false)] {
        let run = dir.path().join(format!("run-{weight}"));
        let good = bevworld_owned(&args(&run, weight));
        assert!(good.status.success(), "{}", text(&good));
        assert_eq!(recorded_value(&run, field), weight.parse().ok());
        let csv = std::fs::read_to_string(run.join("metrics.csv")).expect("csv");
        let header: Vec<&str> = csv.lines().next().expect("header").split(',').collect();
        let position = header.iter().position(|h| *h == column).expect(column);
        for line in csv.lines().skip(1) {
            let fields: Vec<&str> = line.split(',').collect();
            assert_eq!(fields.len(), header.len(), "{line}");
            let term = fields[position].parse::<f64>().ok();
            match (fields[1], on) {
                ("train", true) => assert!(term.is_some_and(|t| range.contains(&t)), "{line}"),
                _ => assert_eq!(term, None, "{line}"),
            }
        }
    }
}

#[test]
fn the_lidar_distortion_weight_is_checked_recorded_and_logged() {
    // The committed config weighs the term 0.1; the flag overrides it either way. A ray's
    // distortion lies in [0, 1).
    a_loss_weight_flag_is_checked_recorded_and_logged(
        "lidar-distortion",
        "lidar_distortion",
        "loss_distortion",
        1e-9..1.0,
    );
}

#[test]
fn the_lidar_termination_weight_is_checked_recorded_and_logged() {
    // Off in the committed config. A ray's negative log-likelihood lies in [0, −ln 1e-6].
    a_loss_weight_flag_is_checked_recorded_and_logged(
        "lidar-termination",
        "lidar_termination",
        "loss_termination",
        1e-9..13.82,
    );
}

#[test]
fn the_density_sparsity_weight_is_checked_recorded_and_logged() {
    // Off in the committed config. The normalised prior lies in [0, 1]; a field trained for
    // two steps is far from empty.
    a_loss_weight_flag_is_checked_recorded_and_logged(
        "density-sparsity",
        "density_sparsity",
        "loss_sparsity",
        1e-3..1.0,
    );
}

#[test]
fn the_peak_learning_rate_flag_is_checked_recorded_and_followed() {
    let dir = tempfile::tempdir().expect("tempdir");
    let data = dir.path().join("data");
    synth(&data, "4");
    let args = |run: &Path, extra: &[&str]| train_args(run, &data, &data, "2", extra);

    let run = dir.path().join("refused");
    let bad = bevworld_owned(&args(&run, &["--lr=-1"]));
    assert_refused_before_writing(&bad, &run, "--lr: optimizer.lr: -1");

    // The committed config warms up over 100 steps: step 1 trains at a hundredth of the peak,
    // 1.5e-5 for the config's 1.5e-3 and 2e-5 for `--lr 2e-3`.
    for (extra, peak, first) in [
        (&[][..], 1.5e-3, "0.000015"),
        (&["--lr", "2e-3"][..], 2e-3, "0.000020"),
    ] {
        let run = dir.path().join(format!("run-{peak}"));
        let good = bevworld_owned(&args(&run, extra));
        assert!(good.status.success(), "{}", text(&good));
        assert_eq!(recorded_value(&run, "lr"), Some(peak));
        let rows = training_rows(&run);
        assert_eq!(rows[0]["step"], "1");
        assert_eq!(rows[0]["lr"], first);
    }
}

#[test]
fn the_vehicle_share_and_moving_weight_flags_are_checked_before_anything_is_written() {
    let dir = tempfile::tempdir().expect("tempdir");
    let run = dir.path().join("run");
    // The data need not exist: the refusal comes first.
    let (data, val) = (dir.path().join("none"), dir.path().join("none-val"));
    let share = bevworld_owned(&train_args(
        &run,
        &data,
        &val,
        "2",
        &["--lidar-vehicle-share", "1.5"],
    ));
    assert_refused_before_writing(
        &share,
        &run,
        "--lidar-vehicle-share: rays.lidar_vehicle_share: 1.5",
    );
    for (weight, message) in [
        ("four", "--moving-weight: 'four' is not EXTRA,THRESHOLD"),
        ("4", "--moving-weight: '4' is not EXTRA,THRESHOLD"),
        ("4,3,2", "--moving-weight: '4,3,2' is not EXTRA,THRESHOLD"),
    ] {
        let world_model = bevworld_owned(
            &[
                "train",
                "world-model",
                "--out",
                run.to_str().expect("utf-8"),
                "--moving-weight",
                weight,
            ]
            .map(String::from),
        );
        assert_refused_before_writing(&world_model, &run, message);
    }
    let detector = bevworld_owned(
        &[
            "train",
            "detector",
            "--config",
            "configs/models/train-detector-vehicles-tiny.yaml",
            "--input",
            "feature",
            "--out",
            run.to_str().expect("utf-8"),
            "--moving-weight",
            "0.5",
        ]
        .map(String::from),
    );
    assert_refused_before_writing(&detector, &run, "--moving-weight 0.5: not ≥ 1");
}

#[test]
fn the_fine_select_flag_is_checked_before_anything_is_written() {
    let dir = tempfile::tempdir().expect("tempdir");
    let run = dir.path().join("run");
    let fine = "configs/models/finetune-world-model-fine-tiny.yaml";
    let coarse = "configs/models/finetune-world-model-coarse-tiny.yaml";
    for (config, select, message) in [
        (
            fine,
            "eight",
            "--fine-select: 'eight' is not THRESHOLD,DILATE",
        ),
        (
            fine,
            "8,-1",
            "--fine-select: '8,-1' is not THRESHOLD,DILATE",
        ),
        (fine, "-1,0", "fine_tokens.select.threshold: -1"),
        (
            coarse,
            "8,1",
            "--fine-select: the model 'world-model-tiny' has no fine tokens",
        ),
    ] {
        let out = bevworld_owned(
            &[
                "train",
                "world-model",
                "--config",
                config,
                "--out",
                run.to_str().expect("utf-8"),
                // With `=`, a value that starts with a minus is the flag's, not a flag.
                &format!("--fine-select={select}"),
            ]
            .map(String::from),
        );
        assert_refused_before_writing(&out, &run, message);
    }
}

/// The command failed with status 1, its output names `message`, and it wrote no run folder.
fn assert_refused_before_writing(bad: &std::process::Output, run: &Path, message: &str) {
    assert_eq!(bad.status.code(), Some(1), "{}", text(bad));
    assert!(text(bad).contains(message), "{}", text(bad));
    assert!(!run.exists(), "{}", text(bad));
}

/// The number `field` (a loss weight, a step count) as the run recorded it in `RUN/train.yaml`.
fn recorded_value(run: &Path, field: &str) -> Option<f64> {
    let recorded = std::fs::read_to_string(run.join("train.yaml")).expect("train config");
    recorded
        .lines()
        .find_map(|l| l.trim().strip_prefix(&format!("{field}:")))
        .and_then(|v| v.trim().parse::<f64>().ok())
}

/// The training rows of `RUN/metrics.csv`, each field by its column's name.
fn training_rows(run: &Path) -> Vec<std::collections::BTreeMap<String, String>> {
    let csv = std::fs::read_to_string(run.join("metrics.csv")).expect("csv");
    let mut lines = csv.lines();
    let header: Vec<&str> = lines.next().expect("header").split(',').collect();
    lines
        .map(|line| line.split(',').collect::<Vec<_>>())
        .inspect(|fields| assert_eq!(fields.len(), header.len(), "{fields:?}"))
        .filter(|fields| fields[1] == "train")
        .map(|fields| {
            header
                .iter()
                .zip(fields)
                .map(|(h, f)| (h.to_string(), f.to_string()))
                .collect()
        })
        .collect()
}

#[test]
fn steps_sets_the_decay_horizon_where_until_keeps_the_configs() {
    let dir = tempfile::tempdir().expect("tempdir");
    let data = dir.path().join("data");
    synth(&data, "4");
    let (committed, _) = bevworld_tokenizer_train::TrainConfig::from_yaml_file(
        &common::repo().join("configs/models/train-tokenizer-tiny.yaml"),
    )
    .expect("the committed training config");
    let horizon = committed.optimizer.decay_steps.expect("a decay horizon") as f64;

    // `--until` alone: the committed schedule, its horizon recorded for `--resume`.
    let kept = dir.path().join("kept");
    let mut args: Vec<String> = ["train", "tokenizer", "--out"].map(String::from).to_vec();
    args.push(kept.display().to_string());
    for (flag, value) in [("--data", &data), ("--val", &data)] {
        args.extend([flag.to_string(), value.display().to_string()]);
    }
    args.extend(["--until".into(), "1".into()]);
    let first = bevworld_owned(&args);
    assert!(first.status.success(), "{}", text(&first));
    assert_eq!(recorded_value(&kept, "decay_steps"), Some(horizon));
    assert_eq!(recorded_value(&kept, "steps"), Some(committed.steps as f64));

    // `--steps N`: N steps that decay over N, the config's horizon set aside.
    let own = dir.path().join("own");
    let second = bevworld_owned(&train_args(&own, &data, &data, "5", &["--until", "1"]));
    assert!(second.status.success(), "{}", text(&second));
    assert_eq!(recorded_value(&own, "steps"), Some(5.0));
    assert_eq!(recorded_value(&own, "decay_steps"), None);
}

#[test]
fn the_squared_rgb_weight_is_checked_recorded_and_logged() {
    // 5 in the committed config; the flag overrides it either way. Colours lie in [0, 1], so
    // a mean squared error does too.
    a_loss_weight_flag_is_checked_recorded_and_logged(
        "rgb-l2",
        "rgb_l2",
        "loss_rgb_squared",
        1e-9..1.0,
    );
}

#[test]
fn the_rgb_l1_weight_is_checked_recorded_and_weighs_the_loss() {
    let dir = tempfile::tempdir().expect("tempdir");
    let data = dir.path().join("data");
    synth(&data, "6");
    let run = dir.path().join("run-bad");
    let bad = bevworld_owned(&train_args(&run, &data, &data, "2", &["--rgb-l1=-1"]));
    assert_refused_before_writing(&bad, &run, "--rgb-l1: loss.rgb_l1: -1");

    // RGB L1 alone at weight 2 (the squared term off): every training row's loss is twice the
    // RGB term plus the committed LiDAR (0.025) and distortion (0.1) terms.
    let run = dir.path().join("run");
    let flags = ["--rgb-l1=2", "--rgb-l2=0"];
    let good = bevworld_owned(&train_args(&run, &data, &data, "2", &flags));
    assert!(good.status.success(), "{}", text(&good));
    assert_eq!(recorded_value(&run, "rgb_l1"), Some(2.0));
    let rows = training_rows(&run);
    assert_eq!(rows.len(), 2, "{rows:?}");
    for row in rows {
        let value = |name: &str| row[name].parse::<f64>().unwrap_or(f64::NAN);
        assert_eq!(row["loss_rgb_squared"], "", "{row:?}");
        let expected =
            2.0 * value("loss_rgb") + 0.025 * value("loss_lidar") + 0.1 * value("loss_distortion");
        assert!(value("loss_rgb") > 0.0, "{row:?}");
        assert!(
            (value("loss") - expected).abs() < 1e-5,
            "{row:?}: {expected}"
        );
    }
}

#[test]
fn the_lidar_l1_weight_is_checked_recorded_and_weighs_the_loss() {
    let dir = tempfile::tempdir().expect("tempdir");
    let data = dir.path().join("data");
    synth(&data, "5");
    let args = |run: &Path, weight: &str| {
        let flag = format!("--lidar-l1={weight}");
        train_args(run, &data, &data, "2", &[flag.as_str()])
    };

    // A negative or non-finite weight is refused before anything is written.
    for weight in ["-0.5", "NaN"] {
        let run = dir.path().join("run-bad");
        let bad = bevworld_owned(&args(&run, weight));
        assert_refused_before_writing(&bad, &run, &format!("--lidar-l1: loss.lidar_l1: {weight}"));
    }

    // The run records the weight, and every training row's loss is the RGB terms at the
    // committed config's weights (L1 0.5, squared 5), the LiDAR term at the flag's weight and
    // the distortion term at the committed 0.1 (the perceptual term has no weights here and
    // the GAN has not started).
    let run = dir.path().join("run");
    let good = bevworld_owned(&args(&run, "0.5"));
    assert!(good.status.success(), "{}", text(&good));
    assert_eq!(recorded_value(&run, "lidar_l1"), Some(0.5));
    let rows = training_rows(&run);
    assert_eq!(rows.len(), 2, "{rows:?}");
    for row in rows {
        let value = |name: &str| row[name].parse::<f64>().unwrap_or(f64::NAN);
        let expected = 0.5 * value("loss_rgb")
            + 5.0 * value("loss_rgb_squared")
            + 0.5 * value("loss_lidar")
            + 0.1 * value("loss_distortion");
        assert!(value("loss_lidar") > 0.1, "{row:?}");
        // Colours lie in [0, 1]: the squared error is positive and below the absolute one.
        let squared = value("loss_rgb_squared");
        assert!(squared > 0.0 && squared <= value("loss_rgb"), "{row:?}");
        assert!(
            (value("loss") - expected).abs() < 1e-5,
            "{row:?}: {expected}"
        );
    }
}

#[test]
fn runs_of_no_steps_are_refused_before_anything_is_written() {
    let dir = tempfile::tempdir().expect("tempdir");
    let run = dir.path().join("run");
    // The data need not exist: the refusal comes first.
    let (data, val) = (dir.path().join("none"), dir.path().join("none-val"));
    let until_zero = bevworld_owned(&train_args(&run, &data, &val, "5", &["--until", "0"]));
    assert_refused_before_writing(&until_zero, &run, "--until 0");
    let steps_zero = bevworld_owned(&train_args(&run, &data, &val, "0", &[]));
    assert_refused_before_writing(&steps_zero, &run, "steps");
    let world_model = bevworld_owned(
        &[
            "train",
            "world-model",
            "--out",
            run.to_str().expect("utf-8"),
            "--until",
            "0",
        ]
        .map(String::from),
    );
    assert_refused_before_writing(&world_model, &run, "--until 0");
}
