//! What the detector learns from: the keyframes of an annotated set, each with its exported
//! map (the same files and `index.json` a user exports) and its agents in its own ego frame,
//! each agent with its future centre at the motion head's steps, from the same instance's
//! later annotations.
//!
//! - Every map must come from one model and weights digest, on one grid; a map with a
//!   non-finite value is refused naming its file.
//! - A keyframe without a map, or a map of a sample the dataset does not have, is refused: a
//!   set scored on fewer frames than it claims is not the set.
//! - Agents without a LiDAR return are not learnt (the metrics do not score them either).

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};

use bevworld_heads::{AgentTruth, DetectorConfig, MotionConfig};
use bevworld_metrics::detection::{SampleTruth, sample_truth};
use bevworld_sensors::{Dataset, DatasetOptions};
use bevworld_sinks::export_index::{ExportIndexError, read_export_index};
use bevworld_types::detection::detection_name_of;
use bevworld_types::pose::yaw_of;
use bevworld_types::{BevGrid, ObjectBox, Pose, SensorFrame};
use glam::DVec3;

/// The export's index file in each input's folder.
pub const INDEX: &str = "index.json";

#[derive(Debug, thiserror::Error)]
pub enum DataError {
    #[error(transparent)]
    Export(#[from] ExportIndexError),
    #[error("{path}: {message}")]
    Invalid { path: PathBuf, message: String },
    #[error("{path}: {message}")]
    Dataset { path: PathBuf, message: String },
    #[error("keyframe {sample}: {message}")]
    Keyframe { sample: String, message: String },
}

/// One keyframe.
#[derive(Clone, Debug)]
pub struct LabelledFrame {
    pub sample_token: String,
    pub scene: String,
    pub time_us: i64,
    pub global_from_ego: Pose,
    /// The exported map, `[C, H, W]`, as written.
    pub map: Vec<f32>,
    /// The scene's previous keyframe, an index into the set's frames.
    pub previous: Option<usize>,
    pub agents: Vec<AgentTruth>,
}

/// A set's keyframes and what the metrics score them against.
#[derive(Clone)]
pub struct DetectionSet {
    pub frames: Vec<LabelledFrame>,
    /// Every keyframe's truth for the detection metrics, by sample token.
    pub truth: BTreeMap<String, SampleTruth>,
    /// The model and weights digest that made the maps, and their grid and channels.
    pub model: String,
    pub weights_hash: String,
    pub grid: BevGrid,
    pub channels: usize,
}

/// A keyframe's agents of `classes` (detection names; `AgentTruth::class` indexes them), in
/// its ego frame, with their futures at `motion`'s steps from `later` (the scene's next
/// keyframes, in order).
pub fn agents_of(
    classes: &[String],
    motion: &MotionConfig,
    frame: &SensorFrame,
    later: &[&SensorFrame],
) -> Vec<AgentTruth> {
    let ego_from_global = frame.global_from_ego.inverse();
    let interval_us = motion.interval_s * 1e6;
    frame
        .boxes
        .iter()
        .filter(|object| object.num_pts > 0)
        .filter_map(|object| {
            let name = detection_name_of(&object.category)?;
            let class = classes.iter().position(|c| c == name)?;
            let centre = ego_from_global.transform_point3(object.global_from_box.translation);
            let ego_from_box = ego_from_global * object.global_from_box;
            let velocity = object.velocity.map(|[vx, vy]| {
                let v = ego_from_global.transform_vector3(DVec3::new(vx, vy, 0.0));
                [v.x, v.y]
            });
            let future = (1..=motion.steps)
                .map(|step| {
                    let next = later.get(step - 1)?;
                    let gap_us = (next.time_of_validity_us - frame.time_of_validity_us) as f64;
                    // A step is the annotation `step` intervals on, within a fifth of one.
                    if (gap_us - step as f64 * interval_us).abs() > 0.2 * interval_us {
                        return None;
                    }
                    let same: &ObjectBox = next
                        .boxes
                        .iter()
                        .find(|b| b.instance_token == object.instance_token)?;
                    let p = ego_from_global.transform_point3(same.global_from_box.translation);
                    Some([p.x, p.y])
                })
                .collect();
            Some(AgentTruth {
                class,
                centre: centre.to_array(),
                size: object.size,
                yaw: yaw_of(&ego_from_box),
                velocity,
                future,
            })
        })
        .collect()
}

/// Reads the keyframes of `dataset` and their maps exported into `features`.
pub fn load_set(
    features: &Path,
    dataset: &Path,
    config: &DetectorConfig,
) -> Result<DetectionSet, DataError> {
    let index_path = features.join(INDEX);
    let invalid = |message: String| DataError::Invalid {
        path: index_path.clone(),
        message,
    };
    let entries = read_export_index(features, INDEX)?;
    let first = entries
        .first()
        .ok_or_else(|| invalid("lists no frame".into()))?;
    let grid = first.bev_grid().ok_or_else(|| {
        invalid(format!(
            "frame {} has no `grid` or a shape {:?} that is not [C, H, W]",
            first.frame_token, first.shape
        ))
    })?;
    let (model, weights_hash, shape) = (
        first.model.clone(),
        first.weights_hash.clone(),
        first.shape.clone(),
    );
    let mut maps: HashMap<String, Vec<f32>> = HashMap::new();
    for entry in &entries {
        if entry.model != model || entry.weights_hash != weights_hash {
            return Err(invalid(format!(
                "frame {} was made by '{}' with weights {}, frame {} by '{model}' with weights {weights_hash}: one export, one model",
                entry.frame_token, entry.model, entry.weights_hash, first.frame_token
            )));
        }
        if entry.shape != shape || entry.bev_grid() != Some(grid) {
            return Err(invalid(format!(
                "frame {} has shape {:?} on another grid than frame {}'s {shape:?}",
                entry.frame_token, entry.shape, first.frame_token
            )));
        }
        maps.insert(entry.sample_token.clone(), entry.read_values(features)?);
    }
    let options = DatasetOptions {
        skip_images: true,
        ..Default::default()
    };
    let (frames, truth) = read_keyframes(dataset, &options, config, |frame| {
        maps.remove(&frame.sample_token).ok_or_else(|| {
            invalid(format!(
                "has no map of keyframe {} (scene {}); export the set again into {}",
                frame.sample_token,
                frame.scene_name,
                features.display()
            ))
        })
    })?;
    if let Some((sample, _)) = maps.iter().next() {
        return Err(invalid(format!(
            "holds a map of sample {sample}, which {} does not have: features of another set",
            dataset.display()
        )));
    }
    Ok(DetectionSet {
        frames,
        truth,
        model,
        weights_hash,
        grid,
        channels: shape[0],
    })
}

/// A set's keyframes, scene by scene in time order, each with its agents and the map
/// `map_of` gives it (read from an export, or left for an encoder to make), and every
/// keyframe's truth for the detection metrics.
pub fn read_keyframes(
    dataset: &Path,
    options: &DatasetOptions,
    config: &DetectorConfig,
    mut map_of: impl FnMut(&SensorFrame) -> Result<Vec<f32>, DataError>,
) -> Result<(Vec<LabelledFrame>, BTreeMap<String, SampleTruth>), DataError> {
    let dataset_error = |message: String| DataError::Dataset {
        path: dataset.to_path_buf(),
        message,
    };
    let opened = Dataset::open(dataset, options).map_err(|e| dataset_error(e.to_string()))?;
    let mut keyframes = Vec::with_capacity(opened.len());
    for index in 0..opened.len() {
        keyframes.push(
            opened
                .read(index)
                .map_err(|e| dataset_error(e.to_string()))?,
        );
    }
    let mut by_scene: BTreeMap<String, Vec<usize>> = BTreeMap::new();
    for (i, frame) in keyframes.iter().enumerate() {
        by_scene
            .entry(frame.scene_name.clone())
            .or_default()
            .push(i);
    }
    let mut frames = Vec::with_capacity(keyframes.len());
    let mut truth = BTreeMap::new();
    for indices in by_scene.values_mut() {
        indices.sort_by_key(|&i| keyframes[i].time_of_validity_us);
        for (k, &i) in indices.iter().enumerate() {
            let frame = &keyframes[i];
            let map = map_of(frame)?;
            let later: Vec<&SensorFrame> = indices[k + 1..]
                .iter()
                .take(config.motion.steps)
                .map(|&j| &keyframes[j])
                .collect();
            let (sample, sample_truth) = sample_truth(frame).map_err(dataset_error)?;
            truth.insert(sample, sample_truth);
            frames.push(LabelledFrame {
                sample_token: frame.sample_token.clone(),
                scene: frame.scene_name.clone(),
                time_us: frame.time_of_validity_us,
                global_from_ego: frame.global_from_ego,
                map,
                previous: (k > 0).then(|| frames.len() - 1),
                agents: agents_of(&config.classes, &config.motion, frame, &later),
            });
        }
    }
    Ok((frames, truth))
}

impl DetectionSet {
    /// Per-channel mean and population standard deviation over every map (the deviation
    /// floored at 1e-6, so a constant channel standardises to 0, not to NaN).
    pub fn channel_statistics(&self) -> (Vec<f32>, Vec<f32>) {
        let plane = self.grid.height * self.grid.width;
        let mut sum = vec![0.0f64; self.channels];
        let mut square = vec![0.0f64; self.channels];
        for frame in &self.frames {
            for (c, values) in frame.map.chunks(plane).enumerate() {
                for &v in values {
                    sum[c] += f64::from(v);
                    square[c] += f64::from(v) * f64::from(v);
                }
            }
        }
        let n = (self.frames.len() * plane).max(1) as f64;
        let mean: Vec<f64> = sum.iter().map(|s| s / n).collect();
        let std = square
            .iter()
            .zip(&mean)
            .map(|(s, m)| ((s / n - m * m).max(0.0).sqrt()).max(1e-6) as f32)
            .collect();
        (mean.iter().map(|&m| m as f32).collect(), std)
    }
}
