//! A synthetic set's keyframes read with an export written by hand: every keyframe with its
//! map, its previous keyframe and its agents; and an export that does not fit the set
//! (a keyframe without a map, a map of another set, two models in one folder) refused,
//! naming what is wrong.

use std::path::Path;

use bevworld_heads::DetectorConfig;
use bevworld_heads_train::{DataError, TrainDetectorConfig, load_set};
use bevworld_sensors::synth::{SynthConfig, generate};
use bevworld_sensors::{Dataset, DatasetOptions};
use bevworld_sinks::npy::npy_f32;
use glam::DMat4;
use serde_json::json;

pub fn config() -> DetectorConfig {
    DetectorConfig::from_yaml(
        "
name: detector-test
classes: [car, pedestrian, bicycle]
output_cells: 8
trunk: {embed_dim: 8, depths: [2], heads: [2], window: 4}
head_hidden: 8
motion: {modes: 2, steps: 2, interval_s: 0.5}
min_radius: 1
max_detections: 10
min_score: 0.1
",
        "test",
    )
    .expect("valid config")
}

/// Writes one `[2, 8, 8]` map per keyframe of `dataset` (channel 0 the keyframe's position in
/// the set, channel 1 all ones) and an index; `entry` may change each index entry.
pub fn export(dataset: &Path, out: &Path, entry: impl Fn(usize, &mut serde_json::Value)) -> usize {
    let options = DatasetOptions {
        skip_images: true,
        ..Default::default()
    };
    let set = Dataset::open(dataset, &options).expect("opens");
    std::fs::create_dir_all(out).expect("folder");
    let mut frames = Vec::new();
    for index in 0..set.len() {
        let frame = set.read(index).expect("frame");
        let mut values = vec![index as f32; 64];
        values.extend(vec![1.0f32; 64]);
        let file = format!("{index}.npy");
        std::fs::write(out.join(&file), npy_f32(&[2, 8, 8], &values).expect("npy"))
            .expect("written");
        let m = DMat4::from(frame.global_from_ego);
        let rows: Vec<[f64; 4]> = (0..4)
            .map(|r| [m.col(0)[r], m.col(1)[r], m.col(2)[r], m.col(3)[r]])
            .collect();
        let mut value = json!({
            "frame_token": frame.frame_token,
            "sample_token": frame.sample_token,
            "scene": frame.scene_name,
            "timestamp_us": frame.time_of_validity_us,
            "global_from_ego": rows,
            "file": file,
            "shape": [2, 8, 8],
            "dtype": "float32",
            "grid": {"x_range": [-80.0, 80.0], "y_range": [-80.0, 80.0], "resolution_m": 20.0},
            "model": "tokenizer-test",
            "weights_hash": "abc",
        });
        entry(index, &mut value);
        frames.push(value);
    }
    let frames: Vec<_> = frames.into_iter().filter(|f| !f.is_null()).collect();
    std::fs::write(
        out.join("index.json"),
        serde_json::to_vec(&json!({"format": "npy", "frames": frames})).expect("json"),
    )
    .expect("index");
    set.len()
}

pub fn synthetic_set(dir: &Path) {
    let config = SynthConfig {
        seed: 11,
        seconds: 3.0,
        camera_width: 64,
        camera_height: 36,
        pedestrians: 8,
        cyclists: 3,
        ..Default::default()
    };
    generate(dir, &config, |_, _| {}).expect("synthetic set");
}

/// A training config over three tiny synthetic sets under `dir`, `batch` keyframes per step in
/// micro-batches of `micro_batch`.
pub fn train_config(dir: &Path, batch: usize, micro_batch: usize) -> TrainDetectorConfig {
    let text = format!(
        "
model: unused.yaml
tokenizer_model: unused.yaml
tokenizer_weights: unused.bpk
train: {{synth: {{dir: {d}/a, seed: 1, scenes: 1, seconds: 3, camera_size: 64x36}}, features: {d}/fa}}
val: {{synth: {{dir: {d}/b, seed: 2, scenes: 1, seconds: 3, camera_size: 64x36}}, features: {d}/fb}}
test: {{synth: {{dir: {d}/c, seed: 3, scenes: 1, seconds: 3, camera_size: 64x36}}, features: {d}/fc}}
seed: 5
steps: 30
batch: {batch}
micro_batch: {micro_batch}
optimizer: {{lr: 2.0e-3, beta_1: 0.9, beta_2: 0.999, epsilon: 1.0e-8, weight_decay: 0.01, warmup_steps: 2, final_lr_fraction: 0.1, grad_clip_norm: 10.0}}
fine_tune_lr_fraction: 0.1
loss: {{heatmap: 1.0, boxes: 0.25, motion: 0.1}}
validate_every: 100
checkpoint_every: 100
",
        d = dir.display(),
        batch = batch,
        micro_batch = micro_batch,
    );
    let path = dir.join("train.yaml");
    std::fs::write(&path, text).expect("written");
    TrainDetectorConfig::from_yaml_file(&path).expect("valid config")
}

#[test]
fn an_export_and_its_set_give_every_keyframe_its_map_agents_and_previous_frame() {
    let root = tempfile::tempdir().expect("dir");
    let data = root.path().join("set");
    synthetic_set(&data);
    let features = root.path().join("features");
    let keyframes = export(&data, &features, |_, _| {});
    let set = load_set(&features, &data, &config()).expect("loads");
    assert_eq!(set.frames.len(), keyframes);
    assert_eq!(set.truth.len(), keyframes);
    assert_eq!(
        (set.model.as_str(), set.weights_hash.as_str()),
        ("tokenizer-test", "abc")
    );
    assert_eq!(
        (set.channels, set.grid.height, set.grid.resolution),
        (2, 8, 20.0)
    );
    assert_eq!(set.frames[0].previous, None);
    for (k, frame) in set.frames.iter().enumerate().skip(1) {
        assert_eq!(frame.previous, Some(k - 1), "one scene, in time order");
        assert!(frame.time_us > set.frames[k - 1].time_us);
    }
    let classes: std::collections::BTreeSet<usize> = set
        .frames
        .iter()
        .flat_map(|f| f.agents.iter().map(|a| a.class))
        .collect();
    assert_eq!(
        classes.len(),
        3,
        "cars, pedestrians and cyclists: {classes:?}"
    );
    // Every agent with a return, of a class the detector predicts: no more, no less.
    let options = DatasetOptions {
        skip_images: true,
        ..Default::default()
    };
    let dataset = Dataset::open(&data, &options).expect("opens");
    let mut wanted = 0;
    for index in 0..dataset.len() {
        wanted += dataset
            .read(index)
            .expect("frame")
            .boxes
            .iter()
            .filter(|b| b.num_pts > 0)
            .filter(|b| {
                bevworld_types::detection_name_of(&b.category)
                    .is_some_and(|n| config().class_index(n).is_some())
            })
            .count();
    }
    assert_eq!(
        set.frames.iter().map(|f| f.agents.len()).sum::<usize>(),
        wanted
    );
    // Channel 0 holds each keyframe's position: its mean is the mean position.
    let (mean, std) = set.channel_statistics();
    let expected = (keyframes - 1) as f32 / 2.0;
    assert!((mean[0] - expected).abs() < 1e-4, "{mean:?}");
    assert!(
        (mean[1] - 1.0).abs() < 1e-6 && std[1] <= 1e-6 + 1e-9,
        "a constant channel: {std:?}"
    );
}

#[test]
fn an_export_that_does_not_fit_its_set_is_refused_naming_what_is_wrong() {
    let root = tempfile::tempdir().expect("dir");
    let data = root.path().join("set");
    synthetic_set(&data);

    let missing = root.path().join("missing");
    export(&data, &missing, |index, entry| {
        if index == 2 {
            *entry = serde_json::Value::Null;
        }
    });
    let error = load_set(&missing, &data, &config())
        .err()
        .expect("a keyframe without a map");
    assert!(matches!(error, DataError::Invalid { .. }));
    assert!(
        error.to_string().contains("has no map of keyframe"),
        "{error}"
    );

    let foreign = root.path().join("foreign");
    export(&data, &foreign, |_, _| {});
    let index = foreign.join("index.json");
    let mut file: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&index).expect("index")).expect("json");
    let mut stranger = file["frames"][0].clone();
    stranger["sample_token"] = json!("not-a-sample");
    stranger["frame_token"] = json!("stranger");
    file["frames"]
        .as_array_mut()
        .expect("frames")
        .push(stranger);
    std::fs::write(&index, serde_json::to_vec(&file).expect("json")).expect("written");
    let error = load_set(&foreign, &data, &config())
        .err()
        .expect("a map of another set");
    let text = error.to_string();
    assert!(
        text.contains("not-a-sample") && text.contains("features of another set"),
        "{text}"
    );

    let mixed = root.path().join("mixed");
    export(&data, &mixed, |index, entry| {
        if index == 3 {
            entry["weights_hash"] = json!("def");
        }
    });
    let error = load_set(&mixed, &data, &config())
        .err()
        .expect("two models");
    let text = error.to_string();
    assert!(
        text.contains("abc") && text.contains("def") && text.contains("one export, one model"),
        "{text}"
    );

    let broken = root.path().join("broken");
    export(&data, &broken, |_, _| {});
    std::fs::write(broken.join("0.npy"), b"not an array").expect("written");
    let error = load_set(&broken, &data, &config())
        .err()
        .expect("a damaged array");
    assert!(error.to_string().contains("0.npy"), "{error}");
}

#[test]
fn a_moving_weight_under_one_is_refused_by_name_and_the_default_is_one() {
    let dir = tempfile::tempdir().expect("dir");
    let config = train_config(dir.path(), 4, 2);
    assert_eq!(
        config.loss.moving, 1.0,
        "a config without it counts every agent once"
    );
    let text = std::fs::read_to_string(dir.path().join("train.yaml")).expect("written");
    let path = dir.path().join("moving.yaml");
    std::fs::write(
        &path,
        text.replace("motion: 0.1}", "motion: 0.1, moving: 0.5}"),
    )
    .expect("written");
    let error = TrainDetectorConfig::from_yaml_file(&path)
        .expect_err("refused")
        .to_string();
    assert!(
        error.contains("loss.moving") && error.contains("0.5"),
        "{error}"
    );
}
