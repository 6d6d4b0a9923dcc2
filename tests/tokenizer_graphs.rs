//! The tokenizer's graphs as a user runs them: `reconstruct.yaml` writes inputs,
//! reconstructions, side-by-side pairs, sweeps and metrics; `export_features.yaml` exports the
//! latent and the fused feature; bad model params fail before any frame flows, naming the field.
//! The graphs run the shipped weights on tiny random scenes, so these tests check plumbing and
//! invariants; quality is checked in `nodes/tokenizer/tests/shipped_weights.rs`.

use crate::common;

use common::{bevworld, bevworld_owned, node, reconstruct_outputs, text};

use std::path::Path;

/// `scenes` synthetic scenes of 1 s (2 keyframes each) with small cameras and a sparse LiDAR.
fn synth_small(out: &Path, scenes: usize) {
    let scenes = scenes.to_string();
    let output = bevworld(&[
        "synth",
        "--out",
        out.to_str().expect("utf-8 path"),
        "--scenes",
        &scenes,
        "--camera-size",
        "64x36",
        "--azimuth-step",
        "2",
        "--agents",
        "1",
        "--seconds",
        "1",
    ]);
    assert!(output.status.success(), "{}", text(&output));
}

fn run_reconstruct(data: &Path, out: &Path, extra: &[&str]) -> serde_json::Value {
    let metrics = out.join("metrics.json");
    let mut args: Vec<String> = vec![
        "run".into(),
        "configs/graphs/reconstruct.yaml".into(),
        "--no-progress".into(),
        "--metrics".into(),
        metrics.display().to_string(),
        "--set".into(),
        format!("source.data={}", data.display()),
    ];
    args.extend(reconstruct_outputs(out));
    args.extend(extra.iter().map(|s| s.to_string()));
    let output = bevworld_owned(&args);
    assert!(output.status.success(), "{}", text(&output));
    serde_json::from_slice(&std::fs::read(&metrics).expect("metrics file")).expect("json")
}

fn ply_vertices(path: &Path) -> usize {
    let bytes = std::fs::read(path).expect("ply");
    let header = String::from_utf8_lossy(&bytes[..bytes.len().min(512)]).to_string();
    header
        .lines()
        .find_map(|l| l.strip_prefix("element vertex "))
        .and_then(|n| n.trim().parse().ok())
        .expect("vertex count")
}

#[test]
fn reconstruct_writes_inputs_reconstructions_pairs_sweeps_and_metrics() {
    let dir = tempfile::tempdir().expect("tempdir");
    let data = dir.path().join("data");
    synth_small(&data, 1);
    let out = dir.path().join("out");
    let report = run_reconstruct(&data, &out, &[]);

    let metrics = node(&report, "metrics");
    assert_eq!(
        metrics["items_in"].as_u64(),
        Some(2 * 3),
        "frame, images, lidar for 2 frames"
    );
    let extra = &metrics["extra"];
    assert_eq!(extra["frames_scored"].as_f64(), Some(2.0));
    let psnr = extra["psnr_db_mean"].as_f64().expect("psnr");
    let chamfer = extra["chamfer_m2_mean"].as_f64().expect("chamfer");
    // Untrained: far from the input, but finite and positive.
    assert!(psnr.is_finite() && psnr > 3.0 && psnr < 40.0, "psnr {psnr}");
    assert!(chamfer.is_finite() && chamfer > 0.0, "chamfer {chamfer}");
    assert_eq!(
        node(&report, "render")["extra"]["samples_evaluated_fraction"].as_f64(),
        Some(1.0),
        "dense rendering evaluates every sample"
    );

    let frame = out.join("000000");
    for camera in ["CAM_FRONT", "CAM_BACK_LEFT"] {
        let input = image::open(frame.join(format!("{camera}.png"))).expect("input png");
        assert_eq!((input.width(), input.height()), (64, 36));
        let recon = image::open(frame.join(format!("{camera}_recon.png"))).expect("recon png");
        assert_eq!(
            (recon.width(), recon.height()),
            (112, 64),
            "the tiny model's size"
        );
        let pair = image::open(frame.join(format!("{camera}_input_vs_recon.png"))).expect("pair");
        assert_eq!((pair.width(), pair.height()), (224, 64));
    }
    // One rendered point per input return (the synthetic LiDAR has none off the ego body).
    let inputs = ply_vertices(&frame.join("LIDAR_TOP.ply"));
    assert!(inputs > 1000, "{inputs} input points");
    assert_eq!(ply_vertices(&frame.join("LIDAR_TOP_recon.ply")), inputs);
    let csv = std::fs::read_to_string(out.join("metrics.csv")).expect("csv");
    assert_eq!(csv.lines().count(), 3, "{csv}");
    assert!(csv.starts_with("frame_token,scene,psnr_db,ssim,chamfer_m2"));

    // Empty-space skipping with early stop: fewer samples, same outputs written.
    let skipped = run_reconstruct(
        &data,
        &dir.path().join("skipped"),
        &["--set", "render.skipping.stop_transmittance=0.0001"],
    );
    let fraction = node(&skipped, "render")["extra"]["samples_evaluated_fraction"]
        .as_f64()
        .expect("fraction");
    assert!(fraction > 0.0 && fraction < 1.0, "fraction {fraction}");
}

#[test]
fn eval_tokenizer_scores_each_scene_and_the_spread_over_scenes() {
    let dir = tempfile::tempdir().expect("tempdir");
    let data = dir.path().join("data");
    synth_small(&data, 2);
    let eval = |extra: &[&str]| {
        let out = dir.path().join("eval");
        let mut args = vec![
            "eval",
            "tokenizer",
            "--data",
            data.to_str().expect("utf-8 path"),
            "--out",
            out.to_str().expect("utf-8 path"),
        ];
        args.extend(extra);
        bevworld(&args)
    };
    let output = eval(&["--json"]);
    assert!(output.status.success(), "{}", text(&output));
    let table: serde_json::Value = serde_json::from_slice(&output.stdout).expect("json");
    assert_eq!(table["frames"], 4);
    assert_eq!(
        table["weights"], "nodes/tokenizer/weights/tokenizer-tiny.bpk",
        "the graph's weights, said"
    );
    let scenes = table["scenes"].as_array().expect("scenes");
    assert_eq!(scenes.len(), 2);
    let per_scene: Vec<f64> = scenes
        .iter()
        .map(|s| {
            assert_eq!(s["frames"], 2);
            s["psnr_db"].as_f64().expect("psnr")
        })
        .collect();
    // Two keyframes each: the mean over keyframes is the mean of the scenes' means, and the
    // spread of two values is half their distance.
    let psnr = table["psnr_db"].as_f64().expect("psnr");
    assert!((psnr - (per_scene[0] + per_scene[1]) / 2.0).abs() < 1e-9);
    let spread = table["scene_std"]["psnr_db"].as_f64().expect("spread");
    assert!((spread - (per_scene[0] - per_scene[1]).abs() / 2.0).abs() < 1e-9);
    assert!(psnr.is_finite() && table["chamfer_m2"].as_f64().is_some_and(f64::is_finite));
    assert!(dir.path().join("eval/metrics.csv").is_file());
    assert!(dir.path().join("eval/000003/CAM_FRONT_recon.png").is_file());

    // The same weights named on the command line give the same figures; the table names them.
    let shipped = common::repo().join("nodes/tokenizer/weights/tokenizer-tiny.bpk");
    let output = eval(&["--weights", shipped.to_str().expect("utf-8 path")]);
    assert!(output.status.success(), "{}", text(&output));
    let printed = String::from_utf8_lossy(&output.stdout);
    assert!(
        printed.contains(&format!("{psnr:.2} ± {spread:.2}")) && printed.contains("| 2 |"),
        "{printed}"
    );

    // Bad input: each refusal names what was wrong.
    for (args, expected) in [
        (
            vec!["--weights", "/nonexistent/tokenizer.bpk"],
            "/nonexistent/tokenizer.bpk",
        ),
        (vec!["--set", "metrics.colour=1"], "colour"),
    ] {
        let output = eval(&args);
        assert!(!output.status.success());
        assert!(text(&output).contains(expected), "{}", text(&output));
    }
    let output = bevworld(&["eval", "tokenizer", "--data", "/nonexistent/data"]);
    assert!(!output.status.success());
    assert!(
        text(&output).contains("/nonexistent/data"),
        "{}",
        text(&output)
    );
}

#[test]
fn on_the_real_keyframe_the_rendered_sweep_leaves_out_the_returns_off_the_car() {
    let Some(nuscenes) = bevworld_sensors::real_dataset("nuscenes-sample") else {
        return;
    };
    let dir = tempfile::tempdir().expect("tempdir");
    let out = dir.path().join("out");
    let report = run_reconstruct(&nuscenes, &out, &[]);
    let frame = out.join("000000");
    // 8,526 of the sweep's 34,688 returns lie in 4D-Occ's ego box: no ray is cast for them.
    assert_eq!(ply_vertices(&frame.join("LIDAR_TOP.ply")), 34_688);
    assert_eq!(
        ply_vertices(&frame.join("LIDAR_TOP_recon.ply")),
        34_688 - 8_526
    );
    let chamfer = node(&report, "metrics")["extra"]["chamfer_m2_mean"]
        .as_f64()
        .expect("chamfer");
    assert!(chamfer.is_finite() && chamfer > 0.0, "chamfer {chamfer}");
}

#[test]
fn export_features_writes_the_latent_and_the_fused_feature() {
    let dir = tempfile::tempdir().expect("tempdir");
    let data = dir.path().join("data");
    synth_small(&data, 1);
    let out = dir.path().join("features");
    let output = bevworld(&[
        "run",
        "configs/graphs/export_features.yaml",
        "--no-progress",
        "--set",
        &format!("source.data={}", data.display()),
        "--set",
        &format!("export.out={}", out.display()),
        "--set",
        &format!("export_fused.out={}", out.join("fused").display()),
    ]);
    assert!(output.status.success(), "{}", text(&output));
    let index: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("index.json")).expect("index"))
            .expect("json");
    let frames = index["frames"].as_array().expect("frames");
    assert_eq!(frames.len(), 2);
    assert_eq!(frames[0]["model"], "tokenizer-tiny");
    // The graph runs the shipped weights, and says so by their digest.
    let shipped = bevworld_tokenizer::weights_digest(
        &common::repo().join("nodes/tokenizer/weights/tokenizer-tiny.bpk"),
    )
    .expect("shipped weights");
    assert_eq!(frames[0]["weights_hash"], shipped.as_str());
    let npy = |folder: &Path| -> Vec<usize> {
        let file = std::fs::read_dir(folder)
            .expect("folder")
            .map(|e| e.expect("entry").path())
            .find(|p| p.extension().is_some_and(|x| x == "npy"))
            .expect("an npy file");
        let (shape, values) =
            bevworld_sinks::npy::read_npy_f32(&std::fs::read(file).expect("npy")).expect("parses");
        assert!(values.iter().all(|v| v.is_finite()));
        shape
    };
    assert_eq!(npy(&out), vec![4, 64, 64]);
    assert_eq!(npy(&out.join("fused")), vec![32, 64, 64]);
}

#[test]
fn bad_model_params_fail_before_any_frame_naming_the_field() {
    let dir = tempfile::tempdir().expect("tempdir");
    let garbage = dir.path().join("garbage.bpk");
    std::fs::write(&garbage, b"not a burnpack file").expect("write");
    let cases: Vec<(Vec<String>, Vec<&str>)> = vec![
        (
            vec!["models.tiny.tokenizer.weights=/nonexistent/tokenizer.bpk".into()],
            vec![
                "model bundle 'tiny'",
                "tokenizer.weights",
                "/nonexistent/tokenizer.bpk",
                "not found",
            ],
        ),
        (
            vec![format!(
                "models.tiny.tokenizer.weights={}",
                garbage.display()
            )],
            vec!["'tiny'", "tokenizer.weights", "garbage.bpk"],
        ),
        (
            vec!["models.tiny.tokenizer.config=configs/models/nope.yaml".into()],
            vec!["'tiny'", "tokenizer.config", "nope.yaml"],
        ),
        (
            vec!["encode.model=tyni".into()],
            vec!["encode", "model", "no model bundle 'tyni'"],
        ),
        (
            vec!["render.skipping.segment=0".into()],
            vec!["render", "skipping", "segment"],
        ),
        (vec!["render.chunk=0".into()], vec!["render", "chunk"]),
    ];
    for (sets, expected) in cases {
        let mut args = vec![
            "check".to_string(),
            "configs/graphs/reconstruct.yaml".into(),
        ];
        for set in &sets {
            args.push("--set".into());
            args.push(set.clone());
        }
        let output = bevworld_owned(&args);
        assert!(!output.status.success(), "{sets:?} was accepted");
        let message = text(&output);
        for word in expected {
            assert!(
                message.contains(word),
                "{sets:?}: '{word}' missing from: {message}"
            );
        }
        assert!(!message.contains("panicked"), "{message}");
    }
}

#[test]
fn a_lidar_only_model_refuses_to_render_the_cameras() {
    let dir = tempfile::tempdir().expect("tempdir");
    let data = dir.path().join("data");
    synth_small(&data, 1);
    // The ablation's L -> L model: its camera decoder never trained.
    let tiny = std::fs::read_to_string("configs/models/tokenizer-tiny.yaml").expect("tiny config");
    assert!(tiny.contains("modalities: [camera, lidar]"));
    let lidar_only = dir.path().join("tokenizer-lidar.yaml");
    std::fs::write(
        &lidar_only,
        tiny.replace("modalities: [camera, lidar]", "modalities: [lidar]"),
    )
    .expect("write config");
    let mut args: Vec<String> = vec![
        "run".into(),
        "configs/graphs/reconstruct.yaml".into(),
        "--no-progress".into(),
        "--set".into(),
        format!("source.data={}", data.display()),
        "--set".into(),
        format!("models.tiny.tokenizer.config={}", lidar_only.display()),
        "--set".into(),
        "models.tiny.tokenizer.weights=untrained".into(),
    ];
    args.extend(reconstruct_outputs(&dir.path().join("out")));
    let output = bevworld_owned(&args);
    let message = text(&output);
    assert!(!output.status.success(), "rendered cameras: {message}");
    for word in [
        "render",
        "`images`",
        "without the cameras",
        "modalities: lidar",
    ] {
        assert!(message.contains(word), "'{word}' missing from: {message}");
    }
    assert!(!message.contains("panicked"), "{message}");
}

#[test]
fn tokenizer_stats_matches_the_latents_it_summarises() {
    use bevworld_tokenizer::{FrameInputs, TokenizerConfig, load_weights, save_weights};
    use bevworld_types::{LatentStatsFile, stats_path_for};

    let dir = tempfile::tempdir().expect("tempdir");
    let data = dir.path().join("data");
    synth_small(&data, 1);
    let root = std::path::PathBuf::from(
        std::env::var_os("CARGO_MANIFEST_DIR").expect("cargo sets CARGO_MANIFEST_DIR"),
    );
    let config_path = root.join("configs/models/tokenizer-tiny.yaml");
    let config = TokenizerConfig::from_yaml_file(&config_path).expect("config");
    let device = burn::prelude::Device::flex();
    let weights = dir.path().join("tiny.bpk");
    save_weights(&config.init_seeded(0, &device), &weights).expect("save");

    let output = bevworld(&[
        "tokenizer",
        "stats",
        "--config",
        config_path.to_str().expect("utf-8"),
        "--weights",
        weights.to_str().expect("utf-8"),
        "--data",
        data.to_str().expect("utf-8"),
    ]);
    assert!(output.status.success(), "{}", text(&output));
    let path = stats_path_for(&weights);
    assert_eq!(path, dir.path().join("tiny.stats.json"));
    let file = LatentStatsFile::load(&path).expect("stats file");
    assert_eq!(file.model, "tokenizer-tiny");
    assert_eq!(file.stats.frames, 2);
    let digest = bevworld_tokenizer::weights_digest(&weights).expect("digest");
    file.check_matches("tokenizer-tiny", &digest, &path)
        .expect("same weights");
    assert!(file.check_matches("tokenizer-tiny", "0123", &path).is_err());

    // A second run over fewer frames must not silently replace the file.
    let before = std::fs::read(&path).expect("stats bytes");
    let rerun = |extra: &[&str]| {
        let mut args = vec![
            "tokenizer",
            "stats",
            "--config",
            config_path.to_str().expect("utf-8"),
            "--weights",
            weights.to_str().expect("utf-8"),
            "--data",
            data.to_str().expect("utf-8"),
            "--max-frames",
            "1",
        ];
        args.extend_from_slice(extra);
        bevworld(&args)
    };
    let refused = rerun(&[]);
    assert!(!refused.status.success());
    assert!(text(&refused).contains("--overwrite"), "{}", text(&refused));
    assert_eq!(std::fs::read(&path).expect("stats bytes"), before);
    let replaced = rerun(&["--overwrite"]);
    assert!(replaced.status.success(), "{}", text(&replaced));
    assert_eq!(LatentStatsFile::load(&path).expect("stats").stats.frames, 1);
    std::fs::write(&path, &before).expect("restore");

    // The same latents, encoded here, give the same per-channel means and deviations.
    let model = load_weights(&config, &weights, &device).expect("load");
    let inputs = FrameInputs::new(&config);
    let dataset = bevworld_sensors::Dataset::open(&data, &Default::default()).expect("dataset");
    let mut values: Vec<Vec<f64>> = vec![Vec::new(); 4];
    for index in 0..dataset.len() {
        let frame = dataset.read(index).expect("frame");
        let mut points = Vec::new();
        bevworld_pillarize::ego_points_into(&frame.lidar, &mut points);
        let pillars = bevworld_pillarize::Pillarizer::new(inputs.pillar_grid(), Default::default())
            .run(&points);
        let input = inputs
            .encoder_input(&frame, &pillars, &device)
            .expect("input");
        let latent = model
            .encode(input)
            .latent
            .into_data()
            .try_to_vec::<f32>()
            .expect("latent");
        let cells = config.latent_size() * config.latent_size();
        for (c, plane) in latent.chunks(cells).enumerate() {
            values[c].extend(plane.iter().map(|&v| f64::from(v)));
        }
    }
    for (c, channel) in values.iter().enumerate() {
        let n = channel.len() as f64;
        let mean = channel.iter().sum::<f64>() / n;
        let std = (channel.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n).sqrt();
        assert!(
            (file.stats.mean[c] - mean).abs() < 1e-5 * (1.0 + mean.abs()),
            "channel {c} mean"
        );
        assert!(
            (file.stats.std[c] - std).abs() < 1e-5 * (1.0 + std),
            "channel {c} std"
        );
    }

    let missing = bevworld(&[
        "tokenizer",
        "stats",
        "--weights",
        "/nonexistent/w.bpk",
        "--data",
        data.to_str().expect("utf-8"),
    ]);
    assert_eq!(missing.status.code(), Some(1));
    assert!(
        text(&missing).contains("/nonexistent/w.bpk"),
        "{}",
        text(&missing)
    );
}

#[test]
fn check_reads_no_weights_and_run_loads_them() {
    use bevworld_tokenizer::{TokenizerConfig, save_weights};
    use burn::prelude::Device;

    // A real burnpack file of a wider decoder: a valid header, tensors of other shapes.
    let dir = tempfile::tempdir().expect("tempdir");
    let mut wider =
        TokenizerConfig::from_yaml_file(&common::repo().join("configs/models/tokenizer-tiny.yaml"))
            .expect("tiny config");
    wider.decoder.dim = 64;
    let weights = dir.path().join("wider.bpk");
    save_weights(&wider.init_seeded(1, &Device::flex()), &weights).expect("save");
    let data = dir.path().join("data");
    synth_small(&data, 1);
    let sets = [
        format!("models.tiny.tokenizer.weights={}", weights.display()),
        format!("data={}", data.display()),
    ];
    let with_sets = |command: &str| {
        let mut args = vec![
            command.to_string(),
            "configs/graphs/reconstruct.yaml".into(),
        ];
        for set in &sets {
            args.extend(["--set".to_string(), set.clone()]);
        }
        args
    };
    // `check` validates what it can without loading a tensor: it accepts the file...
    let checked = bevworld_owned(&with_sets("check"));
    assert!(checked.status.success(), "{}", text(&checked));
    // ...and `run` builds the nodes, loads the weights, and refuses them before any frame.
    let mut run = with_sets("run");
    run.push("--no-progress".into());
    let refused = bevworld_owned(&run);
    assert_eq!(refused.status.code(), Some(2), "{}", text(&refused));
    let message = text(&refused);
    assert!(
        message.contains("weights") && message.contains("do not fit"),
        "{message}"
    );
    assert!(!message.contains("panicked"), "{message}");
}
