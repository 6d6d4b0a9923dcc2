//! How well the agent layer's tracks (`bevworld_types::agent_track`, `move_agents`'
//! `follow: track`) tell each annotated car's speed, beside the detector's velocity head: the
//! per-car measure behind `agents.md`'s "Tracks" section.
//!
//! Every annotated car of a keyframe is matched to the nearest confident detection of a car
//! within 2 m (nearest pairs first). A car is moving when its annotated speed is at least
//! 1 m/s and parked under `MOVING_SPEED_MPS`; between the two it is neither. For each class:
//! how many were detected, how many of those the agent layer would carry (a track at least
//! `min_speed_mps` fast; the head's velocity at least that fast), and the error of each
//! velocity against the annotated one. The detections are tracked in the global frame, which
//! moves nothing: a track's speed is the same in every frame.

use std::collections::BTreeMap;

use bevworld_types::{
    AgentTrack, DetectedAgent, Detection, DetectionsWithReturns, FrameDetections, FrameMeta,
    MOVING_SPEED_MPS, Pose, ReturnsRule, SensorFrame, TrackRule, frame_returns, track_agents,
    velocities_on_returns,
};
use serde::{Deserialize, Serialize};

/// The annotated speed from which a car counts as moving, m/s.
pub const MOVING_FROM_MPS: f64 = 1.0;
/// How far a detection may lie from an annotated car it is matched to, m.
pub const MATCH_DISTANCE_M: f64 = 2.0;

/// One class of annotated cars (moving or parked), summed over the keyframes.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CarClassSpeeds {
    /// Annotated cars with a velocity.
    pub cars: usize,
    /// Of them, matched to a confident detection.
    pub detected: usize,
    /// Of those, whose detection has a track through an earlier frame.
    pub tracked: usize,
    /// Of the detected, those the layer would carry by their track (at least the speed bar).
    pub carried_by_track: usize,
    /// Of the detected, those the layer would carry by the detector's velocity.
    pub carried_by_head: usize,
    /// Median |velocity − annotated velocity| over the tracked, m/s (none without one).
    pub track_error_median_mps: Option<f64>,
    /// The same for the detector's velocity over the detected, m/s.
    pub head_error_median_mps: Option<f64>,
    /// Of the tracked, those whose track's velocity is within 1 m/s of the annotated one.
    pub track_within_1mps: usize,
}

/// Both classes.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrackSpeeds {
    pub keyframes: usize,
    /// Frames a track reaches back, the current one included (files written before it was
    /// recorded tracked through 3).
    #[serde(default = "three_frames")]
    pub frames: usize,
    pub min_score: f64,
    pub min_speed_mps: f64,
    /// With velocities read from the LiDAR returns (`agent_returns`): the margin around each
    /// box that took them, m; `None` for the detector's positions.
    #[serde(default)]
    pub returns_margin_m: Option<f64>,
    pub moving: CarClassSpeeds,
    pub parked: CarClassSpeeds,
}

fn three_frames() -> usize {
    3
}

fn median(mut values: Vec<f64>) -> Option<f64> {
    if values.is_empty() {
        return None;
    }
    values.sort_by(f64::total_cmp);
    let n = values.len();
    Some(if n % 2 == 1 {
        values[n / 2]
    } else {
        0.5 * (values[n / 2 - 1] + values[n / 2])
    })
}

/// A keyframe's detections as the tracker reads them, in the global frame.
fn in_global_frame(frame: &SensorFrame, detections: &[Detection]) -> FrameDetections {
    FrameDetections {
        meta: FrameMeta {
            sample_token: frame.sample_token.clone(),
            frame_token: frame.frame_token.clone(),
            scene_name: frame.scene_name.clone(),
            time_of_validity_us: frame.time_of_validity_us,
            global_from_ego: Pose::IDENTITY,
            keyframe: true,
        },
        agents: detections
            .iter()
            .map(|d| DetectedAgent {
                detection_name: d.detection_name.clone(),
                score: d.detection_score,
                centre: d.translation,
                size: d.size,
                yaw: d.yaw(),
                velocity: d.velocity,
                modes: Vec::new(),
            })
            .collect(),
        interval_s: 0.5,
        model: String::new(),
        weights_hash: String::new(),
    }
}

/// A keyframe's LiDAR returns off the ego's body, in the global frame (where the tracker reads
/// `in_global_frame`'s detections).
fn global_points(frame: &SensorFrame) -> Vec<[f32; 3]> {
    let global_from_lidar = frame.lidar.global_from_ego * frame.lidar.ego_from_lidar;
    frame
        .lidar
        .scene_indices()
        .into_iter()
        .map(|i| {
            let p = &frame.lidar.points[i];
            let g = global_from_lidar.transform_point3(glam::DVec3::new(
                f64::from(p.x),
                f64::from(p.y),
                f64::from(p.z),
            ));
            [g.x as f32, g.y as f32, g.z as f32]
        })
        .collect()
}

/// The per-car speeds of `results` (by sample token, the submission's boxes) on `keyframes`,
/// tracked by `rule`, each track's velocity read from the detections' positions or, with
/// `returns`, from the registration of its LiDAR returns; the layer carries what is at least
/// `min_speed_mps` fast.
pub fn track_speeds(
    keyframes: &[SensorFrame],
    results: &BTreeMap<String, Vec<Detection>>,
    rule: &TrackRule,
    returns: Option<&ReturnsRule>,
    min_speed_mps: f64,
) -> TrackSpeeds {
    let mut order: Vec<&SensorFrame> = keyframes.iter().collect();
    order.sort_by(|a, b| {
        (a.scene_name.as_str(), a.time_of_validity_us)
            .cmp(&(b.scene_name.as_str(), b.time_of_validity_us))
    });
    let frames: Vec<FrameDetections> = order
        .iter()
        .map(|f| {
            let boxes = results.get(&f.sample_token).map_or(&[][..], Vec::as_slice);
            in_global_frame(f, boxes)
        })
        .collect();
    // With `returns`, each agent's returns, and the velocities come from their registration.
    let frame_returns: Vec<Vec<Vec<[f64; 2]>>> = match returns {
        None => Vec::new(),
        Some(returns) => order
            .iter()
            .zip(&frames)
            .map(|(f, d)| frame_returns(d, &global_points(f), returns))
            .collect(),
    };
    let mut errors: [(Vec<f64>, Vec<f64>); 2] = Default::default();
    let mut summary = TrackSpeeds {
        keyframes: frames.len(),
        frames: rule.frames,
        min_score: rule.min_score,
        min_speed_mps,
        returns_margin_m: returns.map(|r| r.margin_m),
        ..Default::default()
    };
    for (k, (frame, detections)) in order.iter().zip(&frames).enumerate() {
        // The frames before this one, newest first; `track_agents` stops at another scene.
        let velocities: Vec<Option<[f64; 2]>> = match returns {
            None => {
                let earlier: Vec<&FrameDetections> = frames[..k].iter().rev().collect();
                track_agents(detections, &earlier, rule)
                    .iter()
                    .map(AgentTrack::velocity)
                    .collect()
            }
            Some(returns) => {
                let with_returns = |i: usize| DetectionsWithReturns {
                    detections: &frames[i],
                    returns: &frame_returns[i],
                };
                let earlier: Vec<DetectionsWithReturns<'_>> =
                    (0..k).rev().map(with_returns).collect();
                velocities_on_returns(with_returns(k), &earlier, rule, returns.min_returns)
            }
        };
        let speed = |v: [f64; 2]| v[0].hypot(v[1]);
        // Nearest pairs first, as the tracker links.
        let mut pairs: Vec<(f64, usize, usize)> = Vec::new();
        for (i, object) in frame.boxes.iter().enumerate() {
            if bevworld_types::detection_name_of(&object.category) != Some("car")
                || object.velocity.is_none()
            {
                continue;
            }
            let at = object.global_from_box.translation;
            for (j, agent) in detections.agents.iter().enumerate() {
                if agent.detection_name != "car" || agent.score < rule.min_score {
                    continue;
                }
                let distance = (agent.centre[0] - at.x).hypot(agent.centre[1] - at.y);
                if distance <= MATCH_DISTANCE_M {
                    pairs.push((distance, i, j));
                }
            }
        }
        pairs.sort_by(|a, b| a.0.total_cmp(&b.0));
        let mut matched: Vec<Option<usize>> = vec![None; frame.boxes.len()];
        let mut taken = vec![false; detections.agents.len()];
        for (_, i, j) in pairs {
            if matched[i].is_none() && !taken[j] {
                matched[i] = Some(j);
                taken[j] = true;
            }
        }
        for (object, detection) in frame.boxes.iter().zip(&matched) {
            let Some(truth) = object.velocity else {
                continue;
            };
            if bevworld_types::detection_name_of(&object.category) != Some("car") {
                continue;
            }
            let (class, class_errors) = if speed(truth) >= MOVING_FROM_MPS {
                (&mut summary.moving, &mut errors[0])
            } else if speed(truth) < MOVING_SPEED_MPS {
                (&mut summary.parked, &mut errors[1])
            } else {
                continue;
            };
            class.cars += 1;
            let Some(j) = *detection else { continue };
            class.detected += 1;
            let head = detections.agents[j].velocity;
            class_errors
                .1
                .push(speed([head[0] - truth[0], head[1] - truth[1]]));
            class.carried_by_head += usize::from(speed(head) >= min_speed_mps);
            if let Some(v) = velocities[j] {
                class.tracked += 1;
                let error = speed([v[0] - truth[0], v[1] - truth[1]]);
                class_errors.0.push(error);
                class.track_within_1mps += usize::from(error <= 1.0);
                class.carried_by_track += usize::from(speed(v) >= min_speed_mps);
            }
        }
    }
    let [(moving_track, moving_head), (parked_track, parked_head)] = errors;
    summary.moving.track_error_median_mps = median(moving_track);
    summary.moving.head_error_median_mps = median(moving_head);
    summary.parked.track_error_median_mps = median(parked_track);
    summary.parked.head_error_median_mps = median(parked_head);
    summary
}

#[cfg(test)]
mod tests {
    use super::*;
    use bevworld_types::ObjectBox;
    use glam::DVec3;
    use std::sync::Arc;

    fn car_box(x: f64, y: f64, velocity: [f64; 2]) -> ObjectBox {
        ObjectBox {
            instance_token: format!("i{y}"),
            category: "vehicle.car".into(),
            global_from_box: Pose::from_translation(DVec3::new(x, y, 0.8)),
            size: [1.9, 4.5, 1.6],
            velocity: Some(velocity),
            attributes: Vec::new(),
            num_pts: 10,
        }
    }

    fn keyframe(t: f64, boxes: Vec<ObjectBox>) -> SensorFrame {
        SensorFrame {
            time_of_validity_us: (t * 1e6).round() as i64,
            sample_token: format!("s{t}"),
            frame_token: format!("f{t}"),
            scene_name: "a".into(),
            index_in_scene: (t * 2.0) as usize,
            keyframe: true,
            global_from_ego: Pose::from_translation(DVec3::new(5.0 * t, 0.0, 0.0)),
            cameras: Vec::new(),
            lidar: Arc::new(Default::default()),
            action: None,
            boxes,
        }
    }

    fn detection(t: f64, x: f64, y: f64, velocity: [f64; 2], score: f64) -> Detection {
        Detection {
            sample_token: format!("s{t}"),
            translation: [x, y, 0.8],
            size: [1.9, 4.5, 1.6],
            rotation: [1.0, 0.0, 0.0, 0.0],
            velocity,
            detection_name: "car".into(),
            detection_score: score,
            attribute_name: String::new(),
        }
    }

    #[test]
    fn moving_and_parked_cars_are_scored_by_hand() {
        // A car drives +x at 10 m/s along y = 0 (annotated 10 m/s), detected 0.2 m behind at
        // t = 0.5 with a head that says 1 m/s; a car parked at (20, 4) is detected at
        // (20, 4), (20.5, 4), (21, 4): a drift of 1 m/s its track reads and its head (0 m/s)
        // does not. At 0.5 s a third car parked at (40, 4) is missed (its detection scored
        // 0.1). The first frame's cars have no earlier frame: detected, untracked.
        let times = [0.0, 0.5, 1.0];
        let keyframes: Vec<SensorFrame> = times
            .iter()
            .map(|&t| {
                keyframe(
                    t,
                    vec![
                        car_box(10.0 * t, 0.0, [10.0, 0.0]),
                        car_box(20.0, 4.0, [0.0, 0.0]),
                        car_box(40.0, 4.0, [0.0, 0.0]),
                    ],
                )
            })
            .collect();
        let mut results = BTreeMap::new();
        for &t in &times {
            let driving_x = 10.0 * t - if t == 0.5 { 0.2 } else { 0.0 };
            results.insert(
                format!("s{t}"),
                vec![
                    detection(t, driving_x, 0.0, [1.0, 0.0], 0.9),
                    detection(t, 20.0 + t, 4.0, [0.0, 0.0], 0.8),
                    detection(t, 40.0, 4.0, [0.0, 0.0], 0.1),
                ],
            );
        }
        let rule = TrackRule {
            frames: 3,
            max_speed_mps: 20.0,
            gate_m: 2.0,
            min_score: 0.3,
        };
        let speeds = track_speeds(&keyframes, &results, &rule, None, 2.0);
        assert_eq!(speeds.keyframes, 3);
        let moving = &speeds.moving;
        assert_eq!((moving.cars, moving.detected, moving.tracked), (3, 3, 2));
        // Tracked at 0.5 s: (4.8 − 0)/0.5 = 9.6 m/s, error 0.4. At 1 s, the slope through
        // 0, 4.8, 10 at −1, −0.5, 0 s: ((−0.5)(−4.933) + 0 + (0.5)(5.067)) / 0.5 = 10, error 0.
        // Median of {0.4, 0}: 0.2. The head's error is 9 every time.
        let close = |v: Option<f64>, to: f64| v.is_some_and(|v| (v - to).abs() < 1e-9);
        assert!(close(moving.track_error_median_mps, 0.2), "{moving:?}");
        assert!(close(moving.head_error_median_mps, 9.0));
        assert_eq!((moving.carried_by_track, moving.carried_by_head), (2, 0));
        assert_eq!(moving.track_within_1mps, 2);
        let parked = &speeds.parked;
        // Six parked cars, three missed (the unsure detections), two tracked at 1 m/s: under
        // the bar, not carried.
        assert_eq!((parked.cars, parked.detected, parked.tracked), (6, 3, 2));
        assert!(close(parked.track_error_median_mps, 1.0));
        assert_eq!(parked.head_error_median_mps, Some(0.0));
        assert_eq!((parked.carried_by_track, parked.carried_by_head), (0, 0));
        // At a bar of 0.5 m/s the drifting parked car is carried twice.
        let low = track_speeds(&keyframes, &results, &rule, None, 0.5);
        assert_eq!(low.parked.carried_by_track, 2);
        // Tracks of two frames: at 1 s the driving car's slope is (10 − 4.8)/0.5 = 10.4 m/s,
        // error 0.4, as at 0.5 s: the median becomes 0.4.
        let short = TrackRule { frames: 2, ..rule };
        let two = track_speeds(&keyframes, &results, &short, None, 2.0);
        assert_eq!(two.frames, 2);
        assert!(
            close(two.moving.track_error_median_mps, 0.4),
            "{:?}",
            two.moving
        );
    }

    #[test]
    fn no_detection_gives_no_error_figure_rather_than_zero() {
        let keyframes = vec![keyframe(0.0, vec![car_box(0.0, 0.0, [5.0, 0.0])])];
        let rule = TrackRule {
            frames: 3,
            max_speed_mps: 20.0,
            gate_m: 2.0,
            min_score: 0.3,
        };
        let speeds = track_speeds(&keyframes, &BTreeMap::new(), &rule, None, 2.0);
        assert_eq!((speeds.moving.cars, speeds.moving.detected), (1, 0));
        assert_eq!(speeds.moving.track_error_median_mps, None);
        assert_eq!(speeds.moving.head_error_median_mps, None);
        // And it reads back as written.
        let text = serde_json::to_string(&speeds).expect("json");
        let back: TrackSpeeds = serde_json::from_str(&text).expect("read back");
        assert_eq!(back, speeds);
        // A summary missing a field, or with one it does not know, is refused by name.
        let missing = text.replace("\"tracked\":0,", "");
        let error = serde_json::from_str::<TrackSpeeds>(&missing)
            .unwrap_err()
            .to_string();
        assert!(error.contains("tracked"), "{error}");
        let unknown = text.replace("\"keyframes\"", "\"keyframe_count\"");
        let error = serde_json::from_str::<TrackSpeeds>(&unknown)
            .unwrap_err()
            .to_string();
        assert!(error.contains("keyframe_count"), "{error}");
        // A summary from before the track length was recorded tracked through 3 frames.
        let before = text.replace("\"frames\":3,", "");
        assert_ne!(before, text);
        let back: TrackSpeeds = serde_json::from_str(&before).expect("older summary");
        assert_eq!(back.frames, 3);
    }
}
