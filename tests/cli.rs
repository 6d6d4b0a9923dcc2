//! The `bevworld` tool as a user runs it: exit codes, error messages and written files.

use crate::common;

use common::{bevworld, node, text};

use std::path::{Path, PathBuf};
use std::process::Command;

/// A small synthetic dataset for tests: 32x18 cameras, a 3-degree LiDAR and one agent;
/// `extra` adds the scene count and length.
fn synth_small(out: &Path, extra: &[&str]) {
    let mut args = vec![
        "synth",
        "--out",
        out.to_str().unwrap(),
        "--camera-size",
        "32x18",
        "--azimuth-step",
        "3",
        "--agents",
        "1",
    ];
    args.extend_from_slice(extra);
    let output = bevworld(&args);
    assert!(output.status.success(), "{}", text(&output));
}

fn nuscenes() -> Option<PathBuf> {
    bevworld_sensors::real_dataset("nuscenes-sample")
}

#[test]
fn replay_writes_pngs_and_a_ply_that_parse_back() {
    let Some(nuscenes) = nuscenes() else {
        return;
    };
    let out = tempfile::tempdir().unwrap();
    let o = out.path().display().to_string();
    let metrics = out.path().join("metrics.json");
    let output = bevworld(&[
        "run",
        "configs/graphs/replay.yaml",
        "--set",
        &format!("source.data={}", nuscenes.clone().display()),
        "--set",
        &format!("images.out={o}"),
        "--set",
        &format!("sweeps.out={o}"),
        "--metrics",
        metrics.to_str().unwrap(),
        "--no-progress",
    ]);
    assert!(output.status.success(), "{}", text(&output));
    for channel in [
        "CAM_FRONT",
        "CAM_FRONT_RIGHT",
        "CAM_BACK_RIGHT",
        "CAM_BACK",
        "CAM_BACK_LEFT",
        "CAM_FRONT_LEFT",
    ] {
        let png = image::open(out.path().join(format!("000000/{channel}.png"))).unwrap();
        assert_eq!((png.width(), png.height()), (1600, 900), "{channel}");
        assert!(matches!(png, image::DynamicImage::ImageRgb8(_)));
    }
    let ply = out.path().join("000000/LIDAR_TOP.ply");
    let header = std::fs::read(&ply).unwrap();
    assert!(String::from_utf8_lossy(&header[..200]).contains("format binary_little_endian 1.0"));
    let points = bevworld_sinks_ply::read(&ply);
    assert_eq!(points, 34_688);
    // No temporary files left behind by the atomic writes.
    let leftovers: Vec<_> = std::fs::read_dir(out.path().join("000000"))
        .unwrap()
        .filter(|e| {
            e.as_ref()
                .unwrap()
                .file_name()
                .to_string_lossy()
                .ends_with(".tmp")
        })
        .collect();
    assert!(leftovers.is_empty());
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&metrics).unwrap()).unwrap();
    assert_eq!(report["outcome"], "completed");
    let source = node(&report, "source");
    assert_eq!(source["items_out"], 1);
}

/// Reads a PLY with ply-rs-bw's generic element map, independently of our own codec.
mod bevworld_sinks_ply {
    use ply_rs_bw::parser::Parser;
    use ply_rs_bw::ply::DefaultElement;

    pub fn read(path: &std::path::Path) -> usize {
        let mut file = std::fs::File::open(path).unwrap();
        let ply = Parser::<DefaultElement>::new().read_ply(&mut file).unwrap();
        let vertex = &ply.payload["vertex"];
        assert!(vertex[0].contains_key("intensity"));
        vertex.len()
    }
}

#[test]
fn check_reports_problems_with_positions_and_exits_2() {
    let dir = tempfile::tempdir().unwrap();
    let graph = dir.path().join("bad.yaml");
    std::fs::write(&graph, "nodes:\n  - {id: source, kind: dataset_sourc, params: {data: x}}\n  - {id: png, kind: png_sink, params: {out: o, colour: red}}\n").unwrap();
    let output = bevworld(&["check", graph.to_str().unwrap()]);
    assert_eq!(output.status.code(), Some(2));
    let message = text(&output);
    assert!(
        message.contains("bad.yaml:2:") && message.contains("did you mean 'dataset_source'"),
        "{message}"
    );
    assert!(
        message.contains("'colour'") && message.contains("accepted:"),
        "{message}"
    );
    assert!(message.contains("required input 'png.images'"), "{message}");
}

#[test]
fn check_and_dot_on_the_shipped_graphs() {
    for graph in std::fs::read_dir(
        PathBuf::from(
            std::env::var_os("CARGO_MANIFEST_DIR").expect("cargo sets CARGO_MANIFEST_DIR"),
        )
        .join("configs/graphs"),
    )
    .unwrap()
    {
        let path = graph.unwrap().path();
        let output = bevworld(&["check", path.to_str().unwrap()]);
        assert!(
            output.status.success(),
            "{}: {}",
            path.display(),
            text(&output)
        );
        let dot = bevworld(&["graph", path.to_str().unwrap(), "--dot"]);
        assert!(String::from_utf8_lossy(&dot.stdout).starts_with("digraph"));
    }
}

#[test]
fn a_missing_dataset_fails_naming_node_and_path() {
    let output = bevworld(&[
        "run",
        "configs/graphs/replay.yaml",
        "--set",
        "source.data=/no/such/dataset",
        "--set",
        "source.generate=null",
        "--no-progress",
    ]);
    assert_eq!(output.status.code(), Some(1));
    let message = text(&output);
    assert!(
        message.contains("node 'source'") && message.contains("/no/such/dataset"),
        "{message}"
    );
}

#[test]
fn a_corrupt_frame_is_skipped_under_skip_and_stops_under_stop() {
    // Two synthetic frames; the second one's front camera image is corrupted.
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("data");
    synth_small(&data, &["--seconds", "1"]);
    let keyframe = std::fs::read_dir(data.join("samples/CAM_FRONT"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .max()
        .unwrap();
    std::fs::write(&keyframe, b"not an image").unwrap();
    let out = dir.path().join("out");
    let run = |on_error: &str| {
        bevworld(&[
            "run",
            "configs/graphs/replay.yaml",
            "--set",
            &format!("source.data={}", data.display()),
            "--set",
            "source.sweeps=true",
            "--set",
            &format!("source.on_error={on_error}"),
            "--set",
            "source.pacing.speed=0",
            "--set",
            &format!("images.out={}", out.display()),
            "--set",
            &format!("sweeps.out={}", out.display()),
            "--metrics",
            dir.path()
                .join(format!("{on_error}.json"))
                .to_str()
                .unwrap(),
            "--no-progress",
        ])
    };
    let skipped = run("skip");
    assert!(skipped.status.success(), "{}", text(&skipped));
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.path().join("skip.json")).unwrap()).unwrap();
    let source = node(&report, "source");
    assert_eq!(source["skips"], 1);
    assert_eq!(source["items_out"], 11, "the other 11 frames go through");
    let stopped = run("stop");
    assert_eq!(stopped.status.code(), Some(1));
    let message = text(&stopped);
    assert!(
        message.contains("node 'source'")
            && message.contains("CAM_FRONT")
            && message.contains("corrupt image"),
        "{message}"
    );
}

#[test]
fn shard_and_overwrite_flags_reach_the_nodes() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("data");
    synth_small(&data, &["--scenes", "2", "--seconds", "1"]);
    let out = dir.path().join("features");
    let run = |extra: &[&str]| {
        let metrics = dir.path().join("m.json");
        let mut args = vec![
            "run".to_string(),
            "configs/graphs/export_bev_stats.yaml".into(),
            "--set".into(),
            format!("source.data={}", data.display()),
            "--set".into(),
            format!("export.out={}", out.display()),
            "--metrics".into(),
            metrics.display().to_string(),
            "--no-progress".into(),
        ];
        args.extend(extra.iter().map(|s| s.to_string()));
        let output = Command::new(env!("CARGO_BIN_EXE_bevworld"))
            .args(&args)
            .current_dir(
                std::env::var_os("CARGO_MANIFEST_DIR").expect("cargo sets CARGO_MANIFEST_DIR"),
            )
            .output()
            .unwrap();
        assert!(output.status.success(), "{}", text(&output));
        let report: serde_json::Value =
            serde_json::from_slice(&std::fs::read(&metrics).unwrap()).unwrap();
        let export = node(&report, "export").clone();
        (
            export["items_in"].as_u64().unwrap(),
            export["extra"]["files_written"].as_f64().unwrap(),
        )
    };
    // Two scenes of 2 keyframes each: shard 1/2 takes the second scene only.
    assert_eq!(run(&["--shard", "1/2"]), (2, 2.0));
    assert_eq!(
        run(&[]),
        (4, 2.0),
        "the first scene's files are new, the second's are skipped"
    );
    assert_eq!(run(&["--overwrite"]), (4, 4.0));
    let bad = bevworld(&[
        "run",
        "configs/graphs/export_bev_stats.yaml",
        "--shard",
        "2/2",
    ]);
    assert_eq!(bad.status.code(), Some(1));
    assert!(
        text(&bad).contains("--shard") && text(&bad).contains("0 <= I < N"),
        "{}",
        text(&bad)
    );
}

#[test]
fn four_shards_at_once_into_one_folder_index_every_file_once() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("data");
    synth_small(&data, &["--scenes", "8", "--seconds", "1"]);
    let out = dir.path().join("features");
    // A temporary a killed writer left: the first shard to start removes it, and no shard
    // removes another's.
    std::fs::create_dir_all(&out).unwrap();
    let stale = out.join("old.npy.4000000000.0.tmp");
    std::fs::write(&stale, b"left by a kill").unwrap();
    let shards: Vec<std::process::Child> = (0..4)
        .map(|shard| {
            Command::new(env!("CARGO_BIN_EXE_bevworld"))
                .args([
                    "run",
                    "configs/graphs/export_bev_stats.yaml",
                    "--set",
                    &format!("source.data={}", data.display()),
                    "--set",
                    &format!("export.out={}", out.display()),
                    "--shard",
                    &format!("{shard}/4"),
                    "--no-progress",
                ])
                .current_dir(env!("CARGO_MANIFEST_DIR"))
                .stdout(std::process::Stdio::piped())
                .stderr(std::process::Stdio::piped())
                .spawn()
                .unwrap()
        })
        .collect();
    for child in shards {
        let output = child.wait_with_output().unwrap();
        assert!(output.status.success(), "{}", text(&output));
    }
    let index: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("index.json")).unwrap()).unwrap();
    let mut listed: Vec<String> = index["frames"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| f["file"].as_str().unwrap().to_string())
        .collect();
    listed.sort();
    let mut on_disk: Vec<String> = std::fs::read_dir(&out)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().to_string())
        .filter(|n| n.ends_with(".npy"))
        .collect();
    on_disk.sort();
    // Eight scenes of two keyframes each: sixteen files, each listed once.
    assert_eq!(on_disk.len(), 16, "{on_disk:?}");
    assert_eq!(listed, on_disk);
    let scenes: std::collections::BTreeSet<&str> = index["frames"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| f["scene"].as_str().unwrap())
        .collect();
    assert_eq!(scenes.len(), 8);
    assert!(!stale.exists(), "a dead writer's temporary is removed");
    let leftovers: Vec<String> = std::fs::read_dir(&out)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().to_string())
        .filter(|n| n.ends_with(".tmp"))
        .collect();
    assert!(leftovers.is_empty(), "{leftovers:?}");
}

#[test]
fn the_source_counts_dropped_points_and_normalised_rotations_in_the_metrics() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("data");
    synth_small(&data, &["--scenes", "1", "--seconds", "1"]);
    // Three NaN coordinates in one sweep (5 floats a point), and one ego pose's rotation
    // scaled to twice unit length.
    let sweep = std::fs::read_dir(data.join("samples/LIDAR_TOP"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .min()
        .unwrap();
    let mut bytes = std::fs::read(&sweep).unwrap();
    for point in [0usize, 10, 20] {
        let at = point * 20;
        bytes[at..at + 4].copy_from_slice(&f32::NAN.to_le_bytes());
    }
    std::fs::write(&sweep, &bytes).unwrap();
    let poses = data.join("v1.0-synth/ego_pose.json");
    let mut table: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&poses).unwrap()).unwrap();
    for k in 0..4 {
        let v = table[0]["rotation"][k].as_f64().unwrap();
        table[0]["rotation"][k] = (2.0 * v).into();
    }
    std::fs::write(&poses, serde_json::to_vec(&table).unwrap()).unwrap();
    let metrics = dir.path().join("m.json");
    let output = bevworld(&[
        "run",
        "configs/graphs/export_bev_stats.yaml",
        "--set",
        &format!("source.data={}", data.display()),
        "--set",
        &format!("export.out={}", dir.path().join("features").display()),
        "--metrics",
        metrics.to_str().unwrap(),
        "--no-progress",
    ]);
    assert!(output.status.success(), "{}", text(&output));
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&metrics).unwrap()).unwrap();
    let source = node(&report, "source");
    assert_eq!(source["extra"]["non_finite_points_dropped"], 3.0);
    assert_eq!(source["extra"]["non_unit_quaternions_normalised"], 1.0);
    // The table printed at the end shows them.
    assert!(
        text(&output).contains("non_finite_points_dropped = 3"),
        "{}",
        text(&output)
    );
}

#[test]
fn errors_say_each_cause_once_and_in_our_words() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("nope.ply");
    let other = dir.path().join("other.ply");
    let chamfer = bevworld(&[
        "eval",
        "chamfer",
        "--pred",
        missing.to_str().unwrap(),
        "--gt",
        other.to_str().unwrap(),
    ]);
    assert_eq!(chamfer.status.code(), Some(1));
    let message = text(&chamfer);
    assert_eq!(message.matches("os error 2").count(), 1, "{message}");
    assert!(message.contains("nope.ply"), "{message}");

    let folder = dir.path().join("no-dataset");
    let inspect = bevworld(&[
        "inspect",
        "--data",
        folder.to_str().unwrap(),
        "--out",
        dir.path().join("inspect").to_str().unwrap(),
    ]);
    assert_eq!(inspect.status.code(), Some(1));
    let message = text(&inspect);
    assert_eq!(
        message.matches(folder.to_str().unwrap()).count(),
        1,
        "{message}"
    );
    assert!(message.contains("does not exist"), "{message}");

    // A key written twice: the place and a sentence, not the parser library's options.
    let graph = dir.path().join("twice.yaml");
    let yaml = std::fs::read_to_string("configs/graphs/reconstruct.yaml").unwrap();
    std::fs::write(&graph, format!("name: first\n{yaml}")).unwrap();
    let check = bevworld(&["check", graph.to_str().unwrap()]);
    assert_eq!(check.status.code(), Some(2), "{}", text(&check));
    let message = text(&check);
    assert!(message.contains("duplicate mapping key: name"), "{message}");
    assert!(message.contains("a key may appear once"), "{message}");
    assert!(!message.contains("DuplicateKeyPolicy"), "{message}");
    let config = dir.path().join("twice-train.yaml");
    std::fs::write(&config, "steps: 3\nsteps: 4\n").unwrap();
    let train = bevworld(&[
        "train",
        "tokenizer",
        "--config",
        config.to_str().unwrap(),
        "--out",
        dir.path().join("run").to_str().unwrap(),
    ]);
    assert_eq!(train.status.code(), Some(1));
    let message = text(&train);
    assert!(message.contains("line 2, column 1"), "{message}");
    assert!(message.contains("twice-train.yaml"), "{message}");
    assert!(!message.contains("DuplicateKeyPolicy"), "{message}");
    assert_eq!(message.lines().count(), 1, "{message}");
}

#[test]
fn bad_set_syntax_is_an_error() {
    // Refused before any work: exit 2, as every refusal (`commands::Refused`).
    let output = bevworld(&["check", "configs/graphs/replay.yaml", "--set", "nodot"]);
    assert_eq!(output.status.code(), Some(2));
    assert!(text(&output).contains("not node.key=value"));
}

#[test]
fn ctrl_c_drains_and_exits_cleanly() {
    let Some(nuscenes) = nuscenes() else {
        return;
    };
    let out = tempfile::tempdir().unwrap();
    let metrics = out.path().join("metrics.json");
    let child = Command::new(env!("CARGO_BIN_EXE_bevworld"))
        .args([
            "run",
            "configs/graphs/replay.yaml",
            "--set",
            &format!("source.data={}", nuscenes.clone().display()),
            "--set",
            "source.repeat=1000",
            "--set",
            "source.skip_images=true",
            "--set",
            &format!("images.out={}", out.path().display()),
            "--set",
            &format!("sweeps.out={}", out.path().display()),
            "--metrics",
            metrics.to_str().unwrap(),
            "--no-progress",
        ])
        .current_dir(std::env::var_os("CARGO_MANIFEST_DIR").expect("cargo sets CARGO_MANIFEST_DIR"))
        .spawn()
        .unwrap();
    std::thread::sleep(std::time::Duration::from_millis(1500));
    let status = Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(status.success());
    let output = child.wait_with_output().unwrap();
    assert!(output.status.success(), "{}", text(&output));
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&metrics).unwrap()).unwrap();
    assert_eq!(report["outcome"], "drained");
    let produced = node(&report, "source")["items_out"].as_u64().unwrap();
    assert!((5..1000).contains(&produced), "produced {produced}");
    // Every frame the source released reached the PLY sink (nothing in flight was lost).
    let written = std::fs::read_dir(out.path())
        .unwrap()
        .filter(|e| e.as_ref().unwrap().path().join("LIDAR_TOP.ply").exists())
        .count() as u64;
    assert_eq!(written, produced);
}

#[test]
fn pillarize_reports_its_counts_in_the_metrics() {
    let Some(nuscenes) = nuscenes() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let graph = dir.path().join("pillars.yaml");
    std::fs::write(
        &graph,
        format!(
            "nodes:\n  - {{id: source, kind: dataset_source, params: {{data: \"{}\", skip_images: true}}}}\n  - {{id: pillars, kind: pillarize}}\nedges:\n  - {{from: source.frame, to: pillars.frame}}\n",
            nuscenes.clone().display()
        ),
    )
    .unwrap();
    let metrics = dir.path().join("m.json");
    let output = bevworld(&[
        "run",
        graph.to_str().unwrap(),
        "--metrics",
        metrics.to_str().unwrap(),
        "--no-progress",
    ]);
    assert!(output.status.success(), "{}", text(&output));
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&metrics).unwrap()).unwrap();
    let node = node(&report, "pillars");
    let extra = &node["extra"];
    assert_eq!(extra["points_in"], 34_688.0);
    let accounted = [
        "points_kept",
        "dropped_outside_range",
        "dropped_non_finite",
        "dropped_by_pillar_limit",
        "points_in_dropped_pillars",
    ]
    .iter()
    .map(|k| extra[*k].as_f64().unwrap())
    .sum::<f64>();
    assert_eq!(accounted, 34_688.0);
    assert!(extra["mean_pillars_per_frame"].as_f64().unwrap() > 1000.0);
}

#[test]
fn a_killed_export_resumes_to_a_complete_set_without_duplicates() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("data");
    // 4 s of synthetic driving: 48 sweeps at 12 Hz.
    synth_small(&data, &["--seconds", "4"]);
    let out = dir.path().join("features");
    let args = |extra: &[&str]| -> Vec<String> {
        let mut args: Vec<String> = [
            "run",
            "configs/graphs/export_bev_stats.yaml",
            "--set",
            &format!("source.data={}", data.display()),
            "--set",
            "source.sweeps=true",
            "--set",
            &format!("export.out={}", out.display()),
            "--no-progress",
        ]
        .iter()
        .map(|s| s.to_string())
        .collect();
        args.extend(extra.iter().map(|s| s.to_string()));
        args
    };
    // Paced at 40 Hz (1.2 s for 48 frames), killed hard after 0.6 s.
    let mut child = Command::new(env!("CARGO_BIN_EXE_bevworld"))
        .args(args(&["--set", "source.pacing.rate_hz=40"]))
        .current_dir(std::env::var_os("CARGO_MANIFEST_DIR").expect("cargo sets CARGO_MANIFEST_DIR"))
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    std::thread::sleep(std::time::Duration::from_millis(600));
    child.kill().unwrap();
    let _ = child.wait();
    let partial = std::fs::read_dir(&out)
        .map(|d| {
            d.filter(|e| {
                e.as_ref()
                    .unwrap()
                    .path()
                    .extension()
                    .is_some_and(|x| x == "npy")
            })
            .count()
        })
        .unwrap_or(0);
    assert!(
        partial < 48,
        "the run was killed before it finished ({partial} files)"
    );

    let resumed = bevworld(&args(&[]).iter().map(String::as_str).collect::<Vec<_>>());
    assert!(resumed.status.success(), "{}", text(&resumed));
    let names: Vec<String> = std::fs::read_dir(&out)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().to_string())
        .collect();
    assert!(
        !names.iter().any(|n| n.ends_with(".tmp")),
        "no temporary files remain"
    );
    let npys: Vec<&String> = names.iter().filter(|n| n.ends_with(".npy")).collect();
    assert_eq!(npys.len(), 48);
    for name in &npys {
        let (shape, _) =
            bevworld_sinks::npy::read_npy_f32(&std::fs::read(out.join(name)).unwrap()).unwrap();
        assert_eq!(shape, vec![5, 384, 384]);
    }
    let index: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("index.json")).unwrap()).unwrap();
    assert_eq!(index["frames"].as_array().unwrap().len(), 48);
}

/// `--threads` sizes the inference pool: a count is taken with any command, and 0 or a
/// non-number is refused at parse time, naming the flag.
#[test]
fn threads_takes_a_positive_count_and_refuses_anything_else() {
    let output = bevworld(&["--threads", "1", "kinds"]);
    assert!(output.status.success(), "{}", text(&output));
    assert!(text(&output).contains("encode"), "{}", text(&output));
    let output = bevworld(&["kinds", "--threads", "2"]);
    assert!(
        output.status.success(),
        "after the command too: {}",
        text(&output)
    );
    for bad in ["0", "many", "-1"] {
        let flag = format!("--threads={bad}");
        let output = bevworld(&[&flag, "kinds"]);
        assert_eq!(
            output.status.code(),
            Some(2),
            "--threads {bad}: {}",
            text(&output)
        );
        assert!(text(&output).contains("--threads"), "{}", text(&output));
    }
}

/// `synth` refuses what it cannot generate before it writes anything, in the flags' words.
#[test]
fn synth_refuses_jpeg_quality_seed_wrap_and_agent_floods() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("data");
    let out_arg = out.to_str().unwrap();
    for (flags, expected) in [
        (vec!["--jpeg", "0"], "jpeg quality: 0"),
        (vec!["--jpeg", "101"], "jpeg quality: 101"),
        (
            vec!["--seed", "18446744073709551615", "--scenes", "2"],
            "wrap round to 0",
        ),
        (vec!["--agents", "100000"], "agents: 100000"),
        (vec!["--pedestrians", "201"], "pedestrians: 201"),
        (vec!["--cyclists", "5000"], "cyclists: 5000"),
    ] {
        let mut args = vec!["synth", "--out", out_arg];
        args.extend(flags.iter().copied());
        let output = bevworld(&args);
        assert_eq!(
            output.status.code(),
            Some(2),
            "refused before any work: {flags:?}: {}",
            text(&output)
        );
        assert!(
            text(&output).contains(expected),
            "{flags:?}: {}",
            text(&output)
        );
        assert!(
            text(&output).contains("--jpeg"),
            "names the flags: {}",
            text(&output)
        );
        assert!(!out.exists(), "{flags:?}: nothing written");
    }
}

#[test]
fn a_set_merges_into_the_resolved_value_and_keeps_a_hash_in_its_text() {
    let dir = tempfile::tempdir().unwrap();
    // A graph whose pillarize node takes the default grid.
    let graph = dir.path().join("g.yaml");
    let yaml = "nodes:\n  - {id: source, kind: dataset_source, params: {data: DATA}}\n  - {id: pillars, kind: pillarize}\n  - {id: export, kind: export_features, params: {out: OUT}}\n  - {id: bev, kind: bev_stats}\nedges:\n  - {from: source.frame, to: pillars.frame}\n  - {from: pillars.pillars, to: bev.pillars}\n  - {from: bev.features, to: export.features}\n";
    let data = dir.path().join("data");
    std::fs::create_dir_all(&data).unwrap();
    std::fs::write(
        &graph,
        yaml.replace("DATA", &data.display().to_string())
            .replace("OUT", &dir.path().join("o").display().to_string()),
    )
    .unwrap();
    let g = graph.display().to_string();
    let output = bevworld(&["check", &g, "--set", "pillars.grid.pillar_size=0.5"]);
    assert!(output.status.success(), "{}", text(&output));
    let listing = text(&output);
    assert!(
        listing.contains("\"pillar_size\":0.5") && listing.contains("\"x_range\""),
        "{listing}"
    );
    let output = bevworld(&["check", &g, "--set", "export.out=/tmp/x #2"]);
    assert!(output.status.success(), "{}", text(&output));
    assert!(text(&output).contains("/tmp/x #2"), "{}", text(&output));
}

/// `bevworld run` in the background, for the signal tests.
fn spawn_run(args: &[String]) -> std::process::Child {
    Command::new(env!("CARGO_BIN_EXE_bevworld"))
        .args(args)
        .current_dir(std::env::var_os("CARGO_MANIFEST_DIR").expect("cargo sets CARGO_MANIFEST_DIR"))
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap()
}

fn signal(child: &std::process::Child, name: &str) {
    let status = Command::new("kill")
        .args([name, &child.id().to_string()])
        .status()
        .unwrap();
    assert!(status.success());
}

#[test]
fn sigterm_drains_like_the_first_ctrl_c() {
    let Some(nuscenes) = nuscenes() else {
        return;
    };
    let out = tempfile::tempdir().unwrap();
    let metrics = out.path().join("metrics.json");
    let child = spawn_run(&[
        "run".into(),
        "configs/graphs/replay.yaml".into(),
        "--set".into(),
        format!("source.data={}", nuscenes.display()),
        "--set".into(),
        "source.repeat=1000".into(),
        "--set".into(),
        "source.skip_images=true".into(),
        "--set".into(),
        format!("images.out={}", out.path().display()),
        "--set".into(),
        format!("sweeps.out={}", out.path().display()),
        "--metrics".into(),
        metrics.display().to_string(),
        "--no-progress".into(),
    ]);
    std::thread::sleep(std::time::Duration::from_millis(1500));
    signal(&child, "-TERM");
    let output = child.wait_with_output().unwrap();
    assert!(output.status.success(), "{}", text(&output));
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&metrics).unwrap()).unwrap();
    assert_eq!(report["outcome"], "drained");
}

#[test]
fn a_second_ctrl_c_aborts_and_says_so_with_exit_130() {
    let Some(nuscenes) = nuscenes() else {
        return;
    };
    let out = tempfile::tempdir().unwrap();
    let metrics = out.path().join("metrics.json");
    let mut args: Vec<String> = vec![
        "run".into(),
        "configs/graphs/reconstruct.yaml".into(),
        "--set".into(),
        format!("source.data={}", nuscenes.display()),
        "--set".into(),
        "source.repeat=1000".into(),
        "--metrics".into(),
        metrics.display().to_string(),
        "--no-progress".into(),
    ];
    args.extend(common::reconstruct_outputs(out.path()));
    let child = spawn_run(&args);
    // Let the model load and frames flow, then interrupt twice while the drain is under way.
    let started = std::time::Instant::now();
    while started.elapsed() < std::time::Duration::from_secs(120)
        && std::fs::read_dir(out.path()).map_or(0, |d| d.count()) < 3
    {
        std::thread::sleep(std::time::Duration::from_millis(200));
    }
    signal(&child, "-INT");
    std::thread::sleep(std::time::Duration::from_millis(150));
    signal(&child, "-INT");
    let output = child.wait_with_output().unwrap();
    assert_eq!(output.status.code(), Some(130), "{}", text(&output));
    assert!(text(&output).contains("aborted"), "{}", text(&output));
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&metrics).unwrap()).unwrap();
    let outcome = report["outcome"].as_str().unwrap();
    assert!(
        outcome.starts_with("aborted") && outcome.contains("metrics"),
        "{outcome}"
    );
    assert!(
        !out.path().join("metrics.csv").exists(),
        "the CSV is written at the end, which never came"
    );
}

#[test]
fn a_run_that_produces_nothing_fails_saying_so() {
    let Some(nuscenes) = nuscenes() else {
        return;
    };
    let out = tempfile::tempdir().unwrap();
    let output = bevworld(&[
        "run",
        "configs/graphs/replay.yaml",
        "--set",
        &format!("source.data={}", nuscenes.display()),
        "--set",
        "source.start=50",
        "--set",
        &format!("images.out={}", out.path().display()),
        "--set",
        &format!("sweeps.out={}", out.path().display()),
        "--no-progress",
    ]);
    assert_eq!(output.status.code(), Some(1), "{}", text(&output));
    assert!(
        text(&output).contains("produced no items"),
        "{}",
        text(&output)
    );
}

#[test]
fn synth_never_writes_into_another_dataset() {
    for foreign in ["v1.0-mini", "velodyne"] {
        let dir = tempfile::tempdir().unwrap();
        std::fs::create_dir_all(dir.path().join(foreign)).unwrap();
        std::fs::create_dir_all(dir.path().join("samples/CAM_FRONT")).unwrap();
        let out = dir.path().to_str().unwrap();
        for extra in [&[][..], &["--overwrite"][..]] {
            let mut args = vec![
                "synth",
                "--out",
                out,
                "--seconds",
                "0.5",
                "--camera-size",
                "64x36",
            ];
            args.extend_from_slice(extra);
            let output = bevworld(&args);
            assert_eq!(output.status.code(), Some(1), "{}", text(&output));
            assert!(
                text(&output).contains("another dataset"),
                "{}",
                text(&output)
            );
            assert!(!dir.path().join("v1.0-synth").exists());
            assert_eq!(
                std::fs::read_dir(dir.path().join("samples/CAM_FRONT"))
                    .unwrap()
                    .count(),
                0,
                "nothing written into the other dataset's samples"
            );
        }
    }
}

/// Every file a run writes appears whole or not at all: a run killed (SIGKILL, no draining)
/// in the middle of writing images and sweeps leaves outputs that all decode, and at most the
/// temporaries of the writes it was in, under their own names.
#[test]
fn a_killed_run_leaves_no_truncated_file() {
    let Some(nuscenes) = nuscenes() else {
        return;
    };
    let out = tempfile::tempdir().unwrap();
    let mut child = Command::new(env!("CARGO_BIN_EXE_bevworld"))
        .args([
            "run",
            "configs/graphs/replay.yaml",
            "--set",
            &format!("source.data={}", nuscenes.display()),
            "--set",
            "source.repeat=1000",
            "--set",
            &format!("images.out={}", out.path().display()),
            "--set",
            &format!("sweeps.out={}", out.path().display()),
            "--no-progress",
        ])
        .current_dir(std::env::var_os("CARGO_MANIFEST_DIR").expect("cargo sets CARGO_MANIFEST_DIR"))
        .spawn()
        .unwrap();
    std::thread::sleep(std::time::Duration::from_millis(2500));
    child.kill().unwrap();
    child.wait().unwrap();
    let mut files = Vec::new();
    let mut folders = vec![out.path().to_path_buf()];
    while let Some(folder) = folders.pop() {
        for entry in std::fs::read_dir(&folder).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                folders.push(path);
            } else {
                files.push(path);
            }
        }
    }
    let (mut pngs, mut plys) = (0, 0);
    for file in &files {
        let name = file.file_name().unwrap().to_string_lossy().to_string();
        if name.ends_with(".tmp") || name == ".bevworld.lock" {
            continue;
        }
        if name.ends_with(".png") {
            image::open(file).unwrap_or_else(|e| panic!("{}: {e}", file.display()));
            pngs += 1;
        } else if name.ends_with(".ply") {
            assert!(bevworld_sinks_ply::read(file) > 0, "{}", file.display());
            plys += 1;
        } else {
            panic!("an output nobody asked for: {}", file.display());
        }
    }
    // The run got far enough for the check to mean something.
    assert!(pngs >= 6 && plys >= 1, "{pngs} images, {plys} sweeps");
}
