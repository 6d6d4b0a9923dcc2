//! The motion scores through the detections, by hand: which detection a true agent is matched
//! to, its minADE and minFDE over the modes, the miss rate, and constant velocity beside them;
//! and an annotated frame's agents in its ego frame with their futures.

use bevworld_heads::{AgentTruth, DetectorConfig};
use bevworld_heads_train::{LabelledFrame, agents_of, motion_scores};
use bevworld_types::{DetectedAgent, ObjectBox, Pose, SensorFrame, TrajectoryMode};
use glam::{DQuat, DVec3};

fn config() -> DetectorConfig {
    DetectorConfig::from_yaml(
        "
name: detector-test
classes: [car, pedestrian]
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

fn frame(agents: Vec<AgentTruth>) -> LabelledFrame {
    LabelledFrame {
        sample_token: "s0".into(),
        scene: "scene".into(),
        time_us: 0,
        global_from_ego: Pose::IDENTITY,
        map: Vec::new(),
        previous: None,
        agents,
    }
}

fn agent(class: usize, x: f64, future: [Option<[f64; 2]>; 2]) -> AgentTruth {
    AgentTruth {
        class,
        centre: [x, 0.0, 0.0],
        size: [2.0, 4.0, 1.5],
        yaw: 0.0,
        velocity: Some([2.0, 0.0]),
        future: future.to_vec(),
    }
}

fn detected(
    name: &str,
    score: f64,
    x: f64,
    velocity: f64,
    modes: Vec<Vec<[f64; 2]>>,
) -> DetectedAgent {
    let n = modes.len() as f64;
    DetectedAgent {
        detection_name: name.into(),
        score,
        centre: [x, 0.0, 0.0],
        size: [2.0, 4.0, 1.5],
        yaw: 0.0,
        velocity: [velocity, 0.0],
        modes: modes
            .into_iter()
            .map(|positions| TrajectoryMode {
                probability: 1.0 / n,
                positions,
            })
            .collect(),
    }
}

#[test]
fn motion_is_scored_through_the_matched_detection_by_hand() {
    let config = config();
    // A car at x = 0 going to (1, 0) then (2, 0); a pedestrian at x = 10 without a whole
    // future (not scored); a car at x = 30 that nothing detects.
    let truth = frame(vec![
        agent(0, 0.0, [Some([1.0, 0.0]), Some([2.0, 0.0])]),
        agent(1, 10.0, [Some([10.0, 1.0]), None]),
        agent(0, 30.0, [Some([31.0, 0.0]), Some([32.0, 0.0])]),
    ]);
    let detections = vec![
        // 0.5 m from the first car; its modes miss by (0.5, 0.5) and by (0, 3).
        detected(
            "car",
            0.9,
            0.5,
            1.0,
            vec![vec![[1.5, 0.0], [2.5, 0.0]], vec![[1.0, 0.0], [5.0, 0.0]]],
        ),
        // A weaker car detection at the same place: the first car is taken.
        detected("car", 0.3, 0.0, 0.0, vec![vec![[9.0, 9.0], [9.0, 9.0]]]),
        // A pedestrian detection 3 m from the pedestrian: beyond the 2 m match.
        detected(
            "pedestrian",
            0.8,
            13.0,
            0.0,
            vec![vec![[13.0, 0.0], [13.0, 0.0]]],
        ),
    ];
    let scores = motion_scores(&config.classes, &config.motion, &[&truth], &[&detections]);
    assert_eq!(scores.agents, 2, "the two cars have a whole future");
    assert_eq!(scores.matched, 1);
    // Mode 0: errors 0.5 and 0.5 → ADE 0.5, FDE 0.5; mode 1: 0 and 3 → ADE 1.5, FDE 3.
    assert!((scores.min_ade - 0.5).abs() < 1e-12, "{}", scores.min_ade);
    assert!((scores.min_fde - 0.5).abs() < 1e-12, "{}", scores.min_fde);
    assert_eq!(scores.miss_rate, 0.0);
    // Constant velocity from x = 0.5 at 1 m/s: 1.0 then 1.5, against 1 and 2 → 0 and 0.5.
    assert!((scores.constant_velocity_ade - 0.25).abs() < 1e-12);
    assert!((scores.constant_velocity_fde - 0.5).abs() < 1e-12);

    // Nothing detected: no figure, not a perfect one.
    let none = motion_scores(&config.classes, &config.motion, &[&truth], &[&Vec::new()]);
    assert_eq!((none.agents, none.matched), (2, 0));
    assert!(none.min_ade.is_nan() && none.miss_rate.is_nan());
}

#[test]
fn a_frames_agents_are_in_its_ego_frame_with_their_futures() {
    let config = config();
    // The ego at (100, 50), turned 90° left: global +y is its +x.
    let global_from_ego = Pose::from_rotation_translation(
        DQuat::from_rotation_z(std::f64::consts::FRAC_PI_2),
        DVec3::new(100.0, 50.0, 0.0),
    );
    let object = |x: f64, y: f64, points: i64| ObjectBox {
        instance_token: "car-1".into(),
        category: "vehicle.car".into(),
        global_from_box: Pose::from_rotation_translation(DQuat::IDENTITY, DVec3::new(x, y, 1.0)),
        size: [1.9, 4.5, 1.6],
        velocity: Some([0.0, 4.0]),
        attributes: vec!["vehicle.moving".into()],
        num_pts: points,
    };
    let sensor = |time_us: i64, boxes: Vec<ObjectBox>| SensorFrame {
        time_of_validity_us: time_us,
        global_from_ego,
        boxes,
        sample_token: String::new(),
        frame_token: String::new(),
        scene_name: "scene".into(),
        index_in_scene: 0,
        keyframe: true,
        cameras: Vec::new(),
        lidar: Default::default(),
        action: None,
    };
    let now = sensor(
        0,
        vec![object(100.0, 60.0, 12), {
            let mut hidden = object(90.0, 50.0, 0);
            hidden.instance_token = "car-2".into();
            hidden
        }],
    );
    let next = sensor(500_000, vec![object(100.0, 62.0, 12)]);
    // The step after is 1.5 s on, not 1 s: a gap, so no position.
    let after_gap = sensor(1_500_000, vec![object(100.0, 66.0, 12)]);
    let agents = agents_of(&config.classes, &config.motion, &now, &[&next, &after_gap]);
    assert_eq!(agents.len(), 1, "the box without a return is not learnt");
    let car = &agents[0];
    // 10 m ahead of the ego along global +y: its +x.
    assert!((car.centre[0] - 10.0).abs() < 1e-9 && car.centre[1].abs() < 1e-9);
    assert!(
        (car.yaw + std::f64::consts::FRAC_PI_2).abs() < 1e-9,
        "{}",
        car.yaw
    );
    let [vx, vy] = car.velocity.expect("annotated velocity");
    assert!((vx - 4.0).abs() < 1e-9 && vy.abs() < 1e-9);
    let first = car.future[0].expect("annotated at the next keyframe");
    assert!((first[0] - 12.0).abs() < 1e-9 && first[1].abs() < 1e-9);
    assert_eq!(car.future[1], None);
}
