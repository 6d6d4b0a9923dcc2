//! Scoring a detector on a set: its boxes with the nuScenes detection metrics (the devkit's,
//! `bevworld_metrics::detection`), and its trajectories as the paper scores motion, through
//! the detections: each true agent whose whole future is annotated is matched to the best
//! detection of its class within 2 m, and its minADE and minFDE over the K modes are taken,
//! beside a constant-velocity extrapolation of the same detected box.

use std::collections::BTreeMap;

use bevworld_heads::{Detector, DetectorConfig, FrameMaps, InputSpec, MotionConfig, PosedMap};
use bevworld_metrics::detection::{DetectionConfig, DetectionScores, EvaluationError, evaluate};
use bevworld_metrics::report_file::population_std;
use bevworld_training::{WorkerPanicked, parallel_map};
use bevworld_types::{DetectedAgent, Detection};
use burn::prelude::*;
use serde::Serialize;

use crate::data::{DetectionSet, LabelledFrame};

/// How far a detection may be from a true agent to carry its motion, m (the devkit's 2 m
/// centre-distance threshold).
pub const MATCH_DISTANCE_M: f64 = 2.0;
/// A forecast whose final point misses by more than this misses, m.
pub const MISS_DISTANCE_M: f64 = 2.0;

/// Frames per forward pass when predicting.
const PREDICT_BATCH: usize = 4;

/// Every frame's detections, in the set's order.
pub fn predict(
    model: &Detector,
    config: &DetectorConfig,
    input: &InputSpec,
    set: &DetectionSet,
    threads: usize,
    device: &Device,
) -> Result<Vec<Vec<DetectedAgent>>, WorkerPanicked> {
    let chunks: Vec<Vec<usize>> = (0..set.frames.len())
        .collect::<Vec<_>>()
        .chunks(PREDICT_BATCH)
        .map(<[usize]>::to_vec)
        .collect();
    let output_grid = config.output_grid(input);
    let per_chunk = parallel_map(
        &chunks,
        threads,
        || model.clone(),
        |model, chunk| {
            let tensor = input_batch(input, &set.frames, chunk, device);
            let outputs = model.forward(tensor);
            let values = |t: Tensor<4>| t.into_data().try_to_vec::<f32>().unwrap_or_default();
            let (heat, boxes, motion) = (
                values(outputs.heatmap),
                values(outputs.boxes),
                values(outputs.motion),
            );
            let plane = output_grid.height * output_grid.width;
            let (c_heat, c_box, c_motion) = (
                config.classes.len() * plane,
                bevworld_heads::BOX_CHANNELS * plane,
                config.motion_channels() * plane,
            );
            (0..chunk.len())
                .map(|b| {
                    let maps = FrameMaps {
                        heatmap: heat.get(b * c_heat..(b + 1) * c_heat).unwrap_or(&[]),
                        boxes: boxes.get(b * c_box..(b + 1) * c_box).unwrap_or(&[]),
                        motion: motion.get(b * c_motion..(b + 1) * c_motion).unwrap_or(&[]),
                    };
                    config.decode(&output_grid, &maps)
                })
                .collect::<Vec<_>>()
        },
    )?;
    Ok(per_chunk.into_iter().flatten().collect())
}

/// The input tensor `[N, C·F, H, W]` of `frames[indices]`.
pub fn input_batch(
    input: &InputSpec,
    frames: &[LabelledFrame],
    indices: &[usize],
    device: &Device,
) -> Tensor<4> {
    let mut values = Vec::with_capacity(indices.len() * input.frame_len() * input.frames);
    for &i in indices {
        let frame = &frames[i];
        let current = PosedMap {
            values: &frame.map,
            global_from_ego: frame.global_from_ego,
        };
        let previous = frame.previous.map(|p| PosedMap {
            values: &frames[p].map,
            global_from_ego: frames[p].global_from_ego,
        });
        // The maps were checked when the set was read.
        let assembled = input
            .assemble(&current, previous.as_ref())
            .expect("maps checked on load");
        values.extend(assembled);
    }
    Tensor::from_data(
        TensorData::new(
            values,
            [
                indices.len(),
                input.channels * input.frames,
                input.grid.height,
                input.grid.width,
            ],
        ),
        device,
    )
}

/// The detections as the submission format keys them, every frame present.
pub fn results_of(
    set: &DetectionSet,
    detections: &[Vec<DetectedAgent>],
) -> BTreeMap<String, Vec<Detection>> {
    set.frames
        .iter()
        .zip(detections)
        .map(|(frame, agents)| {
            (
                frame.sample_token.clone(),
                agents
                    .iter()
                    .map(|a| a.to_detection(&frame.sample_token, &frame.global_from_ego))
                    .collect(),
            )
        })
        .collect()
}

/// Motion scores over the matched agents.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct MotionScores {
    /// True agents with a whole annotated future, and how many a detection matched.
    pub agents: usize,
    pub matched: usize,
    pub min_ade: f64,
    pub min_fde: f64,
    pub miss_rate: f64,
    /// The same for a constant-velocity extrapolation of the matched box.
    pub constant_velocity_ade: f64,
    pub constant_velocity_fde: f64,
    pub constant_velocity_miss_rate: f64,
}

/// Per matched agent: (minADE, minFDE) of the modes and of constant velocity.
fn motion_errors(
    classes: &[String],
    motion: &MotionConfig,
    frame: &LabelledFrame,
    agents: &[DetectedAgent],
) -> (usize, Vec<[f64; 4]>) {
    let steps = motion.steps;
    let whole: Vec<(usize, Vec<[f64; 2]>)> = frame
        .agents
        .iter()
        .enumerate()
        .filter_map(|(i, truth)| {
            let future: Option<Vec<[f64; 2]>> = truth.future.iter().take(steps).copied().collect();
            future.filter(|f| f.len() == steps).map(|f| (i, f))
        })
        .collect();
    let mut order: Vec<usize> = (0..agents.len()).collect();
    order.sort_by(|&a, &b| agents[b].score.total_cmp(&agents[a].score));
    let mut taken = vec![false; whole.len()];
    let mut errors = Vec::new();
    for d in order {
        let detected = &agents[d];
        let best = whole
            .iter()
            .enumerate()
            .filter(|(k, (i, _))| {
                !taken[*k] && classes[frame.agents[*i].class] == detected.detection_name
            })
            .map(|(k, (i, _))| {
                let c = frame.agents[*i].centre;
                (
                    k,
                    (c[0] - detected.centre[0]).hypot(c[1] - detected.centre[1]),
                )
            })
            .filter(|(_, distance)| *distance < MATCH_DISTANCE_M)
            .min_by(|a, b| a.1.total_cmp(&b.1));
        let Some((k, _)) = best else { continue };
        taken[k] = true;
        let future = &whole[k].1;
        let distances = |positions: &[[f64; 2]]| -> (f64, f64) {
            let d: Vec<f64> = positions
                .iter()
                .zip(future)
                .map(|(p, t)| (p[0] - t[0]).hypot(p[1] - t[1]))
                .collect();
            (
                d.iter().sum::<f64>() / d.len().max(1) as f64,
                d.last().copied().unwrap_or(0.0),
            )
        };
        let (mut ade, mut fde) = (f64::INFINITY, f64::INFINITY);
        for mode in &detected.modes {
            let (a, f) = distances(&mode.positions);
            ade = ade.min(a);
            fde = fde.min(f);
        }
        let constant: Vec<[f64; 2]> = (1..=steps)
            .map(|s| {
                let t = s as f64 * motion.interval_s;
                [
                    detected.centre[0] + detected.velocity[0] * t,
                    detected.centre[1] + detected.velocity[1] * t,
                ]
            })
            .collect();
        let (cv_ade, cv_fde) = distances(&constant);
        errors.push([ade, fde, cv_ade, cv_fde]);
    }
    (whole.len(), errors)
}

/// Motion scores of `detections` on `frames`, whose agents' classes index `classes`.
pub fn motion_scores(
    classes: &[String],
    motion: &MotionConfig,
    frames: &[&LabelledFrame],
    detections: &[&Vec<DetectedAgent>],
) -> MotionScores {
    let mut agents = 0;
    let mut errors = Vec::new();
    for (frame, detected) in frames.iter().zip(detections) {
        let (count, frame_errors) = motion_errors(classes, motion, frame, detected);
        agents += count;
        errors.extend(frame_errors);
    }
    // No matched agent: no figure (NaN, null in JSON), not a perfect one.
    let n = errors.len() as f64;
    let mean = |k: usize| errors.iter().map(|e| e[k]).sum::<f64>() / n;
    let misses = |k: usize| errors.iter().filter(|e| e[k] > MISS_DISTANCE_M).count() as f64 / n;
    MotionScores {
        agents,
        matched: errors.len(),
        min_ade: mean(0),
        min_fde: mean(1),
        miss_rate: misses(1),
        constant_velocity_ade: mean(2),
        constant_velocity_fde: mean(3),
        constant_velocity_miss_rate: misses(3),
    }
}

/// A detector's scores on a set: over all its frames, and the spread of each scene's.
#[derive(Clone, Debug, Serialize)]
pub struct Evaluation {
    pub frames: usize,
    pub detection: DetectionScores,
    pub motion: MotionScores,
    /// Per scene: NDS, mAP, minADE.
    pub scenes: BTreeMap<String, [f64; 3]>,
    /// Population standard deviations of the per-scene NDS, mAP and minADE.
    pub scene_spread: [f64; 3],
}

impl Evaluation {
    /// Metrics-log columns.
    pub fn as_scores(&self) -> Vec<(&'static str, Option<f64>)> {
        let d = &self.detection;
        let finite = |v: f64| v.is_finite().then_some(v);
        let tp = |name: &str| d.tp_errors.get(name).copied().and_then(finite);
        vec![
            ("nds", finite(d.nd_score)),
            ("map", finite(d.mean_ap)),
            ("mate", tp("trans_err")),
            ("mase", tp("scale_err")),
            ("maoe", tp("orient_err")),
            ("mave", tp("vel_err")),
            ("maae", tp("attr_err")),
            ("min_ade", finite(self.motion.min_ade)),
            ("min_fde", finite(self.motion.min_fde)),
            ("miss_rate", finite(self.motion.miss_rate)),
            ("cv_ade", finite(self.motion.constant_velocity_ade)),
            ("cv_fde", finite(self.motion.constant_velocity_fde)),
        ]
    }
}

/// Scores `detections` (one list per frame of `set`) on the detector's classes.
pub fn evaluate_set(
    config: &DetectorConfig,
    set: &DetectionSet,
    detections: &[Vec<DetectedAgent>],
) -> Result<Evaluation, EvaluationError> {
    let classes: Vec<&str> = config.classes.iter().map(String::as_str).collect();
    let metric_config = DetectionConfig::for_classes(&classes);
    let results = results_of(set, detections);
    let detection = evaluate(&metric_config, &set.truth, &results)?;
    let all_frames: Vec<&LabelledFrame> = set.frames.iter().collect();
    let all_detections: Vec<&Vec<DetectedAgent>> = detections.iter().collect();
    let motion = motion_scores(
        &config.classes,
        &config.motion,
        &all_frames,
        &all_detections,
    );
    let mut scenes = BTreeMap::new();
    let mut names: Vec<&String> = set.frames.iter().map(|f| &f.scene).collect();
    names.dedup();
    for scene in names {
        let picked: Vec<usize> = (0..set.frames.len())
            .filter(|&i| &set.frames[i].scene == scene)
            .collect();
        let truth = picked
            .iter()
            .filter_map(|&i| {
                let token = &set.frames[i].sample_token;
                set.truth.get(token).map(|t| (token.clone(), t.clone()))
            })
            .collect();
        let scene_results = picked
            .iter()
            .filter_map(|&i| {
                let token = &set.frames[i].sample_token;
                results.get(token).map(|r| (token.clone(), r.clone()))
            })
            .collect();
        let scores = evaluate(&metric_config, &truth, &scene_results)?;
        let frames: Vec<&LabelledFrame> = picked.iter().map(|&i| &set.frames[i]).collect();
        let scene_detections: Vec<&Vec<DetectedAgent>> =
            picked.iter().map(|&i| &detections[i]).collect();
        let scene_motion =
            motion_scores(&config.classes, &config.motion, &frames, &scene_detections);
        scenes.insert(
            scene.clone(),
            [scores.nd_score, scores.mean_ap, scene_motion.min_ade],
        );
    }
    let spread = |k: usize| {
        let values: Vec<f64> = scenes.values().map(|s| s[k]).collect();
        population_std(&values).unwrap_or(0.0)
    };
    Ok(Evaluation {
        frames: set.frames.len(),
        scene_spread: [spread(0), spread(1), spread(2)],
        detection,
        motion,
        scenes,
    })
}
