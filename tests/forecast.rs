//! The forecast graph as a user runs it, on small synthetic scenes none of the training sets
//! holds: every file it promises, the scores `eval forecast` prints in its documented shape,
//! a forecast that sees nothing of the future but the actions, a log without a future, and
//! parameters it refuses.

use crate::common;

use std::path::{Path, PathBuf};

use common::{bevworld_owned, text};

const CAMERAS: [&str; 6] = [
    "CAM_FRONT",
    "CAM_FRONT_RIGHT",
    "CAM_BACK_RIGHT",
    "CAM_BACK",
    "CAM_BACK_LEFT",
    "CAM_FRONT_LEFT",
];

fn path(p: &Path) -> String {
    p.display().to_string()
}

fn synth(dir: &Path, seed: u64, seconds: f64) -> PathBuf {
    let data = dir.join(format!("synth-{seed}-{seconds}"));
    let output = bevworld_owned(&[
        "synth".into(),
        "--out".into(),
        path(&data),
        "--seed".into(),
        seed.to_string(),
        "--seconds".into(),
        seconds.to_string(),
        "--camera-size".into(),
        "224x126".into(),
    ]);
    assert!(output.status.success(), "{}", text(&output));
    data
}

/// The context folders a forecast run wrote into `out`.
fn context_folders(out: &Path) -> Vec<PathBuf> {
    std::fs::read_dir(out)
        .expect("out")
        .filter_map(Result::ok)
        .map(|e| e.path())
        .filter(|p| p.is_dir())
        .collect()
}

/// `bevworld run configs/graphs/forecast.yaml` on `data`, writing into `out`.
fn run_forecast(data: &Path, out: &Path, set: &[&str]) -> std::process::Output {
    let mut args = vec![
        "run".to_string(),
        "configs/graphs/forecast.yaml".into(),
        "--set".into(),
        format!("source.data={}", path(data)),
        "--set".into(),
        format!("files.out={}", path(out)),
        "--set".into(),
        format!("scores.json={}", path(&out.join("scores.json"))),
    ];
    for s in set {
        args.push("--set".into());
        args.push((*s).into());
    }
    bevworld_owned(&args)
}

#[test]
fn eval_forecast_scores_every_context_and_writes_every_file_it_promises() {
    let dir = tempfile::tempdir().expect("dir");
    // 5.5 s: 11 keyframes. Contexts are keyframes 3..=10; 3..=9 have a logged frame 0.5 s on
    // (so 7 are scored), 3 and 4 have 3 s of log, and 10 is forecast without a score.
    let data = synth(dir.path(), 9710, 5.5);
    let out = dir.path().join("forecast");
    let output = bevworld_owned(&[
        "eval".into(),
        "forecast".into(),
        "--data".into(),
        path(&data),
        "--horizons".into(),
        "0.5,3".into(),
        "--out".into(),
        path(&out),
        "--plot".into(),
        path(&dir.path().join("chamfer.png")),
        "--json".into(),
    ]);
    assert!(output.status.success(), "{}", text(&output));
    let table: serde_json::Value = serde_json::from_slice(&output.stdout).expect("one JSON object");
    assert_eq!(table["contexts"], 7, "{table}");
    assert_eq!(table["steps"], 1);
    assert_eq!(
        table["shrink"]["tau"], 0.25,
        "the graph's sampler is recorded: {table}"
    );
    assert!(table["ms_per_forecast"].as_f64().expect("ms") > 0.0);
    let rows = table["horizons"].as_array().expect("horizons");
    assert_eq!(rows.len(), 2);
    for (row, (horizon, ahead, contexts)) in rows.iter().zip([(0.5, 1, 7), (3.0, 6, 2)]) {
        assert_eq!(row["horizon_s"], horizon);
        assert_eq!(row["frames_ahead"], ahead);
        assert_eq!(row["contexts"], contexts, "{row}");
        for method in ["model", "latent_copy_last", "latent_ego_warp", "oracle"] {
            for score in ["chamfer", "psnr_db", "latent_l1"] {
                let value = row[method][score].as_f64().unwrap_or(f64::NAN);
                assert!(value.is_finite() && value >= 0.0, "{method} {score}: {row}");
            }
        }
        assert_eq!(
            row["oracle"]["latent_l1"], 0.0,
            "the oracle is the truth's own latent"
        );
        for method in ["copy_last", "ego_warp"] {
            assert!(row[method]["chamfer"].as_f64().expect("raw baseline") > 0.0);
        }
        // The agents: the synthetic world annotates its vehicles, so every method and both
        // raw baselines get the three classes' scores, over the same true points.
        let points = |method: &str, class: &str| {
            row[method]["agents"][class]["points"]
                .as_u64()
                .unwrap_or_else(|| panic!("{method} {class}: {row}"))
        };
        for class in ["moving_vehicles", "parked_vehicles", "static"] {
            let truth = points("model", class);
            assert!(truth > 0, "{class}: {row}");
            for method in ["latent_ego_warp", "oracle", "copy_last", "ego_warp"] {
                assert_eq!(points(method, class), truth, "{method} {class}");
            }
            for method in ["model", "oracle", "ego_warp"] {
                let recall = row[method]["agents"][class]["recall_1m"]
                    .as_f64()
                    .unwrap_or(f64::NAN);
                assert!((0.0..=1.0).contains(&recall), "{method} {class}: {row}");
            }
        }
        assert!(points("model", "static") > 10 * points("model", "moving_vehicles"));
    }
    // On this scene, at 3 s, the network adds to the ego warp it starts from: the shipped pair
    // reads latent L1 0.48 against 0.65 and Chamfer 2.62 against 2.71 m². A model that only
    // warps, or ignores the context, does not.
    let at_3s = &rows[1];
    for score in ["latent_l1", "chamfer"] {
        let (model, warp) = (
            at_3s["model"][score].as_f64().expect("model"),
            at_3s["latent_ego_warp"][score].as_f64().expect("warp"),
        );
        assert!(
            model < warp,
            "{score} at 3 s: model {model}, latent_ego_warp {warp}"
        );
    }
    assert!(dir.path().join("chamfer.png").is_file());

    // Files: every context, every horizon; the truth only where the log reaches.
    let contexts = context_folders(&out);
    assert_eq!(contexts.len(), 8, "{contexts:?}");
    let mut with_truth = [0usize; 2];
    for context in &contexts {
        for (i, horizon) in ["+0.5s", "+3s"].iter().enumerate() {
            let folder = context.join(horizon);
            for camera in CAMERAS {
                assert!(
                    folder.join(format!("{camera}.png")).is_file(),
                    "{}",
                    folder.display()
                );
            }
            assert!(folder.join("LIDAR_TOP.ply").is_file());
            assert!(folder.join("top_down.png").is_file());
            with_truth[i] += usize::from(folder.join("LIDAR_TOP_true.ply").is_file());
        }
        for camera in CAMERAS {
            let strip = image::open(context.join(format!("strip_{camera}.png"))).expect("strip");
            // A label column and one 112-pixel column per horizon; truth above forecast.
            assert_eq!((strip.width(), strip.height()), (72 + 2 * 112, 16 + 2 * 64));
        }
    }
    assert_eq!(with_truth, [7, 2]);
}

#[test]
fn eval_forecast_with_draws_scores_the_best_of_them_beside_the_unchanged_point_forecast() {
    let dir = tempfile::tempdir().expect("dir");
    // 4 s: keyframes 3..=6 are contexts with a logged frame 0.5 s on.
    let data = synth(dir.path(), 9711, 4.0);
    let eval = |samples: Option<usize>, out: &str| {
        let mut args: Vec<String> = [
            "eval",
            "forecast",
            "--data",
            &path(&data),
            "--horizons",
            "0.5",
            "--out",
            &path(&dir.path().join(out)),
            "--set",
            "sensors=[lidar]",
            "--set",
            "methods=[model,latent_ego_warp]",
            "--json",
        ]
        .map(String::from)
        .to_vec();
        if let Some(k) = samples {
            args.extend(["--samples".into(), k.to_string()]);
        }
        let output = bevworld_owned(&args);
        assert!(output.status.success(), "{}", text(&output));
        let table: serde_json::Value =
            serde_json::from_slice(&output.stdout).expect("one JSON object");
        table
    };
    let single = eval(None, "single");
    let drawn = eval(Some(3), "drawn");
    assert_eq!(drawn["samples"], 3, "the draws are recorded: {drawn}");
    assert_eq!(drawn["contexts"], 4, "{drawn}");
    let (one, three) = (&single["horizons"][0], &drawn["horizons"][0]);
    assert_eq!(
        one["model"]["chamfer"], three["model"]["chamfer"],
        "the model row stays the point forecast, draw 0"
    );
    assert!(one.get("model_draws").is_none() && one.get("model_best_of_3").is_none());
    let chamfer = |method: &str| {
        three[method]["chamfer"]
            .as_f64()
            .unwrap_or_else(|| panic!("{method}: {three}"))
    };
    // The best of three is at most every draw's Chamfer, so at most draw 0's and their mean.
    assert!(chamfer("model_best_of_3") <= chamfer("model"), "{three}");
    assert!(
        chamfer("model_best_of_3") <= chamfer("model_draws"),
        "{three}"
    );
    let points = |method: &str| three[method]["agents"]["moving_vehicles"]["points"].clone();
    assert_eq!(
        points("model_best_of_3"),
        points("model"),
        "the same true points"
    );
    assert_eq!(
        points("model_draws").as_u64(),
        points("model").as_u64().map(|p| 3 * p),
        "every draw's, pooled"
    );
    // One forecast is written per context: the point forecast.
    assert_eq!(context_folders(&dir.path().join("drawn")).len(), 5);
}

/// Files of the dataset recorded after `after_us`, each replaced by noise of its own kind.
fn scramble_after(data: &Path, after_us: i64) -> usize {
    let table: serde_json::Value = serde_json::from_slice(
        &std::fs::read(data.join("v1.0-synth/sample_data.json")).expect("sample_data"),
    )
    .expect("json");
    let mut state = 7u64;
    let mut noise = move || {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (state >> 40) as u32
    };
    let mut count = 0;
    for entry in table.as_array().expect("list") {
        if entry["timestamp"].as_i64().expect("timestamp") <= after_us {
            continue;
        }
        let file = data.join(entry["filename"].as_str().expect("filename"));
        if file.extension().is_some_and(|e| e == "bin") {
            let floats = std::fs::metadata(&file).expect("bin").len() / 4;
            let bytes: Vec<u8> = (0..floats)
                .flat_map(|_| ((noise() % 100) as f32 - 50.0).to_le_bytes())
                .collect();
            std::fs::write(&file, bytes).expect("write");
        } else {
            let original = image::open(&file).expect("image").to_rgb8();
            let scrambled =
                image::RgbImage::from_fn(original.width(), original.height(), |_, _| {
                    let v = noise();
                    image::Rgb([v as u8, (v >> 8) as u8, (v >> 16) as u8])
                });
            scrambled.save(&file).expect("save");
        }
        count += 1;
    }
    count
}

#[test]
fn the_forecast_sees_nothing_of_the_future_but_the_actions() {
    let dir = tempfile::tempdir().expect("dir");
    let data = synth(dir.path(), 9711, 5.0);
    let scrambled = dir.path().join("scrambled");
    let copy = std::process::Command::new("cp")
        .args(["-r", &path(&data), &path(&scrambled)])
        .status()
        .expect("cp");
    assert!(copy.success());
    // The first context is keyframe 3 (1.5 s in): everything after it becomes noise.
    let samples: serde_json::Value = serde_json::from_slice(
        &std::fs::read(data.join("v1.0-synth/sample.json")).expect("sample"),
    )
    .expect("json");
    let mut keyframes: Vec<i64> = samples
        .as_array()
        .expect("list")
        .iter()
        .map(|s| s["timestamp"].as_i64().expect("timestamp"))
        .collect();
    keyframes.sort_unstable();
    assert!(scramble_after(&scrambled, keyframes[3] + 1000) > 100);

    let set = ["rollout.horizons=[0.5,3.0]", "views.methods=[model,oracle]"];
    let (clean_out, noisy_out) = (dir.path().join("clean"), dir.path().join("noisy"));
    for (input, out) in [(&data, &clean_out), (&scrambled, &noisy_out)] {
        let output = run_forecast(input, out, &set);
        assert!(output.status.success(), "{}", text(&output));
    }
    let context = std::fs::read_dir(&clean_out)
        .expect("out")
        .filter_map(Result::ok)
        .map(|e| e.file_name())
        .find(|n| n.to_string_lossy().ends_with("-0003"))
        .expect("the first context's folder");
    for horizon in ["+0.5s", "+3s"] {
        for camera in CAMERAS {
            let file = |out: &Path| {
                std::fs::read(
                    out.join(&context)
                        .join(horizon)
                        .join(format!("{camera}.png")),
                )
                .expect("png")
            };
            assert!(
                file(&clean_out) == file(&noisy_out),
                "{horizon} {camera} changed"
            );
        }
        // The noise did reach the graph: the logged future it is scored against changed.
        let truth = |out: &Path| {
            std::fs::read(out.join(&context).join(horizon).join("LIDAR_TOP_true.ply")).expect("ply")
        };
        assert!(truth(&clean_out) != truth(&noisy_out));
    }
}

#[test]
fn a_log_without_a_future_gives_forecasts_without_scores_and_says_so() {
    let dir = tempfile::tempdir().expect("dir");
    // 2 s: 4 keyframes, one context (keyframe 3) and nothing after it.
    let data = synth(dir.path(), 9712, 2.0);
    let out = dir.path().join("forecast");
    let output = run_forecast(&data, &out, &["rollout.horizons=[0.5]"]);
    assert!(output.status.success(), "{}", text(&output));
    assert!(
        text(&output).contains("nothing scored"),
        "{}",
        text(&output)
    );
    let folder = std::fs::read_dir(&out)
        .expect("out")
        .filter_map(Result::ok)
        .find(|e| e.path().is_dir())
        .expect("a context")
        .path()
        .join("+0.5s");
    assert!(folder.join("CAM_FRONT.png").is_file() && folder.join("LIDAR_TOP.ply").is_file());
    assert!(folder.join("top_down.png").is_file());
    assert!(!folder.join("LIDAR_TOP_true.ply").exists());

    let output = bevworld_owned(&[
        "eval".into(),
        "forecast".into(),
        "--data".into(),
        path(&data),
        "--horizons".into(),
        "0.5".into(),
        "--out".into(),
        path(&dir.path().join("eval")),
    ]);
    assert!(!output.status.success());
    assert!(text(&output).contains("no context"), "{}", text(&output));
}

#[test]
fn the_forecast_graph_refuses_actions_and_horizons_it_cannot_forecast() {
    let check = |set: &str| {
        bevworld_owned(&[
            "check".into(),
            "configs/graphs/forecast.yaml".into(),
            "--set".into(),
            set.into(),
        ])
    };
    let output = check("rollout.actions=sideways");
    assert_eq!(output.status.code(), Some(2), "{}", text(&output));
    assert!(
        text(&output).contains("keep, left, right, faster, slower, stop"),
        "{}",
        text(&output)
    );
    let output = check("rollout.horizons=[0.5,3.5]");
    assert_eq!(output.status.code(), Some(2));
    assert!(text(&output).contains("N = 6"), "{}", text(&output));
    let output = check("views.methods=[model,magic]");
    assert_eq!(output.status.code(), Some(2));
    assert!(
        text(&output).contains("latent_ego_warp") && text(&output).contains("latent_box_warp"),
        "{}",
        text(&output)
    );
    let output = check("views.box_margin_m=-1");
    assert_eq!(output.status.code(), Some(2));
    assert!(
        text(&output).contains("box_margin_m") && text(&output).contains("[0, 10] m"),
        "{}",
        text(&output)
    );
    let output = check("views.box_base=nothing");
    assert_eq!(output.status.code(), Some(2));
    assert!(text(&output).contains("box_base"), "{}", text(&output));
    let output = check("views.box_motion=teleport");
    assert_eq!(output.status.code(), Some(2));
    assert!(
        text(&output).contains("future_box") && text(&output).contains("velocity"),
        "{}",
        text(&output)
    );
    let output = check("rollout.shrink={tau: -0.25, fade_s: 3.0}");
    assert_eq!(output.status.code(), Some(2));
    assert!(
        text(&output).contains("shrink") && text(&output).contains("tau -0.25"),
        "{}",
        text(&output)
    );
    let output = check("rollout.samples=0");
    assert_eq!(output.status.code(), Some(2));
    assert!(
        text(&output).contains("samples") && text(&output).contains("1 (the point forecast)"),
        "{}",
        text(&output)
    );
    let output = check("render.sensors=[radar]");
    assert_eq!(output.status.code(), Some(2));
    assert!(
        text(&output).contains("cameras, lidar"),
        "{}",
        text(&output)
    );
}

#[test]
fn the_live_graph_forecasts_while_the_log_replays_in_real_time() {
    let dir = tempfile::tempdir().expect("dir");
    // 3 s at 12 Hz: 36 sweeps, paced; the history fills after 1.5 s of them.
    let data = synth(dir.path(), 9713, 3.0);
    let out = dir.path().join("live");
    let metrics = dir.path().join("metrics.json");
    let started = std::time::Instant::now();
    let output = bevworld_owned(&[
        "run".into(),
        "configs/graphs/forecast_live.yaml".into(),
        "--set".into(),
        format!("source.data={}", path(&data)),
        "--set".into(),
        format!("files.out={}", path(&out)),
        "--metrics".into(),
        path(&metrics),
    ]);
    assert!(output.status.success(), "{}", text(&output));
    // The 36 sweeps are released 1/12 s apart: the last 35/12 s after the first.
    assert!(
        started.elapsed() >= std::time::Duration::from_millis(2900),
        "{:?}",
        started.elapsed()
    );
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&metrics).expect("metrics")).expect("JSON");
    assert_eq!(report["outcome"], "completed", "{report}");
    let nodes = report["nodes"].as_array().expect("nodes");
    let edges = report["edges"].as_array().expect("edges");
    let node = |id: &str| {
        nodes
            .iter()
            .find(|n| n["id"] == id)
            .unwrap_or_else(|| panic!("no node {id}: {report}"))
    };
    assert_eq!(node("source")["items_out"], 36, "{report}");
    let forecasts = node("rollout")["items_out"].as_u64().expect("forecasts");
    assert!(forecasts >= 1, "{report}");
    // What the slow nodes could not keep up with is dropped on their edges, and each drop is
    // counted as its node's.
    for n in nodes {
        let id = n["id"].as_str().expect("id");
        let dropped: u64 = edges
            .iter()
            .filter(|e| {
                e["to"]
                    .as_str()
                    .is_some_and(|to| to.starts_with(&format!("{id}.")))
            })
            .map(|e| e["dropped"].as_u64().expect("dropped"))
            .sum();
        assert_eq!(n["drops"], dropped, "{id}: {report}");
    }
    // Every forecast made is written, at every horizon.
    let contexts = context_folders(&out);
    assert_eq!(contexts.len() as u64, forecasts);
    for context in &contexts {
        for horizon in ["+0.5s", "+1s", "+3s"] {
            let folder = context.join(horizon);
            assert!(
                folder.join("CAM_FRONT.png").is_file() && folder.join("LIDAR_TOP.ply").is_file(),
                "{}",
                folder.display()
            );
        }
    }
}

#[test]
fn the_agent_graph_adds_the_model_with_its_agents_and_the_box_warp_carries_the_moving_cars() {
    let dir = tempfile::tempdir().expect("dir");
    // 5 s: contexts at keyframes 3..=9, of which 3..=8 have a logged frame 1 s on.
    let data = synth(dir.path(), 9712, 5.0);
    let output = bevworld_owned(&[
        "eval".into(),
        "forecast".into(),
        "--graph".into(),
        "configs/graphs/forecast_agents.yaml".into(),
        "--data".into(),
        path(&data),
        "--horizons".into(),
        "0.5,1".into(),
        "--out".into(),
        path(&dir.path().join("agents")),
        "--set".into(),
        "sensors=[lidar]".into(),
        "--set".into(),
        "methods=[model,model_with_agents,latent_ego_warp,latent_box_warp]".into(),
        // The cars follow their tracks, so the node holds earlier frames' detections back.
        "--set".into(),
        "agents.follow=track".into(),
        "--json".into(),
    ]);
    assert!(output.status.success(), "{}", text(&output));
    let table: serde_json::Value = serde_json::from_slice(&output.stdout).expect("one JSON object");
    let rows = table["horizons"].as_array().expect("horizons");
    assert_eq!(rows.len(), 2, "{table}");
    for row in rows {
        for method in ["model_with_agents", "latent_box_warp"] {
            let chamfer = row[method]["chamfer"].as_f64().unwrap_or(f64::NAN);
            assert!(chamfer.is_finite() && chamfer > 0.0, "{method}: {row}");
            assert_eq!(
                row[method]["agents"]["moving_vehicles"]["points"],
                row["model"]["agents"]["moving_vehicles"]["points"],
                "{method} is scored on the same true points: {row}"
            );
        }
    }
    // The box warp carries each car to its true box: at +1 s it keeps more of the moving
    // cars' returns within 1 m than the ego warp, which leaves them where they were.
    let at_1s = &rows[1];
    let recall = |method: &str| {
        at_1s[method]["agents"]["moving_vehicles"]["recall_1m"]
            .as_f64()
            .unwrap_or_else(|| panic!("{method}: {at_1s}"))
    };
    assert!(
        recall("latent_box_warp") > recall("latent_ego_warp"),
        "box warp {} against ego warp {}",
        recall("latent_box_warp"),
        recall("latent_ego_warp")
    );
}
