//! `bevworld eval detector --trajectories FILE`: a detector's trajectories (the
//! `trajectories.json` that `detections_sink` writes beside `results_nusc.json`) scored as the
//! paper scores motion, through the detections: each annotated agent whose whole future the
//! dataset gives is matched to the best detection of its class within 2 m, and the best mode's
//! minADE and minFDE, the miss rate, and the same box extrapolated at its velocity, are taken
//! (`bevworld_heads_train::motion_scores`, the scores training reports).

use std::collections::{BTreeMap, HashMap};
use std::path::Path;

use anyhow::{Context, Result, bail};
use bevworld_heads::MotionConfig;
use bevworld_heads_train::{LabelledFrame, MotionScores, agents_of, motion_scores};
use bevworld_types::pose::yaw_of;
use bevworld_types::{DetectedAgent, Detection, SensorFrame, TrajectoryMode};
use glam::DVec3;
use serde::Deserialize;

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct TrajectoriesFile {
    interval_s: f64,
    frame: String,
    samples: BTreeMap<String, Vec<BoxTrajectories>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct BoxTrajectories {
    detection_name: String,
    detection_score: f64,
    modes: Vec<Mode>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct Mode {
    probability: f64,
    positions: Vec<[f64; 2]>,
}

/// A box and its modes in the frame's ego frame.
fn in_ego_frame(detection: &Detection, modes: &[Mode], frame: &SensorFrame) -> DetectedAgent {
    let ego_from_global = frame.global_from_ego.inverse();
    let centre = ego_from_global.transform_point3(DVec3::from_array(detection.translation));
    let velocity = ego_from_global.transform_vector3(DVec3::new(
        detection.velocity[0],
        detection.velocity[1],
        0.0,
    ));
    DetectedAgent {
        detection_name: detection.detection_name.clone(),
        score: detection.detection_score,
        centre: centre.to_array(),
        size: detection.size,
        yaw: detection.yaw() - yaw_of(&frame.global_from_ego),
        velocity: [velocity.x, velocity.y],
        modes: modes
            .iter()
            .map(|mode| TrajectoryMode {
                probability: mode.probability,
                positions: mode
                    .positions
                    .iter()
                    .map(|[x, y]| {
                        let p = ego_from_global.transform_point3(DVec3::new(*x, *y, 0.0));
                        [p.x, p.y]
                    })
                    .collect(),
            })
            .collect(),
    }
}

/// The motion scores of `trajectories` (with the boxes of `results`) on the keyframes.
pub fn score(
    path: &Path,
    results: &BTreeMap<String, Vec<Detection>>,
    keyframes: &[SensorFrame],
) -> Result<MotionScores> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let file: TrajectoriesFile = serde_json::from_str(&text)
        .map_err(|e| super::refuse(format!("--trajectories {}: {e}", path.display())))?;
    let refuse =
        |message: String| super::refuse(format!("--trajectories {}: {message}", path.display()));
    if file.frame != "global" {
        return Err(refuse(format!("frame '{}' (accepted: global)", file.frame)));
    }
    if !(file.interval_s.is_finite() && file.interval_s > 0.0) {
        return Err(refuse(format!(
            "interval_s {} (accepted: a number > 0)",
            file.interval_s
        )));
    }
    let steps = file
        .samples
        .values()
        .flatten()
        .flat_map(|b| b.modes.first())
        .map(|m| m.positions.len())
        .next()
        .unwrap_or(0);
    for (sample, boxes) in &file.samples {
        let listed = results.get(sample).map_or(0, Vec::len);
        if boxes.len() != listed {
            return Err(refuse(format!(
                "sample {sample} has {} trajectories for {listed} boxes in the results",
                boxes.len()
            )));
        }
        for (k, entry) in boxes.iter().enumerate() {
            let detection = &results[sample][k];
            if entry.detection_name != detection.detection_name
                || entry.detection_score != detection.detection_score
            {
                return Err(refuse(format!(
                    "sample {sample}, box {k}: a {} of score {} against the results' {} of score {}: the files are of two runs",
                    entry.detection_name,
                    entry.detection_score,
                    detection.detection_name,
                    detection.detection_score
                )));
            }
            if entry
                .modes
                .iter()
                .any(|m| m.positions.len() != steps || !m.probability.is_finite())
                || entry
                    .modes
                    .iter()
                    .flat_map(|m| &m.positions)
                    .flatten()
                    .any(|v| !v.is_finite())
            {
                return Err(refuse(format!(
                    "sample {sample}, box {k}: every mode needs {steps} finite positions and a finite probability"
                )));
            }
        }
    }
    if steps == 0 {
        bail!("--trajectories {}: no box has a trajectory", path.display());
    }
    let motion = MotionConfig {
        modes: 0,
        steps,
        interval_s: file.interval_s,
    };
    let mut classes: Vec<String> = keyframes
        .iter()
        .flat_map(|f| &f.boxes)
        .filter_map(|b| bevworld_types::detection_name_of(&b.category))
        .map(str::to_string)
        .collect();
    classes.sort();
    classes.dedup();
    let mut scenes: HashMap<&str, Vec<&SensorFrame>> = HashMap::new();
    for frame in keyframes {
        scenes
            .entry(frame.scene_name.as_str())
            .or_default()
            .push(frame);
    }
    let mut frames = Vec::new();
    let mut detections = Vec::new();
    for scene in scenes.values_mut() {
        scene.sort_by_key(|f| f.time_of_validity_us);
        for (k, frame) in scene.iter().enumerate() {
            let later: Vec<&SensorFrame> = scene[k + 1..].iter().take(steps).copied().collect();
            let agents = agents_of(&classes, &motion, frame, &later);
            let boxes = results
                .get(&frame.sample_token)
                .map(Vec::as_slice)
                .unwrap_or(&[]);
            let modes = file
                .samples
                .get(&frame.sample_token)
                .map(Vec::as_slice)
                .unwrap_or(&[]);
            detections.push(
                boxes
                    .iter()
                    .enumerate()
                    .map(|(i, d)| {
                        in_ego_frame(d, modes.get(i).map_or(&[][..], |m| &m.modes), frame)
                    })
                    .collect::<Vec<_>>(),
            );
            frames.push(LabelledFrame {
                sample_token: frame.sample_token.clone(),
                scene: frame.scene_name.clone(),
                time_us: frame.time_of_validity_us,
                global_from_ego: frame.global_from_ego,
                map: Vec::new(),
                previous: None,
                agents,
            });
        }
    }
    let frame_refs: Vec<&LabelledFrame> = frames.iter().collect();
    let detection_refs: Vec<&Vec<DetectedAgent>> = detections.iter().collect();
    Ok(motion_scores(
        &classes,
        &motion,
        &frame_refs,
        &detection_refs,
    ))
}
