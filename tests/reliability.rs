//! No silent wrong result on the forecast path, tried as a user and an adversary would: each
//! case of `bench/results/reliability.md` (round two) that a graph run or a command reaches,
//! through the binary. Cases a node or a parser meets on its own are tested beside it (the
//! page names each test).

use crate::common;

use std::path::Path;
use std::process::{Command, Stdio};

use common::{bevworld, bevworld_owned, files_under, node, read_json, repo, text};

fn path(p: &Path) -> String {
    p.display().to_string()
}

/// A small synthetic scene: 32x18 cameras, a 3-degree LiDAR, one agent.
fn synth_small(data: &Path, seconds: &str) {
    let output = bevworld(&[
        "synth",
        "--out",
        &path(data),
        "--seconds",
        seconds,
        "--camera-size",
        "32x18",
        "--azimuth-step",
        "3",
        "--agents",
        "1",
    ]);
    assert!(output.status.success(), "{}", text(&output));
}

fn forecast_args(data: &Path, out: &Path, set: &[String]) -> Vec<String> {
    let mut args = vec![
        "run".to_string(),
        "configs/graphs/forecast.yaml".into(),
        "--no-progress".into(),
        "--set".into(),
        format!("source.data={}", path(data)),
        "--set".into(),
        format!("files.out={}", path(out)),
        "--set".into(),
        format!("scores.json={}", path(&out.join("scores.json"))),
        "--set".into(),
        "scores.print=false".into(),
    ];
    for s in set {
        args.push("--set".into());
        args.push(s.clone());
    }
    args
}

/// Rows 1, 7, 13 and 15: a scene named to escape the output folder, rerun with other
/// horizons, one of them a hair off a frame, and the logged intensity in the truth's PLY.
#[test]
fn a_hostile_scene_name_stays_inside_and_a_rerun_replaces_the_last_runs_files() {
    let dir = tempfile::tempdir().expect("dir");
    let data = dir.path().join("data");
    synth_small(&data, "2.5");
    let scenes = data.join("v1.0-synth/scene.json");
    let text_of = std::fs::read_to_string(&scenes).expect("scene.json");
    let original: serde_json::Value = serde_json::from_str(&text_of).expect("json");
    let name = original[0]["name"].as_str().expect("name").to_string();
    std::fs::write(&scenes, text_of.replace(&name, "../../escaped/x")).expect("write");
    let out = dir.path().join("out");
    let metrics = dir.path().join("metrics.json");

    let mut first = forecast_args(&data, &out, &["rollout.horizons=[0.5,1.0]".into()]);
    first.extend(["--metrics".into(), path(&metrics)]);
    let output = bevworld_owned(&first);
    assert!(output.status.success(), "{}", text(&output));
    // Nothing outside the run's folders: the temporary folder holds the dataset, the output
    // and the metrics, and the sink's layout stays one level down.
    let tops: Vec<String> = std::fs::read_dir(dir.path())
        .expect("dir")
        .flatten()
        .map(|e| e.file_name().to_string_lossy().to_string())
        .collect();
    assert!(
        tops.iter()
            .all(|t| ["data", "out", "metrics.json"].contains(&t.as_str())),
        "{tops:?}"
    );
    assert!(!dir.path().join("escaped").exists());
    let context = out.join(".._.._escaped_x-0003");
    assert!(
        context.join("+1s/LIDAR_TOP.ply").is_file(),
        "{:?}",
        files_under(&out)
    );
    // Row 15: the logged sweep keeps its intensities.
    let truth =
        bevworld_sinks::ply::read_ply(&context.join("+0.5s/LIDAR_TOP_true.ply")).expect("truth");
    let mut levels: Vec<u32> = truth.iter().map(|p| p.intensity.to_bits()).collect();
    levels.sort_unstable();
    levels.dedup();
    assert!(levels.len() > 10, "{} distinct intensities", levels.len());
    let forecast =
        bevworld_sinks::ply::read_ply(&context.join("+0.5s/LIDAR_TOP.ply")).expect("forecast");
    assert!(
        forecast.iter().all(|p| (0.0..=1.0).contains(&p.intensity))
            && forecast.iter().any(|p| p.intensity > 0.5),
        "a forecast's intensity is its ray's opacity"
    );

    // The rerun: one horizon, written as the frame it is.
    let mut second = forecast_args(&data, &out, &["rollout.horizons=[0.5000000001]".into()]);
    second.extend(["--metrics".into(), path(&metrics)]);
    let output = bevworld_owned(&second);
    assert!(output.status.success(), "{}", text(&output));
    assert!(context.join("+0.5s/LIDAR_TOP.ply").is_file());
    assert!(
        !context.join("+1s").exists(),
        "the first run's +1s is gone: {:?}",
        files_under(&out)
    );
    assert!(
        files_under(&out)
            .iter()
            .all(|p| !p.display().to_string().contains("0.5000000001")),
        "{:?}",
        files_under(&out)
    );
    let report = read_json(&metrics);
    assert!(
        node(&report, "files")["extra"]["previous_run_files_removed"]
            .as_f64()
            .expect("counted")
            > 0.0,
        "{report}"
    );
    let scores = read_json(&out.join("scores.json"));
    assert_eq!(scores["horizons"][0]["horizon_s"], 0.5, "{scores}");
}

/// Row 8: a second run into a folder another run is writing into is refused; the first
/// finishes untouched.
#[test]
fn two_runs_into_one_folder_at_once_the_second_is_refused() {
    let dir = tempfile::tempdir().expect("dir");
    let data = dir.path().join("data");
    synth_small(&data, "3");
    let out = dir.path().join("replay");
    let args = |rate: &str| -> Vec<String> {
        vec![
            "run".into(),
            "configs/graphs/replay.yaml".into(),
            "--no-progress".into(),
            "--set".into(),
            format!("source.data={}", path(&data)),
            "--set".into(),
            format!("source.pacing.rate_hz={rate}"),
            "--set".into(),
            format!("images.out={}", path(&out)),
            "--set".into(),
            format!("sweeps.out={}", path(&out)),
        ]
    };
    // The first replays 36 sweeps at 6 Hz: six seconds holding the folder.
    let first = Command::new(env!("CARGO_BIN_EXE_bevworld"))
        .args(args("6"))
        .current_dir(repo())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn");
    // Wait until it holds the folder: its lock cannot be taken.
    let lock = out.join(".bevworld.lock");
    let started = std::time::Instant::now();
    loop {
        let held = std::fs::OpenOptions::new()
            .write(true)
            .open(&lock)
            .is_ok_and(|file| file.try_lock().is_err());
        if held {
            break;
        }
        assert!(
            started.elapsed().as_secs() < 120,
            "the first run never claimed {}",
            out.display()
        );
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    let second = bevworld_owned(&args("12"));
    assert_eq!(second.status.code(), Some(1), "{}", text(&second));
    assert!(
        text(&second).contains("another run is writing into this folder"),
        "{}",
        text(&second)
    );
    let first = first.wait_with_output().expect("first run");
    assert!(
        first.status.success(),
        "{}",
        String::from_utf8_lossy(&first.stderr)
    );
    assert!(
        files_under(&out)
            .iter()
            .any(|p| p.extension().is_some_and(|e| e == "ply")),
        "the first run wrote its sweeps"
    );
}

/// Row 9: the real nuScenes keyframe is one frame; the forecast needs four in a row.
#[test]
fn a_forecast_of_a_log_too_short_for_the_history_fails_naming_the_history() {
    let Some(nuscenes) = bevworld_sensors::real_dataset("nuscenes-sample") else {
        return;
    };
    let dir = tempfile::tempdir().expect("dir");
    let output = bevworld_owned(&forecast_args(&nuscenes, &dir.path().join("out"), &[]));
    assert_eq!(output.status.code(), Some(1), "{}", text(&output));
    let said = text(&output);
    assert!(
        said.contains("node 'history' (latent_history) received 1 item(s)")
            && said.contains("a forecast needs 4"),
        "{said}"
    );
    assert!(!said.contains("no logged future frame"), "{said}");
}

/// Rows 10 and 12, and NaN through `--set`: `check` refuses what would run wrong.
#[test]
fn check_refuses_a_sink_fed_no_views_of_its_method_a_doubled_edge_and_nan() {
    let output = bevworld(&[
        "check",
        "configs/graphs/forecast.yaml",
        "--set",
        "views.methods=[model]",
        "--set",
        "files.method=oracle",
    ]);
    assert_eq!(output.status.code(), Some(2), "{}", text(&output));
    let said = text(&output);
    assert!(
        said.contains("configs/graphs/forecast.yaml:")
            && said.contains("bad parameter 'method' of node 'files'")
            && said.contains("renders only [model]"),
        "{said}"
    );
    // The same methods on both sides pass.
    let output = bevworld(&[
        "check",
        "configs/graphs/forecast.yaml",
        "--set",
        "views.methods=[model,oracle]",
        "--set",
        "files.method=oracle",
    ]);
    assert!(output.status.success(), "{}", text(&output));

    let dir = tempfile::tempdir().expect("dir");
    let graph = dir.path().join("doubled.yaml");
    let yaml = std::fs::read_to_string(repo().join("configs/graphs/forecast.yaml")).expect("graph");
    let edge = "  - {from: rollout.forecast, to: views.forecast}\n";
    assert!(yaml.contains(edge));
    std::fs::write(&graph, yaml.replace(edge, &format!("{edge}{edge}"))).expect("write");
    let output = bevworld(&["check", &path(&graph)]);
    assert_eq!(output.status.code(), Some(2), "{}", text(&output));
    assert!(
        text(&output).contains("rollout.forecast -> views.forecast is written twice"),
        "{}",
        text(&output)
    );

    for set in [
        "rollout.horizons=[.nan]",
        "rollout.eta=.nan",
        "rollout.action_list=[[.nan, 0]]",
    ] {
        let output = bevworld(&["check", "configs/graphs/forecast.yaml", "--set", set]);
        assert_eq!(output.status.code(), Some(2), "{set}: {}", text(&output));
        assert!(
            text(&output).contains("non-finite"),
            "{set}: {}",
            text(&output)
        );
    }
}

/// Row 11: a branch with no keyframe after it would be `keep` again, byte for byte.
#[test]
fn a_branch_too_short_to_differ_is_refused() {
    let dir = tempfile::tempdir().expect("dir");
    let out = dir.path().join("branched");
    let output = bevworld(&[
        "synth",
        "--out",
        &path(&out),
        "--seconds",
        "4",
        "--branch-at",
        "3.99",
        "--manoeuvres",
        "keep,stop",
    ]);
    assert_eq!(output.status.code(), Some(2), "{}", text(&output));
    assert!(
        text(&output).contains("leaves no sensor frame after it")
            && text(&output).contains("3.917 s"),
        "{}",
        text(&output)
    );
    assert!(!out.join("v1.0-synth").exists(), "nothing written");
}

/// Row 14: an empty prediction has no Chamfer distance; it is not a perfect one.
#[test]
fn eval_chamfer_of_an_empty_prediction_fails_saying_it_is_empty() {
    use bevworld_sinks::ply::{PlyEncoding, PlyPoint, encode_ply};
    let dir = tempfile::tempdir().expect("dir");
    let empty = dir.path().join("empty.ply");
    let full = dir.path().join("full.ply");
    std::fs::write(
        &empty,
        encode_ply(&[], PlyEncoding::BinaryLittleEndian, None).expect("ply"),
    )
    .expect("write");
    let points: Vec<PlyPoint> = (0..5)
        .map(|k| PlyPoint::new(k as f32, 1.0, 0.0, 0.0))
        .collect();
    std::fs::write(
        &full,
        encode_ply(&points, PlyEncoding::BinaryLittleEndian, None).expect("ply"),
    )
    .expect("write");
    let output = bevworld(&[
        "eval",
        "chamfer",
        "--pred",
        &path(&empty),
        "--gt",
        &path(&full),
        "--json",
    ]);
    assert_eq!(output.status.code(), Some(1), "{}", text(&output));
    let said: serde_json::Value = serde_json::from_slice(&output.stdout).expect("json");
    assert_eq!(said["chamfer"], serde_json::Value::Null, "{said}");
    assert_eq!(said["empty"], "pred");
    assert!(
        text(&output).contains("no Chamfer distance"),
        "{}",
        text(&output)
    );
    // Two real clouds still score.
    let output = bevworld(&[
        "eval",
        "chamfer",
        "--pred",
        &path(&full),
        "--gt",
        &path(&full),
    ]);
    assert!(output.status.success(), "{}", text(&output));
}

/// The unclear messages: negative values reach their checks, the horizon rule is said, a
/// picture path is checked before the work, and one exit code for a refusal.
#[test]
fn refusals_say_the_rule_and_exit_2_before_any_work() {
    let dir = tempfile::tempdir().expect("dir");
    let cases: Vec<(Vec<String>, &str)> = vec![
        (
            vec!["--threads".into(), "-1".into(), "kinds".into()],
            "at least 1 thread",
        ),
        (
            vec![
                "synth".into(),
                "--out".into(),
                path(&dir.path().join("s")),
                "--branch-at".into(),
                "-1".into(),
            ],
            "branch at: -1 s",
        ),
        (
            vec![
                "eval".into(),
                "control".into(),
                "--data".into(),
                path(dir.path()),
                "--horizon".into(),
                "0".into(),
            ],
            "a multiple of its 0.5 s frame interval from 0.5 s on",
        ),
        (
            vec![
                "eval".into(),
                "control".into(),
                "--data".into(),
                path(dir.path()),
                "--horizon".into(),
                "-1".into(),
            ],
            "a multiple of its 0.5 s frame interval from 0.5 s on",
        ),
        (
            vec![
                "eval".into(),
                "control".into(),
                "--data".into(),
                path(dir.path()),
                "--horizon".into(),
                "3.5".into(),
            ],
            "from 0.5 s on, to 3 s",
        ),
        (
            vec![
                "eval".into(),
                "control".into(),
                "--data".into(),
                path(dir.path()),
                "--set".into(),
                "rollout.no_such_key=1".into(),
            ],
            "bad parameter 'no_such_key' of node 'rollout'",
        ),
        (
            vec![
                "eval".into(),
                "forecast".into(),
                "--data".into(),
                path(dir.path()),
                "--plot".into(),
                path(dir.path()),
            ],
            "is a folder",
        ),
        (
            vec![
                "eval".into(),
                "forecast".into(),
                "--data".into(),
                path(dir.path()),
                "--plot".into(),
                path(&dir.path().join("missing/chamfer.png")),
            ],
            "does not exist",
        ),
    ];
    for (args, says) in cases {
        let output = bevworld_owned(&args);
        assert_eq!(output.status.code(), Some(2), "{args:?}: {}", text(&output));
        assert!(text(&output).contains(says), "{args:?}: {}", text(&output));
    }
    // A bad graph parameter through `eval forecast` exits as `run` does, said once.
    let output = bevworld_owned(&[
        "eval".into(),
        "forecast".into(),
        "--data".into(),
        path(dir.path()),
        "--steps".into(),
        "0".into(),
    ]);
    assert_eq!(output.status.code(), Some(2), "{}", text(&output));
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(stderr.contains("bad parameter 'steps'"), "{stderr}");
    assert!(
        stderr
            .lines()
            .all(|line| line.matches("error:").count() <= 1),
        "{stderr}"
    );
}
