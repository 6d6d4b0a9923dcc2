//! Frames prepared for training and validation: everything a step needs, as host arrays, so
//! that a step never decodes images or pillarises. A synthetic set named in the config is
//! generated first when its folder does not exist.

use std::path::Path;

use bevworld_pillarize::{Limits, Pillarizer, ego_points_into};
use bevworld_sensors::source::parse_size;
use bevworld_sensors::synth::{SynthConfig, generate_in_place, scene_name};
use bevworld_sensors::{Dataset, DatasetOptions};

use crate::frame_input::{EncoderArrays, FrameInputs, FrameRays, InputError};
use crate::render::rays::Rays;
use crate::train::config::SynthSet;

#[derive(Debug, thiserror::Error)]
pub enum DataError {
    #[error("dataset {path}: {message}")]
    Dataset { path: String, message: String },
    #[error("dataset {path}, frame {index}: {source}")]
    Frame {
        path: String,
        index: usize,
        source: InputError,
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
    /// The scene's returns (off the ego vehicle, see `EgoBody`) in the ego frame, for Chamfer.
    pub lidar_points: Vec<[f32; 3]>,
}

/// Makes `set` with the synthetic world unless its folder exists. The folder, found or made,
/// must hold exactly the set's scenes: one made for another seed range would silently change
/// what a run trains or validates on.
pub fn ensure_synthetic(set: &SynthSet) -> Result<(), DataError> {
    let error = |message: String| DataError::Dataset {
        path: set.dir.display().to_string(),
        message,
    };
    if !set.dir.exists() {
        let (camera_width, camera_height) = parse_size(&set.camera_size)
            .map_err(|message| error(format!("camera_size: {message}")))?;
        let config = SynthConfig {
            seed: set.seed,
            scenes: set.scenes,
            seconds: set.seconds,
            camera_width,
            camera_height,
            ..Default::default()
        };
        // Another run may make a set in the same folder at once: `generate_in_place` keeps
        // whichever copy lands first, and the check below holds it to this config's scenes.
        generate_in_place(&set.dir, &config, |_, _| {}).map_err(|e| error(e.to_string()))?;
    }
    let dataset =
        Dataset::open(&set.dir, &DatasetOptions::default()).map_err(|e| error(e.to_string()))?;
    let mut held: Vec<&str> = dataset.scene_names();
    held.dedup();
    let wanted: Vec<String> = (0..set.scenes as u64)
        .map(|k| scene_name(set.seed + k))
        .collect();
    if held != wanted {
        return Err(error(format!(
            "holds {} scene(s) ({}), but the config's set is {} scene(s) from seed {} ({}): \
             remove the folder to make it anew, or give the set another `dir`",
            held.len(),
            span(&held),
            set.scenes,
            set.seed,
            span(&wanted),
        )));
    }
    Ok(())
}

/// "first … last" of a list of scene names, or the one name.
fn span<S: AsRef<str>>(names: &[S]) -> String {
    match (names.first(), names.last()) {
        (Some(first), Some(last)) if names.len() > 1 => {
            format!("{} … {}", first.as_ref(), last.as_ref())
        }
        (Some(only), _) => only.as_ref().to_string(),
        _ => "none".into(),
    }
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
            source,
        };
        let encoder = inputs
            .encoder_arrays(&frame, &pillars)
            .map_err(frame_error)?;
        let rays = inputs.frame_rays(&frame).map_err(frame_error)?;
        let inside: Vec<usize> = (0..rays.lidar.len())
            .filter(|&i| (near..=far).contains(&rays.lidar_ranges[i]))
            .filter(|&i| !render.escape_at_far || in_box(&rays.lidar, i, rays.lidar_ranges[i]))
            .collect();
        frames.push(TrainingFrame {
            token: frame.frame_token.clone(),
            encoder,
            lidar: rays.lidar.subset(&inside),
            lidar_ranges: inside.iter().map(|&i| rays.lidar_ranges[i]).collect(),
            lidar_points: frame.lidar.scene_ego_points(),
            rays,
        });
        progress(index + 1, count);
    }
    Ok(frames)
}
