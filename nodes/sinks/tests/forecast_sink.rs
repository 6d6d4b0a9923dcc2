//! The forecast sink outside a graph, and every sink against the names a dataset may give:
//! nothing lands outside the sink's folder, a rerun leaves no stale file of another run, two
//! runs into one folder at once are refused, and the PLY files carry an intensity that means
//! something.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use bevworld_graph::{Header, Inputs, Instant, Message, Node, Registry, Sink};
use bevworld_sinks::ply::read_ply;
use bevworld_types::{
    BevFeatures, BevGrid, ForecastMethod, FrameMeta, FutureView, ImageSet, LidarPoint, NamedImage,
    PointCloud, Pose, RenderedFuture, SensorFrame,
};
use proptest::prelude::*;

fn header(seq: u64) -> Header {
    Header {
        seq,
        time_of_validity_us: 0,
        entered_graph: Instant::now(),
    }
}

fn build(kind: &str, params: serde_json::Value) -> Box<dyn Sink> {
    let mut registry = Registry::new();
    bevworld_sinks::register(&mut registry);
    match registry.get(kind).expect("kind").build(&params) {
        Ok(Node::Sink(sink)) => sink,
        Ok(_) => panic!("{kind} is not a sink"),
        Err(error) => panic!("{kind}: {}", error.message),
    }
}

fn cloud(intensity: f32) -> PointCloud {
    PointCloud {
        points: (0..4)
            .map(|k| LidarPoint {
                x: 10.0 + k as f32,
                y: 2.0,
                z: 0.5,
                intensity: intensity + k as f32,
                ring: k,
            })
            .collect(),
        ..Default::default()
    }
}

fn frame(scene: &str, token: &str, index: usize, intensity: f32) -> Arc<SensorFrame> {
    Arc::new(SensorFrame {
        time_of_validity_us: 1_000_000 * index as i64,
        sample_token: format!("sample-{token}"),
        frame_token: token.into(),
        scene_name: scene.into(),
        index_in_scene: index,
        keyframe: true,
        global_from_ego: Pose::IDENTITY,
        cameras: Vec::new(),
        lidar: Arc::new(cloud(intensity)),
        action: None,
        boxes: Vec::new(),
    })
}

fn latent(scene: &str, token: &str) -> Arc<BevFeatures> {
    Arc::new(BevFeatures {
        meta: FrameMeta {
            sample_token: format!("sample-{token}"),
            frame_token: token.into(),
            scene_name: scene.into(),
            time_of_validity_us: 0,
            global_from_ego: Pose::IDENTITY,
            keyframe: true,
        },
        grid: BevGrid {
            x_range: [-1.0, 1.0],
            y_range: [-1.0, 1.0],
            resolution: 1.0,
            height: 2,
            width: 2,
        },
        channels: vec!["latent_0".into()],
        data: vec![0.5; 4],
        model: "tokenizer-test".into(),
        weights_hash: "0123456789abcdef".into(),
    })
}

fn images(camera: &str) -> ImageSet {
    ImageSet {
        images: vec![NamedImage {
            name: camera.into(),
            image: Arc::new(image::RgbImage::from_pixel(8, 4, image::Rgb([40, 80, 120]))),
        }],
    }
}

/// A rendered view of `method` at `horizon_s`, of a context in `scene`; with `truth`, the log
/// holds the future (intensities 100, 101, ...); the forecast's intensities are opacities.
fn rendered(
    scene: &str,
    token: &str,
    horizon_s: f64,
    horizons: usize,
    method: ForecastMethod,
    truth: bool,
    camera: &str,
) -> Message {
    let context = frame(scene, token, 3, 7.0);
    let future = frame(scene, &format!("{token}-future"), 4, 100.0);
    let view = FutureView {
        context,
        horizon_s,
        frames_ahead: (horizon_s / 0.5).round() as usize,
        horizons_in_forecast: horizons,
        method,
        sample: 0,
        samples_in_forecast: 1,
        latent: latent(scene, token),
        rays: Arc::clone(&future),
        truth: truth.then_some(future),
        sampling_ms: 1.0,
    };
    let mut forecast = cloud(0.0);
    for (k, p) in forecast.points.iter_mut().enumerate() {
        p.intensity = 0.25 * k as f32;
    }
    let rendered = RenderedFuture {
        view: Arc::new(view),
        images: Some(images(camera)),
        lidar: Some(forecast),
        render_ms: 1.0,
    };
    Message::new(header(0), rendered)
}

fn consume(sink: &mut dyn Sink, port: &'static str, message: Message) {
    sink.consume(&Inputs::from_messages(&[port], vec![Some(message)]))
        .expect("consume");
}

/// Every file under `dir`, relative to it.
fn files_under(dir: &Path) -> Vec<PathBuf> {
    let mut found = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(folder) = stack.pop() {
        for entry in std::fs::read_dir(&folder).expect("read_dir").flatten() {
            let path = entry.path();
            if path.is_dir() {
                stack.push(path);
            } else {
                found.push(path.strip_prefix(dir).expect("inside").to_path_buf());
            }
        }
    }
    found.sort();
    found
}

fn forecast_sink(out: &Path) -> Box<dyn Sink> {
    let mut sink = build("forecast_sink", serde_json::json!({"out": out}));
    sink.start().expect("start");
    sink
}

#[test]
fn the_truth_keeps_its_logged_intensity_and_the_forecast_writes_its_opacity() {
    // Reliability row 15: both PLY files used to hold intensity 0 everywhere.
    let dir = tempfile::tempdir().expect("dir");
    let out = dir.path().join("forecast");
    let mut sink = forecast_sink(&out);
    consume(
        sink.as_mut(),
        "rendered",
        rendered("s", "t", 0.5, 1, ForecastMethod::Model, true, "CAM_FRONT"),
    );
    sink.finish().expect("finish");
    let truth = read_ply(&out.join("s-0003/+0.5s/LIDAR_TOP_true.ply")).expect("truth");
    let intensities: Vec<f32> = truth.iter().map(|p| p.intensity).collect();
    assert_eq!(intensities, vec![100.0, 101.0, 102.0, 103.0]);
    let forecast = read_ply(&out.join("s-0003/+0.5s/LIDAR_TOP.ply")).expect("forecast");
    let opacities: Vec<f32> = forecast.iter().map(|p| p.intensity).collect();
    assert_eq!(opacities, vec![0.0, 0.25, 0.5, 0.75]);
}

#[test]
fn a_rerun_into_the_same_folder_leaves_only_its_own_files() {
    // Reliability row 7: a second run with fewer horizons, and no logged future, used to
    // leave the first run's +1s/, +3s/ and LIDAR_TOP_true.ply beside its own forecast.
    let dir = tempfile::tempdir().expect("dir");
    let out = dir.path().join("forecast");
    let mut first = forecast_sink(&out);
    for horizon in [0.5, 1.0, 3.0] {
        consume(
            first.as_mut(),
            "rendered",
            rendered(
                "s",
                "t",
                horizon,
                3,
                ForecastMethod::Model,
                true,
                "CAM_FRONT",
            ),
        );
    }
    first.finish().expect("finish");
    assert_eq!(first.report()["previous_run_files_removed"], 0.0);
    drop(first);
    // A file of the user's own, beside the layout, is not the sink's to remove.
    std::fs::write(out.join("notes.txt"), b"mine").expect("write");
    std::fs::write(out.join("s-0003/notes.txt"), b"mine").expect("write");
    assert!(out.join("s-0003/+3s/LIDAR_TOP_true.ply").is_file());

    let mut second = forecast_sink(&out);
    consume(
        second.as_mut(),
        "rendered",
        rendered("s", "t", 0.5, 1, ForecastMethod::Model, false, "CAM_FRONT"),
    );
    second.finish().expect("finish");
    let kept: Vec<String> = files_under(&out)
        .iter()
        .map(|p| p.display().to_string())
        .filter(|p| !p.ends_with(".lock"))
        .collect();
    assert_eq!(
        kept,
        [
            "notes.txt",
            "s-0003/+0.5s/CAM_FRONT.png",
            "s-0003/+0.5s/LIDAR_TOP.ply",
            "s-0003/+0.5s/top_down.png",
            "s-0003/notes.txt",
            "s-0003/strip_CAM_FRONT.png",
        ],
        "the first run's other horizons and its truth are gone"
    );
    // First run: 3 horizons x (png, ply, true ply, top-down) + 1 strip; the second rewrote
    // 3 of them and its strip.
    assert_eq!(second.report()["previous_run_files_removed"], 9.0);
    assert!(!out.join("s-0003/+3s").exists(), "emptied folders go too");
}

#[test]
fn a_second_run_into_a_folder_in_use_is_refused_naming_it() {
    // Reliability row 8: two runs into one folder at once both exited 0, one overwriting
    // the other. Another process's claim is the lock file held through another handle.
    let dir = tempfile::tempdir().expect("dir");
    let out = dir.path().join("forecast");
    std::fs::create_dir_all(&out).expect("dir");
    let other = std::fs::OpenOptions::new()
        .create(true)
        .truncate(false)
        .write(true)
        .open(out.join(".bevworld.lock"))
        .expect("lock file");
    other.try_lock().expect("the other run holds it");
    for kind in ["forecast_sink", "png_sink", "ply_sink"] {
        let mut sink = build(kind, serde_json::json!({"out": out}));
        let error = sink.start().expect_err("refused").to_string();
        assert!(
            error.contains("another run is writing") && error.contains(&out.display().to_string()),
            "{kind}: {error}"
        );
    }
    drop(other);
    // Within one run, sinks share a folder (the reconstruct graph writes two PNG sets and a
    // PLY into one).
    let mut images = build("png_sink", serde_json::json!({"out": out}));
    let mut sweeps = build("ply_sink", serde_json::json!({"out": out}));
    images.start().expect("first sink");
    sweeps.start().expect("second sink of the same run");
}

#[test]
fn a_sink_that_writes_none_of_its_views_says_so() {
    // Reliability row 10's run-time half: fed only other methods' views, the sink says why it
    // made nothing (the run then fails naming it; `check` refuses such a graph first).
    let dir = tempfile::tempdir().expect("dir");
    let mut sink = build(
        "forecast_sink",
        serde_json::json!({"out": dir.path().join("forecast"), "method": "oracle"}),
    );
    sink.start().expect("start");
    for _ in 0..3 {
        consume(
            sink.as_mut(),
            "rendered",
            rendered("s", "t", 0.5, 1, ForecastMethod::Model, true, "CAM_FRONT"),
        );
    }
    sink.finish().expect("finish");
    let why = sink.nothing_made().expect("it wrote nothing");
    assert!(
        why.contains("none of the 3 views") && why.contains("'oracle'"),
        "{why}"
    );
}

/// Names a dataset may hold: separators, parent references, absolute paths, control
/// characters, long runs of dots, non-ASCII.
fn hostile_name() -> impl Strategy<Value = String> {
    prop_oneof![
        Just("../../escaped/x".to_string()),
        Just("/etc/passwd".to_string()),
        Just("..".to_string()),
        Just(".".to_string()),
        Just(String::new()),
        Just("a/../../b".to_string()),
        Just("C:\\windows\\system32".to_string()),
        "[./\\\\a-z\\x00-\\x1f\u{00e9}\u{202e}]{0,24}",
        prop::collection::vec(
            prop_oneof![Just("..".to_string()), Just("/".to_string()), "[a-z]{1,3}"],
            0..8
        )
        .prop_map(|parts| parts.concat()),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]

    /// No output of any sink lands outside its configured folder, whatever a dataset calls
    /// its scenes, tokens and cameras.
    #[test]
    fn no_sink_writes_outside_its_folder(
        scene in hostile_name(),
        token in hostile_name(),
        camera in hostile_name(),
    ) {
        let dir = tempfile::tempdir().expect("dir");
        let out = dir.path().join("out");

        let mut sink = build("forecast_sink", serde_json::json!({"out": out.join("forecast")}));
        sink.start().expect("start");
        consume(sink.as_mut(), "rendered", rendered(&scene, &token, 0.5, 1, ForecastMethod::Model, true, &camera));
        sink.finish().expect("finish");

        let mut export = build("export_features", serde_json::json!({"out": out.join("features")}));
        export.start().expect("start");
        let features = latent(&scene, if token.is_empty() { "t" } else { &token });
        consume(export.as_mut(), "features", Message::new(header(0), BevFeatures::clone(&features)));
        export.finish().expect("finish");

        let mut png = build("png_sink", serde_json::json!({"out": out.join("png"), "suffix": &token}));
        png.start().expect("start");
        consume(png.as_mut(), "images", Message::new(header(1), images(&camera)));
        png.finish().expect("finish");

        // Everything the sinks wrote is under `out`, each file in the folder its sink names.
        let outside: Vec<PathBuf> = files_under(dir.path())
            .into_iter()
            .filter(|p| !p.starts_with("out/forecast") && !p.starts_with("out/features") && !p.starts_with("out/png"))
            .collect();
        prop_assert!(outside.is_empty(), "written outside: {outside:?}");
        // And each sink did write (a name made safe is still written, not dropped).
        let written: Vec<PathBuf> = files_under(&out)
            .into_iter()
            .filter(|p| !p.ends_with(".bevworld.lock") && !p.ends_with("index.json"))
            .collect();
        for folder in ["forecast", "features", "png"] {
            prop_assert!(written.iter().any(|p| p.starts_with(folder)), "{folder}: {written:?}");
        }
        prop_assert!(written.iter().any(|p| p.ends_with("LIDAR_TOP_true.ply")));
    }
}
