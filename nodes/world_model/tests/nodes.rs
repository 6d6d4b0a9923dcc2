//! The world model's graph nodes without the graph: the latent history buffer (order, scene
//! resets, gaps, its memory bound, refusals), the rollout's parameters (unknown manoeuvres,
//! horizons past N, lists, statistics of another tokenizer) and its determinism on the
//! shipped weights, and the pairing of forecasts with the frames they are rendered along.

use std::path::PathBuf;
use std::sync::Arc;

use bevworld_graph::{Models, ParamError};
use bevworld_types::LatentStatsFile;
use bevworld_types::object_box::ObjectBox;
use bevworld_types::{
    BevFeatures, BevGrid, CameraChannel, CameraImage, EgoAction, Forecast, ForecastHorizon,
    ForecastMethod, FrameMeta, Intrinsics, LatentGrid, LatentWindow, LidarPoint, PlanarMotion,
    PointCloud, Pose, SensorFrame, warp_latent,
};
use bevworld_world_model::ResidualShrink;
use bevworld_world_model::WorldModelConfig;
use bevworld_world_model::nodes::diffusion_rollout::{self, DiffusionRolloutParams};
use bevworld_world_model::nodes::future_views::{BoxBase, BoxMotion, FutureViews};
use bevworld_world_model::nodes::latent_history::{HistoryShape, LatentHistory};
use bevworld_world_model::nodes::model_params::{WorldModelParams, check_pairing};
use bevworld_world_model::weights::load_sealed_meta;
use glam::DVec3;

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..")
}

const TOKENIZER: (&str, &str) = ("tokenizer-tiny", "digest");

fn shape(future: usize) -> HistoryShape {
    HistoryShape {
        context: 3,
        future,
        interval_s: 0.5,
        latent_shape: [4, 8, 8],
        tokenizer: (TOKENIZER.0.into(), TOKENIZER.1.into()),
    }
}

/// A latent of `scene` at `time_s`, the ego at x = 5 m/s · t.
fn latent(scene: &str, time_s: f64) -> Arc<BevFeatures> {
    Arc::new(BevFeatures {
        meta: FrameMeta {
            sample_token: format!("{scene}@{time_s}"),
            frame_token: format!("{scene}@{time_s}"),
            scene_name: scene.into(),
            time_of_validity_us: (time_s * 1e6).round() as i64,
            global_from_ego: Pose::from_translation(DVec3::new(5.0 * time_s, 0.0, 0.0)),
            keyframe: true,
        },
        grid: BevGrid {
            x_range: [-80.0, 80.0],
            y_range: [-80.0, 80.0],
            resolution: 20.0,
            height: 8,
            width: 8,
        },
        channels: (0..4).map(|c| format!("latent_{c}")).collect(),
        data: vec![time_s as f32; 4 * 8 * 8],
        model: TOKENIZER.0.into(),
        weights_hash: TOKENIZER.1.into(),
    })
}

fn times(window: &LatentWindow) -> Vec<f64> {
    window
        .context
        .iter()
        .map(|l| l.meta.time_of_validity_us as f64 * 1e-6)
        .collect()
}

#[test]
fn the_history_emits_one_window_per_frame_in_order_once_full() {
    let mut history = LatentHistory::new(shape(0), Some(1), 1.5, 0.2);
    let mut windows = Vec::new();
    for k in 0..6 {
        windows.extend(history.push(latent("a", 0.5 * k as f64)).expect("push"));
        assert!(history.len() <= history.capacity());
    }
    // Context 3 needs 4 frames (the motion into the oldest): frames 3, 4, 5 complete windows.
    assert_eq!(windows.len(), 3);
    assert_eq!(times(&windows[0]), vec![0.5, 1.0, 1.5]);
    assert_eq!(times(&windows[2]), vec![1.5, 2.0, 2.5]);
    // The motion into each context frame: 2.5 m forward in 0.5 s.
    for action in &windows[0].context_actions {
        assert!((action.dx - 2.5).abs() < 1e-9 && (action.speed_mps - 5.0).abs() < 1e-9);
    }
    assert!(windows.iter().all(|w| w.logged_future.is_empty()));
    assert_eq!(history.capacity(), 4, "bounded: context + 1");
}

#[test]
fn the_history_resets_on_a_new_scene_and_on_a_gap() {
    let mut history = LatentHistory::new(shape(0), Some(1), 1.5, 0.2);
    let mut count = 0;
    for k in 0..4 {
        count += history
            .push(latent("a", 0.5 * k as f64))
            .expect("push")
            .len();
    }
    assert_eq!(count, 1);
    // A new scene starts over: three more frames make no window, the fourth does.
    for k in 0..3 {
        assert!(
            history
                .push(latent("b", 0.5 * k as f64))
                .expect("push")
                .is_empty()
        );
    }
    assert_eq!(history.resets_scene, 1);
    // A gap of 2 s (> 1.5 intervals) starts over too, and is counted.
    assert!(history.push(latent("b", 3.0)).expect("push").is_empty());
    assert_eq!((history.resets_gap, history.len()), (1, 1));
    let mut windows = Vec::new();
    for k in 1..4 {
        windows.extend(
            history
                .push(latent("b", 3.0 + 0.5 * k as f64))
                .expect("push"),
        );
    }
    assert_eq!(windows.len(), 1);
    assert_eq!(times(&windows[0]), vec![3.5, 4.0, 4.5]);
}

#[test]
fn the_history_keeps_every_kth_frame_and_refuses_the_wrong_rate() {
    let mut history = LatentHistory::new(shape(0), Some(6), 1.5, 0.2);
    let mut windows = Vec::new();
    for k in 0..24 {
        windows.extend(history.push(latent("a", k as f64 / 12.0)).expect("push"));
    }
    assert_eq!(windows.len(), 1);
    assert_eq!(times(&windows[0]), vec![0.5, 1.0, 1.5]);
    // By time (the default): 12 Hz sweeps with some dropped on the way still make 2 Hz.
    let mut by_time = LatentHistory::new(shape(0), None, 1.5, 0.2);
    let mut windows = Vec::new();
    for k in (0..30).filter(|k| k % 5 != 1) {
        windows.extend(by_time.push(latent("a", k as f64 / 12.0)).expect("push"));
    }
    // 0.5 s was dropped: 7/12 s takes its slot, and 1.0 s is still the next one's.
    let kept: Vec<Vec<i64>> = windows
        .iter()
        .map(|w| times(w).iter().map(|t| (t * 1e3).round() as i64).collect())
        .collect();
    assert_eq!(
        kept[..2],
        [vec![583, 1000, 1500], vec![1000, 1500, 2000]],
        "{kept:?}"
    );
    assert_eq!(by_time.resets_gap, 0);
    let mut wrong = LatentHistory::new(shape(0), Some(1), 1.5, 0.2);
    wrong.push(latent("a", 0.0)).expect("first");
    let error = wrong
        .push(latent("a", 1.0 / 12.0))
        .expect_err("12 Hz on a 2 Hz model");
    assert!(error.contains("every"), "{error}");
}

#[test]
fn the_history_refuses_latents_of_another_tokenizer() {
    let mut history = LatentHistory::new(shape(0), Some(1), 1.5, 0.2);
    let mut other = BevFeatures::clone(&latent("a", 0.0));
    other.weights_hash = "another".into();
    let error = history.push(Arc::new(other)).expect_err("refused");
    assert!(
        error.contains("another") && error.contains("digest"),
        "{error}"
    );
    let mut small = BevFeatures::clone(&latent("a", 0.0));
    small.data.truncate(10);
    assert!(history.push(Arc::new(small)).is_err());
}

#[test]
fn a_replayed_history_waits_for_the_logged_future_and_flushes_the_end_of_the_log() {
    let mut history = LatentHistory::new(shape(2), None, 1.5, 0.2);
    let mut windows = Vec::new();
    for k in 0..7 {
        windows.extend(history.push(latent("a", 0.5 * k as f64)).expect("push"));
        assert!(history.len() <= 6, "bounded: context + 1 + future");
    }
    // Frames 0..=6 s/2: the contexts ending at 1.5 and 2.0 s have both future frames.
    assert_eq!(windows.len(), 2);
    assert_eq!(times(&windows[0]), vec![0.5, 1.0, 1.5]);
    let future: Vec<i64> = windows[0]
        .logged_future
        .iter()
        .map(|f| f.time_of_validity_us)
        .collect();
    assert_eq!(future, vec![2_000_000, 2_500_000]);
    // The end of the log: 2.5 s with one logged future frame, 3.0 s with none.
    let ends: Vec<(f64, usize)> = history
        .flush()
        .iter()
        .map(|w| (times(w)[2], w.logged_future.len()))
        .collect();
    assert_eq!(ends, vec![(2.5, 1), (3.0, 0)]);
    assert!(history.is_empty());
}

#[test]
fn a_history_that_never_fills_says_how_many_frames_it_got_and_how_many_a_forecast_needs() {
    // Reliability row 9: a dataset too short for the history used to end in "0 contexts",
    // blamed on the log's future.
    let mut history = LatentHistory::new(shape(3), None, 1.5, 0.2);
    assert_eq!(
        history.why_no_window(),
        None,
        "nothing taken, nothing to explain"
    );
    for t in [0.0, 0.5, 1.0] {
        assert!(history.push(latent("a", t)).expect("push").is_empty());
    }
    assert!(history.push(latent("b", 0.0)).expect("push").is_empty());
    assert!(history.flush().is_empty());
    let why = history.why_no_window().expect("no window was made");
    assert!(
        why.contains("took 4 latent(s)") && why.contains("was 3") && why.contains("needs 4"),
        "{why}"
    );
    // Four frames in a row make a window, and there is nothing to explain.
    for t in [0.0, 0.5, 1.0, 1.5] {
        history.push(latent("c", t)).expect("push");
    }
    assert_eq!(history.flush().len(), 1);
    assert_eq!(history.why_no_window(), None);
}

fn rollout_params(actions: &str, horizons: &[f64]) -> DiffusionRolloutParams {
    DiffusionRolloutParams {
        model: WorldModelParams {
            model: "tiny".into(),
        },
        horizons: horizons.to_vec(),
        steps: 1,
        eta: 0.0,
        spacing: Default::default(),
        seed: 0,
        samples: 1,
        shrink: None,
        actions: actions.into(),
        action_list: None,
        baselines: true,
    }
}

/// A graph's `models:` section with one bundle, `tiny`: the shipped tokenizer and a world
/// model's config and weights.
fn bundle(config: &std::path::Path, weights: &std::path::Path) -> Models {
    Models::new(std::collections::BTreeMap::from([(
        "tiny".to_string(),
        serde_json::json!({
            "tokenizer": {
                "config": repo().join("configs/models/tokenizer-tiny.yaml"),
                "weights": repo().join("nodes/tokenizer/weights/tokenizer-tiny.bpk"),
            },
            "world_model": {"config": config, "weights": weights},
        }),
    )]))
}

fn shipped_config() -> PathBuf {
    repo().join("configs/models/world-model-tiny.yaml")
}

fn shipped_weights() -> PathBuf {
    repo().join("nodes/world_model/weights/world-model-tiny.bpk")
}

fn shipped() -> Models {
    bundle(&shipped_config(), &shipped_weights())
}

fn plan(params: &DiffusionRolloutParams) -> Result<diffusion_rollout::RolloutPlan, ParamError> {
    diffusion_rollout::plan(params, &shipped())
}

fn refusal(params: &DiffusionRolloutParams) -> (String, String) {
    refusal_in(params, &shipped())
}

fn refusal_in(params: &DiffusionRolloutParams, models: &Models) -> (String, String) {
    let Err(error) = diffusion_rollout::plan(params, models) else {
        panic!("{params:?} was accepted");
    };
    (
        format!("{}: {}", error.field.unwrap_or_default(), error.message),
        error.accepted.unwrap_or_default(),
    )
}

#[test]
fn the_rollout_refuses_unknown_manoeuvres_and_horizons_it_does_not_make() {
    assert!(plan(&rollout_params("left", &[0.5, 1.0, 3.0])).is_ok());
    let (message, accepted) = refusal(&rollout_params("sideways", &[0.5]));
    assert!(
        message.starts_with("actions") && message.contains("sideways"),
        "{message}"
    );
    for known in [
        "log", "keep", "left", "right", "faster", "slower", "stop", "list",
    ] {
        assert!(accepted.contains(known), "{accepted}");
    }
    // N = 6 frames 0.5 s apart: 3.5 s is past the last, 0.7 s is not a frame.
    for horizon in [3.5, 0.7, 0.0, -0.5] {
        let (message, _) = refusal(&rollout_params("keep", &[horizon]));
        assert!(
            message.starts_with("horizons") && message.contains("N = 6"),
            "{message}"
        );
    }
    assert!(refusal(&rollout_params("keep", &[])).0.contains("empty"));
    assert!(
        refusal(&rollout_params("keep", &[1.0, 1.0]))
            .0
            .contains("twice")
    );
    let mut list = rollout_params("list", &[1.0]);
    assert!(refusal(&list).0.starts_with("action_list"));
    list.action_list = Some(vec![[8.0, 0.0]; 2]);
    assert!(refusal(&list).0.contains("needs 6"));
    list.action_list = Some(vec![[8.0, 0.1]; 6]);
    assert!(plan(&list).is_ok());
    let mut no_bundle = rollout_params("keep", &[1.0]);
    no_bundle.model.model = "tyni".into();
    let (message, accepted) = refusal(&no_bundle);
    assert!(
        message.starts_with("model") && message.contains("'tyni'"),
        "{message}"
    );
    assert!(accepted.contains("tiny"), "{accepted}");
    let mut steps = rollout_params("keep", &[1.0]);
    steps.steps = 0;
    assert!(refusal(&steps).0.starts_with("steps"));
    let mut eta = rollout_params("keep", &[1.0]);
    eta.eta = -1.0;
    assert!(refusal(&eta).0.starts_with("eta"));
}

/// A copy of the shipped weights and their metadata in a folder of the test's own, with the
/// metadata's JSON edited by `edit` (nothing re-sealed), for the refusals of files that were
/// changed after they were written.
fn shipped_copy(name: &str, edit: impl FnOnce(&mut serde_json::Value)) -> (PathBuf, PathBuf) {
    let dir = std::env::temp_dir().join(format!("bevworld-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("dir");
    let weights = dir.join("world-model-tiny.bpk");
    std::fs::copy(
        repo().join("nodes/world_model/weights/world-model-tiny.bpk"),
        &weights,
    )
    .expect("weights");
    let mut meta: serde_json::Value = serde_json::from_slice(
        &std::fs::read(repo().join("nodes/world_model/weights/world-model-tiny.meta.json"))
            .expect("meta"),
    )
    .expect("json");
    edit(&mut meta);
    let meta_path = dir.join("world-model-tiny.meta.json");
    std::fs::write(&meta_path, serde_json::to_vec_pretty(&meta).expect("json")).expect("write");
    (weights, meta_path)
}

#[test]
fn the_rollout_refuses_metadata_and_weights_changed_after_they_were_written() {
    // Reliability rows 2 and 3: a spread of 0 or below, an action mean moved, a weights file
    // overwritten. Each used to forecast NaN or nonsense with exit 0.
    for (name, field, value, says) in [
        ("std-zero", "std", 0.0, "action_stats.std[0]"),
        ("std-negative", "std", -2.5, "action_stats.std[0]"),
        (
            "mean-moved",
            "mean",
            100.0,
            "was edited after it was written",
        ),
    ] {
        let (weights, meta_path) = shipped_copy(name, |meta| {
            meta["action_stats"][field][0] = serde_json::json!(value);
        });
        let params = rollout_params("keep", &[1.0]);
        let (message, _) = refusal_in(&params, &bundle(&shipped_config(), &weights));
        assert!(
            message.contains("world_model.weights") && message.contains(says),
            "{name}: {message}"
        );
        assert!(
            message.contains(&meta_path.display().to_string()),
            "names the file at fault: {message}"
        );
    }
    // The weights' bytes: 100,000 floats overwritten in the middle of the file.
    let (weights, _) = shipped_copy("bytes", |_| {});
    let mut bytes = std::fs::read(&weights).expect("weights");
    let middle = bytes.len() / 2;
    for b in &mut bytes[middle - 200_000..middle + 200_000] {
        *b = 0x3f;
    }
    std::fs::write(&weights, bytes).expect("write");
    let params = rollout_params("keep", &[1.0]);
    let (message, _) = refusal_in(&params, &bundle(&shipped_config(), &weights));
    assert!(
        message.contains("were changed after they were written")
            && message.contains(&weights.display().to_string()),
        "{message}"
    );
    // A tokenizer digest edited in the metadata is the metadata's fault, named as such, not
    // the statistics file's.
    let (weights, meta_path) = shipped_copy("tokenizer", |meta| {
        meta["tokenizer_weights_hash"] = serde_json::json!("0000000000000000");
    });
    let params = rollout_params("keep", &[1.0]);
    let (message, _) = refusal_in(&params, &bundle(&shipped_config(), &weights));
    assert!(
        message.contains("world_model.weights")
            && message.contains(&meta_path.display().to_string()),
        "{message}"
    );
    // Whitespace and key order change nothing that is sealed.
    let (weights, meta_path) = shipped_copy("respaced", |_| {});
    let compact: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&meta_path).expect("meta")).expect("json");
    std::fs::write(&meta_path, serde_json::to_vec(&compact).expect("json")).expect("write");
    let params = rollout_params("keep", &[1.0]);
    assert!(diffusion_rollout::plan(&params, &bundle(&shipped_config(), &weights)).is_ok());
}

#[test]
fn the_rollout_refuses_what_would_forecast_nonsense_and_names_a_horizon_as_its_frame() {
    // Row 4: η past 1 adds more noise each step than the process removes.
    for eta in [1.5, 10.0, 1e6, f64::NAN] {
        let mut params = rollout_params("keep", &[1.0]);
        params.eta = eta;
        let (message, _) = refusal(&params);
        assert!(
            message.starts_with("eta") && message.contains("[0, 1]"),
            "{message}"
        );
    }
    let mut params = rollout_params("keep", &[1.0]);
    params.eta = 1.0;
    assert!(plan(&params).is_ok(), "DDPM's η = 1");
    // Row 5: physically impossible actions are refused; unusual ones are forecast.
    for (pair, says) in [
        ([1e300, 0.0], "speed"),
        ([8.0, 1e6], "yaw rate"),
        ([-30.0, 0.0], "reversing"),
        ([25.0, 1.0], "lateral"),
    ] {
        let mut list = rollout_params("list", &[1.0]);
        let mut actions = vec![[8.0, 0.0]; 6];
        actions[3] = pair;
        list.action_list = Some(actions);
        let (message, _) = refusal(&list);
        assert!(
            message.starts_with("action_list")
                && message.contains("entry 3")
                && message.contains(says),
            "{pair:?}: {message}"
        );
    }
    let mut unusual = rollout_params("list", &[1.0]);
    unusual.action_list = Some(vec![[0.0, 0.0]; 6]);
    assert!(
        plan(&unusual).is_ok(),
        "standing still is outside the training range, not impossible"
    );
    // Row 6: statistics of 3 channels for a 4-channel latent.
    let dir = std::env::temp_dir().join(format!("bevworld-stats3-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("dir");
    let mut stats: serde_json::Value = serde_json::from_slice(
        &std::fs::read(repo().join("nodes/tokenizer/weights/tokenizer-tiny.stats.json"))
            .expect("stats"),
    )
    .expect("json");
    for key in ["mean", "std"] {
        stats["stats"][key].as_array_mut().expect("list").pop();
    }
    let three = dir.join("three.stats.json");
    std::fs::write(&three, serde_json::to_vec(&stats).expect("json")).expect("write");
    let config = WorldModelConfig::from_yaml_file(&shipped_config()).expect("config");
    let meta = load_sealed_meta(&shipped_weights()).expect("meta").meta;
    let stats = LatentStatsFile::load(&three).expect("stats");
    let tokenizer = (
        meta.tokenizer_model.clone(),
        meta.tokenizer_weights_hash.clone(),
    );
    let error = check_pairing(&config, &meta, (&tokenizer.0, &tokenizer.1), &stats)
        .expect_err("3 channels");
    assert_eq!(error.field.as_deref(), Some("tokenizer.latent_stats"));
    assert!(error.message.contains("3 channels"), "{}", error.message);
    // The shipped pair belongs together; a world model of another tokenizer does not.
    let shipped_stats =
        LatentStatsFile::load(&repo().join("nodes/tokenizer/weights/tokenizer-tiny.stats.json"))
            .expect("stats");
    assert!(check_pairing(&config, &meta, (&tokenizer.0, &tokenizer.1), &shipped_stats).is_ok());
    let error = check_pairing(
        &config,
        &meta,
        (&tokenizer.0, "0123456789abcdef"),
        &shipped_stats,
    )
    .expect_err("another tokenizer");
    assert_eq!(error.field.as_deref(), Some("world_model.weights"));
    assert!(
        error.message.contains("0123456789abcdef"),
        "{}",
        error.message
    );
    // Row 13: a horizon a hair off a frame is that frame, by name too.
    let plan = plan(&rollout_params("keep", &[0.5000000001, 3.0])).expect("plan");
    assert_eq!(plan.horizons, vec![(0.5, 1), (3.0, 6)]);
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn the_rollout_refuses_a_shrink_it_cannot_apply() {
    let shrink = |tau: f64, fade_s: f64| Some(ResidualShrink { tau, fade_s });
    let mut params = rollout_params("keep", &[1.0]);
    params.shrink = shrink(0.25, 3.0);
    assert!(plan(&params).is_ok());
    params.shrink = shrink(-0.25, 3.0);
    let (message, _) = refusal(&params);
    assert!(
        message.starts_with("shrink") && message.contains("tau"),
        "{message}"
    );
    params.shrink = shrink(0.25, 0.0);
    let (message, _) = refusal(&params);
    assert!(
        message.starts_with("shrink") && message.contains("fade_s"),
        "{message}"
    );
    // A model that predicts latents has no residual to shrink.
    let dir = std::env::temp_dir().join(format!("bevworld-shrink-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("dir");
    let text = std::fs::read_to_string(repo().join("configs/models/world-model-tiny.yaml"))
        .expect("config");
    let latent = text.replace(
        "residual_over_ego_warp: true",
        "residual_over_ego_warp: false",
    );
    assert_ne!(latent, text);
    let config = dir.join("world-model-tiny.yaml");
    std::fs::write(&config, latent).expect("write");
    let latent_model = bundle(&config, &shipped_weights());
    params.shrink = shrink(0.25, 3.0);
    let (message, _) = refusal_in(&params, &latent_model);
    assert!(
        message.starts_with("shrink") && message.contains("residual"),
        "{message}"
    );
    params.shrink = None;
    assert!(diffusion_rollout::plan(&params, &latent_model).is_ok());
    // A misspelt field in the graph's YAML is named.
    let yaml = "{model: tiny, horizons: [1.0], shrink: {tau: 0.25, fade: 3.0}}";
    let error = serde_saphyr::from_str::<DiffusionRolloutParams>(yaml).expect_err("unknown field");
    assert!(error.to_string().contains("fade"), "{error}");
    std::fs::remove_dir_all(&dir).ok();
}

/// A window of the shipped model's shape, from the tokenizer's own statistics' scale.
fn window(seed: u64) -> LatentWindow {
    let meta: serde_json::Value = serde_json::from_slice(
        &std::fs::read(repo().join("nodes/world_model/weights/world-model-tiny.meta.json"))
            .expect("meta"),
    )
    .expect("json");
    let hash = meta["tokenizer_weights_hash"]
        .as_str()
        .expect("hash")
        .to_string();
    let mut state = seed;
    let mut noise = || {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((state >> 33) as f32 / (1u64 << 31) as f32) - 0.5
    };
    let context = (0..3)
        .map(|k| {
            let mut l = BevFeatures::clone(&latent("a", 0.5 * k as f64));
            l.grid.height = 64;
            l.grid.width = 64;
            l.data = (0..4 * 64 * 64).map(|_| noise()).collect();
            l.weights_hash = hash.clone();
            Arc::new(l)
        })
        .collect();
    LatentWindow {
        context,
        context_actions: vec![
            EgoAction::between(
                &Pose::IDENTITY,
                0,
                &Pose::from_translation(DVec3::new(2.5, 0.0, 0.0)),
                500_000
            )
            .expect("action");
            3
        ],
        logged_future: Vec::new(),
        stride_s: 0.5,
    }
}

#[test]
fn the_rollout_is_deterministic_for_a_seed_and_moves_the_pose_by_its_actions() {
    let node =
        diffusion_rollout::build(&rollout_params("keep", &[0.5, 3.0]), &shipped()).expect("node");
    let first = node.forecast(&window(1)).expect("forecast");
    let again = node.forecast(&window(1)).expect("forecast");
    assert_eq!(first.horizons.len(), 2);
    for (a, b) in first.horizons.iter().zip(&again.horizons) {
        for ((ma, la), (mb, lb)) in a.latents.iter().zip(&b.latents) {
            assert_eq!(ma, mb);
            assert_eq!(la.data, lb.data, "{ma:?} at {} s", a.horizon_s);
        }
    }
    let horizon = &first.horizons[1];
    assert_eq!((horizon.horizon_s, horizon.frames_ahead), (3.0, 6));
    let model = horizon.latent(ForecastMethod::Model).expect("model");
    // `keep` at 5 m/s straight: 15 m ahead of the current frame (at 1.0 s, x = 5 m), at 4.0 s.
    assert_eq!(model.meta.time_of_validity_us, 4_000_000);
    let x = model.meta.global_from_ego.translation.x;
    assert!((x - 20.0).abs() < 1e-6, "{x}");
    assert!(model.data.iter().all(|v| v.is_finite()));
    let copy = horizon
        .latent(ForecastMethod::LatentCopyLast)
        .expect("copy");
    assert_eq!(
        copy.data, first.horizons[0].latents[1].1.data,
        "copy-last is the current latent"
    );
    assert_ne!(model.data, copy.data);
}

#[test]
fn further_draws_leave_the_point_forecast_as_it_was_and_differ_from_it() {
    let single = diffusion_rollout::build(&rollout_params("keep", &[1.0, 3.0]), &shipped())
        .expect("node")
        .forecast(&window(1))
        .expect("forecast");
    let mut params = rollout_params("keep", &[1.0, 3.0]);
    params.samples = 3;
    let drawn = diffusion_rollout::build(&params, &shipped())
        .expect("node")
        .forecast(&window(1))
        .expect("forecast");
    for (one, three) in single.horizons.iter().zip(&drawn.horizons) {
        assert!(one.samples.is_empty());
        assert_eq!(
            three.samples.len(),
            2,
            "draws 1 and 2 at {} s",
            three.horizon_s
        );
        let point = three.latent(ForecastMethod::Model).expect("model");
        assert_eq!(
            point.data,
            one.latent(ForecastMethod::Model).expect("model").data,
            "draw 0 is the forecast without draws"
        );
        for (k, draw) in three.samples.iter().enumerate() {
            assert_eq!(draw.meta, point.meta, "the same future frame");
            assert!(draw.data.iter().all(|v| v.is_finite()));
            assert_ne!(draw.data, point.data, "draw {} has noise of its own", k + 1);
        }
        assert_ne!(three.samples[0].data, three.samples[1].data);
    }
    for samples in [0, diffusion_rollout::MAX_SAMPLES + 1] {
        let mut params = rollout_params("keep", &[1.0]);
        params.samples = samples;
        let (message, _) = refusal(&params);
        assert!(
            message.starts_with("samples") && message.contains(&samples.to_string()),
            "{message}"
        );
    }
}

fn frame(scene: &str, time_s: f64) -> Arc<SensorFrame> {
    let pose = Pose::from_translation(DVec3::new(5.0 * time_s, 0.0, 0.0));
    let time = (time_s * 1e6).round() as i64;
    Arc::new(SensorFrame {
        time_of_validity_us: time,
        sample_token: format!("{scene}@{time_s}"),
        frame_token: format!("{scene}@{time_s}"),
        scene_name: scene.into(),
        index_in_scene: (time_s * 2.0) as usize,
        keyframe: true,
        global_from_ego: pose,
        cameras: vec![CameraImage {
            channel: CameraChannel::Front,
            image: Arc::new(image::RgbImage::new(4, 4)),
            intrinsics: Intrinsics::from_rows(
                [[2.0, 0.0, 2.0], [0.0, 2.0, 2.0], [0.0, 0.0, 1.0]],
                4,
                4,
            ),
            ego_from_camera: Pose::IDENTITY,
            timestamp_us: time,
            global_from_ego: pose,
            source_file: String::new(),
        }],
        lidar: Arc::new(PointCloud {
            points: vec![LidarPoint {
                x: 10.0,
                y: 0.0,
                z: 0.0,
                intensity: 0.0,
                ring: 0,
            }],
            ego_from_lidar: Pose::IDENTITY,
            timestamp_us: time,
            global_from_ego: pose,
            dropped_non_finite: 0,
            source_file: String::new(),
        }),
        action: None,
        boxes: Vec::new(),
    })
}

/// A forecast from `scene` at `time_s` with one horizon `ahead` frames on, its latent at the
/// predicted pose `x`.
fn forecast(scene: &str, time_s: f64, ahead: usize, actions_from: &str, x: f64) -> Forecast {
    let future_time = time_s + 0.5 * ahead as f64;
    let mut model = BevFeatures::clone(&latent(scene, future_time));
    model.meta.global_from_ego = Pose::from_translation(DVec3::new(x, 0.0, 0.0));
    Forecast {
        context: latent(scene, time_s).meta.clone(),
        actions_from: actions_from.into(),
        future_actions: Vec::new(),
        horizons: vec![ForecastHorizon {
            horizon_s: 0.5 * ahead as f64,
            frames_ahead: ahead,
            latents: vec![(ForecastMethod::Model, Arc::new(model))],
            samples: Vec::new(),
        }],
        sampling_ms: 1.0,
    }
}

#[test]
fn a_replayed_forecast_waits_for_its_logged_future_and_is_rendered_along_it() {
    let mut views = FutureViews::new(
        vec![ForecastMethod::Model, ForecastMethod::Oracle],
        0.05,
        64,
    );
    for k in 0..3 {
        views.push_frame(frame("a", 0.5 * k as f64));
    }
    views.push_forecast(forecast("a", 1.0, 2, "log", 10.0));
    assert!(
        views.ready(false).is_empty(),
        "the frame at 2.0 s has not come yet"
    );
    views.push_frame(frame("a", 1.5));
    views.push_frame(frame("a", 2.0));
    assert!(views.ready(false).is_empty(), "nor has the oracle's latent");
    views.push_latent(latent("a", 2.0));
    let ready = views.ready(false);
    assert_eq!(ready.len(), 2);
    let truth = ready[0].truth.as_ref().expect("truth");
    assert_eq!(truth.time_of_validity_us, 2_000_000);
    assert!(
        Arc::ptr_eq(&ready[0].rays, truth),
        "rendered along the logged frame"
    );
    assert_eq!(ready[1].method, ForecastMethod::Oracle);
    assert_eq!(ready[1].latent.meta.time_of_validity_us, 2_000_000);
    assert_eq!(ready[0].context.time_of_validity_us, 1_000_000);
}

#[test]
fn each_draw_of_the_model_is_a_view_along_the_same_rays_the_point_forecast_first() {
    let mut views = FutureViews::new(
        vec![ForecastMethod::Model, ForecastMethod::Oracle],
        0.05,
        64,
    );
    for k in 0..5 {
        views.push_frame(frame("a", 0.5 * k as f64));
    }
    views.push_latent(latent("a", 2.0));
    let mut with_draws = forecast("a", 1.0, 2, "log", 10.0);
    let point = Arc::clone(&with_draws.horizons[0].latents[0].1);
    let further: Vec<Arc<BevFeatures>> = (0..2)
        .map(|d| {
            let mut draw = BevFeatures::clone(&point);
            draw.data.iter_mut().for_each(|v| *v = d as f32 + 1.0);
            Arc::new(draw)
        })
        .collect();
    with_draws.horizons[0].samples = further.clone();
    views.push_forecast(with_draws);
    let ready = views.ready(false);
    let numbered: Vec<(ForecastMethod, usize, usize)> = ready
        .iter()
        .map(|v| (v.method, v.sample, v.samples_in_forecast))
        .collect();
    assert_eq!(
        numbered,
        vec![
            (ForecastMethod::Model, 0, 3),
            (ForecastMethod::Model, 1, 3),
            (ForecastMethod::Model, 2, 3),
            (ForecastMethod::Oracle, 0, 3),
        ]
    );
    assert!(
        Arc::ptr_eq(&ready[0].latent, &point),
        "draw 0 is the point forecast"
    );
    assert!(Arc::ptr_eq(&ready[1].latent, &further[0]));
    assert!(Arc::ptr_eq(&ready[2].latent, &further[1]));
    let truth = ready[0].truth.as_ref().expect("truth");
    for view in &ready[..3] {
        assert!(
            Arc::ptr_eq(&view.rays, truth),
            "every draw along the logged rays"
        );
    }
}

#[test]
fn a_manoeuvre_is_rendered_from_the_predicted_pose_without_truth() {
    let mut views = FutureViews::new(vec![ForecastMethod::Model], 0.05, 64);
    views.push_frame(frame("a", 0.0));
    views.push_forecast(forecast("a", 0.0, 6, "left", 42.0));
    let ready = views.ready(false);
    assert_eq!(ready.len(), 1, "nothing to wait for");
    let view = &ready[0];
    assert!(view.truth.is_none());
    assert_eq!(view.rays.lidar.global_from_ego.translation.x, 42.0);
    assert_eq!(view.rays.cameras[0].global_from_ego.translation.x, 42.0);
    assert_eq!(view.rays.time_of_validity_us, 3_000_000);
    assert_eq!(
        view.rays.lidar.points, view.context.lidar.points,
        "the rig's own beams"
    );
    assert_eq!(
        views.horizons_without_truth, 0,
        "a manoeuvre has no truth by design"
    );
}

#[test]
fn a_log_that_ends_gives_a_forecast_without_truth_and_the_frames_held_are_bounded() {
    let mut views = FutureViews::new(vec![ForecastMethod::Model], 0.05, 4);
    views.push_frame(frame("a", 0.0));
    views.push_forecast(forecast("a", 0.0, 6, "log", 15.0));
    assert!(views.ready(false).is_empty());
    // The next scene begins: scene a's log ended before 3 s.
    views.push_frame(frame("b", 0.0));
    let ready = views.ready(false);
    assert_eq!(ready.len(), 1);
    assert!(ready[0].truth.is_none());
    assert_eq!(
        views.horizons_without_truth, 1,
        "the log ended within the horizon"
    );
    for k in 0..20 {
        views.push_frame(frame("b", 0.5 * k as f64));
    }
    // The context of a later forecast was evicted: counted, not waited for.
    views.push_forecast(forecast("b", 0.0, 1, "log", 2.5));
    assert!(views.ready(true).is_empty());
    assert_eq!(views.contexts_missing, 1);
}

#[test]
fn without_truth_a_baseline_is_rendered_only_when_asked_for_alone() {
    let with_warp = || {
        let mut f = forecast("a", 0.0, 6, "left", 42.0);
        let warp = Arc::clone(&f.horizons[0].latents[0].1);
        f.horizons[0]
            .latents
            .push((ForecastMethod::LatentEgoWarp, warp));
        f
    };
    let mut both = FutureViews::new(
        vec![ForecastMethod::Model, ForecastMethod::LatentEgoWarp],
        0.05,
        64,
    );
    both.push_frame(frame("a", 0.0));
    both.push_forecast(with_warp());
    let ready = both.ready(false);
    assert_eq!(ready.len(), 1, "nothing to score the baseline against");
    assert_eq!(ready[0].method, ForecastMethod::Model);
    let mut alone = FutureViews::new(vec![ForecastMethod::LatentEgoWarp], 0.05, 64);
    alone.push_frame(frame("a", 0.0));
    alone.push_forecast(with_warp());
    let ready = alone.ready(false);
    assert_eq!(ready.len(), 1);
    assert_eq!(ready[0].method, ForecastMethod::LatentEgoWarp);
}

/// A car 4.5 m long in the context frame `a@0` at global (x, 10), and the same instance in the
/// frame of `time_s`.
fn with_car(frame: Arc<SensorFrame>, x: f64) -> Arc<SensorFrame> {
    let mut frame = SensorFrame::clone(&frame);
    frame.boxes = vec![ObjectBox {
        instance_token: "car-1".into(),
        category: "vehicle.car".into(),
        global_from_box: Pose::from_translation(DVec3::new(x, 10.0, 0.8)),
        size: [1.9, 4.5, 1.6],
        velocity: Some([45.0, 0.0]),
        attributes: vec!["vehicle.moving".into()],
        num_pts: 10,
    }];
    Arc::new(frame)
}

#[test]
fn the_box_warp_carries_a_vehicles_cells_to_its_true_future_box_and_leaves_ground_behind() {
    // 20 m cells over ±80 m; the ego drives 5 m/s along +x, so at +1 s it is at x = 5. The car
    // drives from global (−30, 10) (row 4, column 2) to (15, 10): in the future ego frame at
    // (10, 10), the centre of row 4, column 4.
    let grid = LatentGrid {
        channels: 4,
        height: 8,
        width: 8,
        x_range: [-80.0, 80.0],
        y_range: [-80.0, 80.0],
    };
    let mut current = latent("a", 0.0);
    let plane = 64;
    Arc::make_mut(&mut current).data[4 * 8 + 2] = 9.0;
    let at = |latent: &BevFeatures, i: usize, j: usize| latent.data[i * 8 + j];
    let make = |with_copy: bool| {
        let mut f = forecast("a", 0.0, 2, "log", 5.0);
        let model = Arc::clone(&f.horizons[0].latents[0].1);
        let mut warp = BevFeatures::clone(&model);
        warp.data = warp_latent(
            &current.data,
            &grid,
            &PlanarMotion {
                x: 5.0,
                y: 0.0,
                yaw: 0.0,
            },
            0.0,
        );
        let latents = &mut f.horizons[0].latents;
        latents.push((ForecastMethod::LatentEgoWarp, Arc::new(warp)));
        if with_copy {
            latents.push((ForecastMethod::LatentCopyLast, Arc::clone(&current)));
        }
        f
    };
    let views_of = |with_copy: bool, motion: BoxMotion, base: BoxBase| {
        let mut views = FutureViews::new(
            vec![ForecastMethod::LatentEgoWarp, ForecastMethod::LatentBoxWarp],
            0.05,
            64,
        )
        .with_box_warp(5.0, motion, base);
        views.push_frame(with_car(frame("a", 0.0), -30.0));
        views.push_frame(frame("a", 0.5));
        views.push_frame(with_car(frame("a", 1.0), 15.0));
        views.push_forecast(make(with_copy));
        views.ready(true)
    };
    let ready = views_of(true, BoxMotion::FutureBox, BoxBase::LatentEgoWarp);
    assert_eq!(ready.len(), 2);
    let (warp, moved) = (&ready[0].latent, &ready[1].latent);
    assert_eq!(ready[1].method, ForecastMethod::LatentBoxWarp);
    assert_eq!(moved.meta.global_from_ego, warp.meta.global_from_ego);
    // The ego warp leaves the car behind, a quarter cell back: 0.75 of it in column 2.
    assert!((at(warp, 4, 2) - 6.75).abs() < 1e-4);
    assert!(at(warp, 4, 4).abs() < 1e-6);
    // The box warp draws it where it went, whole, and the ground where it was.
    assert!((at(moved, 4, 4) - 9.0).abs() < 1e-4);
    assert!(at(moved, 4, 2).abs() < 1e-6);
    // The other channels held no car and hold none.
    assert!(moved.data[plane..].iter().all(|v| v.abs() < 1e-6));
    // Its annotated velocity (45 m/s along +x) takes it to the same place in 1 s.
    let by_velocity = views_of(true, BoxMotion::Velocity, BoxBase::LatentEgoWarp);
    assert_eq!(by_velocity[1].latent.data, moved.data);
    // On the model's forecast (here all 1.0, the test forecast's value at 1 s): the car
    // is drawn where it went and every other cell but the ground it left is the model's.
    let on_model = views_of(true, BoxMotion::FutureBox, BoxBase::Model);
    let on_model = &on_model[1].latent;
    assert!((at(on_model, 4, 4) - 9.0).abs() < 1e-4);
    assert!(
        at(on_model, 4, 2).abs() < 1e-6,
        "the ring's ground, from the current latent"
    );
    assert!((at(on_model, 0, 0) - 1.0).abs() < 1e-6);
    // Without the current latent (a rollout without baselines) there is nothing to move.
    let ready = views_of(false, BoxMotion::FutureBox, BoxBase::LatentEgoWarp);
    assert_eq!(ready.len(), 1);
    assert_eq!(ready[0].method, ForecastMethod::LatentEgoWarp);
}
