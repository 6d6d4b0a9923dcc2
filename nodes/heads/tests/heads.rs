//! The detector's parts against known answers: targets decoded back to the boxes they came
//! from, CenterNet's radius and the focal loss by hand, the two-frame warp, an empty frame,
//! and weights refused for another model's features.

use bevworld_heads::{
    AgentTruth, BOX_CHANNELS, DetectorConfig, DetectorMeta, FrameMaps, HeadOutputs, InputKind,
    InputSpec, LossWeights, PosedMap, gaussian_radius, load_detector, save_detector,
};
use bevworld_types::BevGrid;
use burn::prelude::*;
use glam::{DQuat, DVec3};

const CONFIG: &str = "
name: detector-test
classes: [car, pedestrian]
output_cells: 8
trunk: {embed_dim: 8, depths: [2], heads: [2], window: 4}
head_hidden: 8
motion: {modes: 2, steps: 3, interval_s: 0.5}
min_radius: 1
max_detections: 10
min_score: 0.1
";

fn config() -> DetectorConfig {
    DetectorConfig::from_yaml(CONFIG, "test").expect("valid config")
}

/// 8 × 8 cells of 2.5 m over [-10, 10).
fn grid() -> BevGrid {
    BevGrid {
        x_range: [-10.0, 10.0],
        y_range: [-10.0, 10.0],
        resolution: 2.5,
        height: 8,
        width: 8,
    }
}

fn input(frames: usize) -> InputSpec {
    InputSpec {
        kind: InputKind::Latent,
        channels: 1,
        grid: grid(),
        frames,
        model: "tokenizer-tiny".into(),
        weights_hash: "abc".into(),
        mean: vec![0.0],
        std: vec![1.0],
    }
}

fn car() -> AgentTruth {
    AgentTruth {
        class: 0,
        centre: [3.3, -4.1, 0.8],
        size: [1.9, 4.5, 1.6],
        yaw: 0.3,
        velocity: Some([2.0, 1.0]),
        future: vec![Some([4.3, -3.6]), Some([5.3, -3.1]), None],
    }
}

#[test]
fn centernet_radius_matches_a_hand_computation() {
    // A 4 × 2 cell box at overlap 0.1, CenterNet's three bounds:
    // r1 = (6 + √(36 − 4 · 8 · 0.9 / 1.1)) / 2 = 5.4272,
    // r2 = (12 + √(144 − 16 · 0.9 · 8)) / 2 = 10.3246,
    // r3 = (−1.2 + √(1.44 + 4 · 0.4 · 7.2)) / 2 = (−1.2 + 3.6) / 2 = 1.2, the smallest.
    let r = gaussian_radius(4.0, 2.0, 0.1);
    assert!((r - 1.2).abs() < 1e-12, "{r}");
}

#[test]
fn targets_decode_back_to_the_boxes_they_were_made_from() {
    let config = config();
    let truth = car();
    let targets = config.targets(&grid(), std::slice::from_ref(&truth));
    assert_eq!(targets.objects.len(), 1);
    let object = &targets.objects[0];
    // (3.3, −4.1) lies in column (3.3 + 10) / 2.5 = 5.32 → 5, row (−4.1 + 10) / 2.5 = 2.36 → 2.
    assert_eq!(object.cell, 2 * 8 + 5);
    assert_eq!(targets.heatmap[object.cell], 1.0);
    assert!((object.boxes[0] - 0.32).abs() < 1e-5 && (object.boxes[1] - 0.36).abs() < 1e-5);
    assert_eq!(object.future_known, vec![true, true, false]);

    // Maps as a perfect head would give them: the heatmap's logit high at the centre, the
    // box and the first mode the targets, the first mode the likelier.
    let plane = 64;
    let mut heatmap = vec![-8.0f32; 2 * plane];
    heatmap[object.cell] = 4.0;
    let mut boxes = vec![0.0f32; BOX_CHANNELS * plane];
    for (c, value) in object.boxes.iter().enumerate() {
        boxes[c * plane + object.cell] = *value;
    }
    let mut motion = vec![0.0f32; config.motion_channels() * plane];
    for (s, [x, y]) in object.future.iter().enumerate() {
        motion[(2 * s) * plane + object.cell] = *x;
        motion[(2 * s + 1) * plane + object.cell] = *y;
    }
    motion[(2 * 2 * 3) * plane + object.cell] = 3.0; // mode 0's logit
    let maps = FrameMaps {
        heatmap: &heatmap,
        boxes: &boxes,
        motion: &motion,
    };
    let agents = config.decode(&grid(), &maps);
    assert_eq!(agents.len(), 1, "one peak above min_score");
    let agent = &agents[0];
    assert_eq!(agent.detection_name, "car");
    assert!((agent.score - 1.0 / (1.0 + (-4.0f64).exp())).abs() < 1e-6);
    for k in 0..3 {
        assert!(
            (agent.centre[k] - truth.centre[k]).abs() < 1e-5,
            "centre {k}"
        );
        assert!((agent.size[k] - truth.size[k]).abs() < 1e-5, "size {k}");
    }
    assert!((agent.yaw - truth.yaw).abs() < 1e-6);
    assert!((agent.velocity[0] - 2.0).abs() < 1e-6 && (agent.velocity[1] - 1.0).abs() < 1e-6);
    let best = &agent.modes[0];
    assert!(best.probability > agent.modes[1].probability);
    assert!((best.positions[0][0] - 4.3).abs() < 1e-5 && (best.positions[1][1] + 3.1).abs() < 1e-5);
}

#[test]
fn an_empty_frame_gives_no_detections_and_a_finite_loss() {
    let config = config();
    let plane = 64;
    let heatmap = vec![-8.0f32; 2 * plane];
    let boxes = vec![0.0f32; BOX_CHANNELS * plane];
    let motion = vec![0.0f32; config.motion_channels() * plane];
    let maps = FrameMaps {
        heatmap: &heatmap,
        boxes: &boxes,
        motion: &motion,
    };
    assert!(config.decode(&grid(), &maps).is_empty());

    let device = Device::flex();
    let targets = config.targets(&grid(), &[]);
    let outputs = HeadOutputs {
        heatmap: Tensor::<4>::full([1, 2, 8, 8], -8.0, &device),
        boxes: Tensor::<4>::zeros([1, BOX_CHANNELS, 8, 8], &device),
        motion: Tensor::<4>::zeros([1, config.motion_channels(), 8, 8], &device),
    };
    let weights = LossWeights {
        heatmap: 1.0,
        boxes: 1.0,
        motion: 1.0,
        moving: 1.0,
    };
    let loss = config.loss(outputs, &[&targets], &weights);
    let total = loss.total.into_scalar::<f32>();
    assert!(total.is_finite() && total > 0.0, "{total}");
}

#[test]
fn the_focal_loss_matches_a_hand_computation() {
    // One class on 8 × 8 cells, every logit 0 (p = ½), one agent: at its centre
    // −ln ½ · (½)² = 0.17329; each other cell −ln ½ · (½)² · (1 − y)⁴ with its Gaussian y.
    let mut config = config();
    config.classes = vec!["car".into()];
    let truth = car();
    let targets = config.targets(&grid(), &[truth]);
    let device = Device::flex();
    let outputs = HeadOutputs {
        heatmap: Tensor::<4>::zeros([1, 1, 8, 8], &device),
        boxes: Tensor::<4>::zeros([1, BOX_CHANNELS, 8, 8], &device),
        motion: Tensor::<4>::zeros([1, config.motion_channels(), 8, 8], &device),
    };
    let weights = LossWeights {
        heatmap: 1.0,
        boxes: 0.0,
        motion: 0.0,
        moving: 1.0,
    };
    let loss = config.loss(outputs, &[&targets], &weights);
    let quarter_ln2 = 0.25 * std::f64::consts::LN_2;
    let expected: f64 = targets
        .heatmap
        .iter()
        .map(|&y| {
            if y == 1.0 {
                quarter_ln2
            } else {
                quarter_ln2 * (1.0 - f64::from(y)).powi(4)
            }
        })
        .sum();
    let heat = f64::from(loss.heatmap.into_scalar::<f32>());
    assert!((heat - expected).abs() < 1e-5, "{heat} against {expected}");
    // The box loss by hand: |0 − target| summed over the channels, velocity included.
    let box_sum: f64 = targets.objects[0]
        .boxes
        .iter()
        .map(|v| f64::from(v.abs()))
        .sum();
    let boxes = f64::from(loss.boxes.into_scalar::<f32>());
    assert!((boxes - box_sum).abs() < 1e-4, "{boxes} against {box_sum}");
}

#[test]
fn two_frames_see_a_standing_object_in_the_same_cell() {
    // The ego drove 5 m (two cells) along +x between the frames: an object standing at
    // x = 2.5 m in the previous frame's map is at x = −2.5 m now, and the warped previous map
    // must put it there, in the current map's cell.
    let spec = input(2);
    let cell = |x: f64, y: f64| {
        let j = ((x + 10.0) / 2.5).floor() as usize;
        let i = ((y + 10.0) / 2.5).floor() as usize;
        i * 8 + j
    };
    let mut previous = vec![0.0f32; 64];
    previous[cell(3.75, 1.25)] = 1.0;
    let mut current = vec![0.0f32; 64];
    current[cell(-1.25, 1.25)] = 1.0;
    let pose = |x: f64| {
        bevworld_types::Pose::from_rotation_translation(DQuat::IDENTITY, DVec3::new(x, 0.0, 0.0))
    };
    let assembled = spec
        .assemble(
            &PosedMap {
                values: &current,
                global_from_ego: pose(105.0),
            },
            Some(&PosedMap {
                values: &previous,
                global_from_ego: pose(100.0),
            }),
        )
        .expect("maps of the right shape");
    assert_eq!(assembled.len(), 128);
    assert_eq!(
        &assembled[..64],
        &current[..],
        "the current frame first, as given"
    );
    assert!((assembled[64 + cell(-1.25, 1.25)] - 1.0).abs() < 1e-6);
    assert!(assembled[64 + cell(3.75, 1.25)].abs() < 1e-6);
    // Without a previous frame the current one is read twice.
    let alone = spec
        .assemble(
            &PosedMap {
                values: &current,
                global_from_ego: pose(0.0),
            },
            None,
        )
        .expect("maps of the right shape");
    assert_eq!(&alone[64..], &current[..]);
}

#[test]
fn a_map_of_the_wrong_shape_or_with_nan_is_refused() {
    let spec = input(1);
    let pose = bevworld_types::Pose::IDENTITY;
    let short = vec![0.0f32; 10];
    let error = spec
        .assemble(
            &PosedMap {
                values: &short,
                global_from_ego: pose,
            },
            None,
        )
        .expect_err("10 values for 64 cells");
    assert!(error.to_string().contains("10 values"), "{error}");
    let mut nan = vec![0.0f32; 64];
    nan[3] = f32::NAN;
    let error = spec
        .assemble(
            &PosedMap {
                values: &nan,
                global_from_ego: pose,
            },
            None,
        )
        .expect_err("a NaN");
    assert!(error.to_string().contains("1 non-finite"), "{error}");
}

#[test]
fn weights_refuse_another_models_features_and_changed_bytes() {
    let dir = tempfile::tempdir().expect("temporary folder");
    let config = config();
    let spec = input(1);
    let device = Device::flex();
    let model = config.init(&spec, &device);
    let meta = DetectorMeta {
        config: config.clone(),
        input: spec.clone(),
        init: "frozen".into(),
        steps: 1,
        command: "test".into(),
        weights_hash: String::new(),
    };
    let path = dir.path().join("detector.bpk");
    save_detector(&model, &meta, &path).expect("saved");
    let loaded = load_detector(&path, &device).expect("loads back");
    assert_eq!(loaded.meta.input, spec);
    loaded
        .check_features("tokenizer-tiny", "abc")
        .expect("the features it was trained on");
    let error = loaded
        .check_features("tokenizer-tiny", "def")
        .expect_err("other weights");
    let text = error.to_string();
    assert!(text.contains("abc") && text.contains("def"), "{text}");

    let mut bytes = std::fs::read(&path).expect("weights");
    let last = bytes.len() - 1;
    bytes[last] ^= 1;
    std::fs::write(&path, bytes).expect("written");
    let error = load_detector(&path, &device)
        .err()
        .expect("changed weights");
    assert!(
        error
            .to_string()
            .contains("changed after they were written"),
        "{error}"
    );
}

#[test]
fn a_config_names_each_bad_field() {
    let bad = CONFIG
        .replace("classes: [car, pedestrian]", "classes: [car, tractor]")
        .replace("window: 4", "window: 3");
    let error = DetectorConfig::from_yaml(&bad, "bad.yaml").expect_err("two problems");
    let text = error.to_string();
    assert!(
        text.contains("classes[1]") && text.contains("tractor"),
        "{text}"
    );
    assert!(text.contains("trunk.window"), "{text}");
    let unknown = format!("{CONFIG}colour: red\n");
    let error = DetectorConfig::from_yaml(&unknown, "bad.yaml").expect_err("unknown key");
    assert!(error.to_string().contains("colour"), "{error}");
}

#[test]
fn a_moving_agent_counts_moving_times_in_its_velocity_and_motion_terms() {
    // One car moving at √5 m/s: with `moving` 3 its two velocity channels and its motion term
    // count three times; the other box channels and the heatmap do not change. Standing, the
    // weight does nothing.
    let mut config = config();
    config.classes = vec!["car".into()];
    let device = Device::flex();
    let outputs = || HeadOutputs {
        heatmap: Tensor::<4>::zeros([1, 1, 8, 8], &device),
        boxes: Tensor::<4>::zeros([1, BOX_CHANNELS, 8, 8], &device),
        motion: Tensor::<4>::zeros([1, config.motion_channels(), 8, 8], &device),
    };
    let weights = |moving: f64| LossWeights {
        heatmap: 1.0,
        boxes: 1.0,
        motion: 1.0,
        moving,
    };
    let scores = |truth: AgentTruth, moving: f64| {
        let targets = config.targets(&grid(), &[truth]);
        let loss = config.loss(outputs(), &[&targets], &weights(moving));
        let velocity: f64 = targets.objects[0].boxes[8..]
            .iter()
            .map(|v| f64::from(v.abs()))
            .sum();
        (
            f64::from(loss.heatmap.into_scalar::<f32>()),
            f64::from(loss.boxes.into_scalar::<f32>()),
            f64::from(loss.motion.into_scalar::<f32>()),
            velocity,
        )
    };
    let (heat_1, boxes_1, motion_1, velocity) = scores(car(), 1.0);
    let (heat_3, boxes_3, motion_3, _) = scores(car(), 3.0);
    assert!((velocity - 3.0).abs() < 1e-5, "|2| + |1|: {velocity}");
    assert_eq!(heat_1, heat_3);
    assert!(
        (boxes_3 - (boxes_1 + 2.0 * velocity)).abs() < 1e-4,
        "{boxes_3} {boxes_1}"
    );
    assert!(motion_1 > 0.0 && (motion_3 - 3.0 * motion_1).abs() < 1e-4 * motion_1.max(1.0));
    let parked = AgentTruth {
        velocity: Some([0.1, 0.0]),
        ..car()
    };
    let (_, boxes_1, motion_1, _) = scores(parked.clone(), 1.0);
    let (_, boxes_3, motion_3, _) = scores(parked, 3.0);
    assert_eq!((boxes_1, motion_1), (boxes_3, motion_3));
}
