//! Frames prepared for training and validation: everything a step needs, as host arrays, so
//! that a step never decodes images or pillarises. The model crate knows nothing of datasets;
//! this is where a dataset's frames become its inputs.

use std::path::Path;

use crate::config::{LidarDraw, RayConfig};
use bevworld_metrics::agents::{BOX_LIFT_M, BOX_MARGIN_M, vehicles_in_ego_frame};
use bevworld_pillarize::{Limits, Pillarizer, ego_points_into};
use bevworld_sensors::{Dataset, DatasetOptions};
use bevworld_tokenizer::render::rays::Rays;
use bevworld_tokenizer::{EncoderArrays, FrameInputs, FrameRays, InputError};
use bevworld_types::{PointClass, SensorFrame, SplitMix64, classify_point};
use glam::DVec3;

#[derive(Debug, thiserror::Error)]
pub enum DataError {
    #[error("dataset {path}: {message}")]
    Dataset { path: String, message: String },
    #[error("dataset {path}, frame {index}: {source}")]
    Frame {
        path: String,
        index: usize,
        source: Box<InputError>,
    },
}

/// One frame, ready for a step.
#[derive(Clone, Debug)]
pub struct TrainingFrame {
    pub token: String,
    pub encoder: EncoderArrays,
    pub rays: FrameRays,
    /// LiDAR rays whose range lies inside the rendered `[near, far]` (and, with
    /// `render.escape_at_far`, whose return lies inside the voxel box), and those ranges.
    pub lidar: Rays,
    pub lidar_ranges: Vec<f32>,
    /// The indices into `lidar` of the returns on an annotated vehicle (inside its box, grown
    /// as the agent scores grow it), in order: what `rays.lidar_vehicle_share` draws from.
    /// Empty for a frame without annotations.
    pub lidar_on_vehicles: Vec<usize>,
    /// The scene's returns (off the ego vehicle, see `EgoBody`) in the ego frame, for Chamfer.
    pub lidar_points: Vec<[f32; 3]>,
}

/// Prepares up to `limit` keyframes of the dataset at `dir`.
pub fn load_frames(
    dir: &Path,
    inputs: &FrameInputs,
    limit: usize,
    mut progress: impl FnMut(usize, usize),
) -> Result<Vec<TrainingFrame>, DataError> {
    let shown = dir.display().to_string();
    let dataset =
        Dataset::open(dir, &DatasetOptions::default()).map_err(|e| DataError::Dataset {
            path: shown.clone(),
            message: e.to_string(),
        })?;
    let count = dataset.len().min(limit);
    if count == 0 {
        return Err(DataError::Dataset {
            path: shown,
            message: "holds no frames".into(),
        });
    }
    let render = &inputs.config().render;
    let (near, far) = (render.near as f32, render.far as f32);
    let bev = &inputs.config().bev;
    // Whether ray i's return (ego frame) lies inside the voxel box.
    let in_box = |rays: &Rays, i: usize, range: f32| {
        let (o, d) = (rays.origins[i], rays.directions[i]);
        [bev.x_range, bev.y_range, bev.z_range]
            .iter()
            .enumerate()
            .all(|(axis, r)| (r[0]..r[1]).contains(&f64::from(o[axis] + range * d[axis])))
    };
    let mut pillarizer = Pillarizer::new(inputs.pillar_grid(), Limits::default());
    let mut points = Vec::new();
    let mut frames = Vec::with_capacity(count);
    for index in 0..count {
        let frame = dataset.read(index).map_err(|e| DataError::Dataset {
            path: shown.clone(),
            message: format!("frame {index}: {e}"),
        })?;
        ego_points_into(&frame.lidar, &mut points);
        let pillars = pillarizer.run(&points);
        let frame_error = |source| DataError::Frame {
            path: shown.clone(),
            index,
            source: Box::new(source),
        };
        let encoder = inputs
            .encoder_arrays(&frame, &pillars)
            .map_err(frame_error)?;
        let rays = inputs.frame_rays(&frame).map_err(frame_error)?;
        let inside: Vec<usize> = (0..rays.lidar.len())
            .filter(|&i| (near..=far).contains(&rays.lidar_ranges[i]))
            .filter(|&i| !render.escape_at_far || in_box(&rays.lidar, i, rays.lidar_ranges[i]))
            .collect();
        let lidar = rays.lidar.subset(&inside);
        let lidar_ranges: Vec<f32> = inside.iter().map(|&i| rays.lidar_ranges[i]).collect();
        frames.push(TrainingFrame {
            token: frame.frame_token.clone(),
            encoder,
            lidar_on_vehicles: on_vehicles(&frame, &lidar, &lidar_ranges),
            lidar,
            lidar_ranges,
            lidar_points: frame.lidar.scene_ego_points(),
            rays,
        });
        progress(index + 1, count);
    }
    Ok(frames)
}

/// The LiDAR rays of one frame for one step, as indices into `frame.lidar`: a share
/// (`rays.lidar_vehicle_share`, as many as there are) uniformly from the returns on vehicles,
/// the rest by `rays.lidar_draw` from every return. A ray can be drawn by both: it then
/// counts twice, as a heavier weight would count it.
pub fn draw_lidar(rng: &mut SplitMix64, frame: &TrainingFrame, rays: &RayConfig) -> Vec<usize> {
    let on_vehicles = &frame.lidar_on_vehicles;
    let from_vehicles = ((rays.lidar_rays as f64 * rays.lidar_vehicle_share).round() as usize)
        .min(on_vehicles.len());
    let count = rays.lidar_rays - from_vehicles;
    let mut chosen = match rays.lidar_draw {
        LidarDraw::Uniform => rng.choose(frame.lidar.len(), count),
        LidarDraw::ByRange => rng.choose_weighted(&frame.lidar_ranges, count),
    };
    // After the base draw, and only when there is one, so that a share of 0 leaves the run's
    // random stream as it was.
    if from_vehicles > 0 {
        chosen.extend(
            rng.choose(on_vehicles.len(), from_vehicles)
                .into_iter()
                .map(|k| on_vehicles[k]),
        );
    }
    chosen
}

/// The indices of the rays whose return (origin + range · direction, in the frame's LiDAR-time
/// ego frame) lies on one of the frame's annotated vehicles, moving or parked, by the same
/// boxes and margins as the agent scores (`bevworld_metrics::agents`).
pub fn on_vehicles(frame: &SensorFrame, rays: &Rays, ranges: &[f32]) -> Vec<usize> {
    let vehicles = vehicles_in_ego_frame(frame);
    if vehicles.is_empty() {
        return Vec::new();
    }
    (0..rays.len())
        .filter(|&i| {
            let (origin, direction) = (rays.origins[i], rays.directions[i]);
            let at = DVec3::from_array(std::array::from_fn(|axis| {
                f64::from(origin[axis] + ranges[i] * direction[axis])
            }));
            classify_point(&vehicles, at, BOX_MARGIN_M, BOX_LIFT_M) != PointClass::Static
        })
        .collect()
}
