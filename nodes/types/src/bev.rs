//! Dense BEV features on a grid over the ego frame: what detection and motion heads consume,
//! whether they come from pillar statistics or from the tokenizer's latent.

use serde::{Deserialize, Serialize};

use crate::pose::Pose;

/// Where a product came from in the dataset.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct FrameMeta {
    pub sample_token: String,
    /// Unique per frame (see `SensorFrame::frame_token`).
    pub frame_token: String,
    pub scene_name: String,
    pub time_of_validity_us: i64,
    pub global_from_ego: Pose,
    /// The sample's own sweep (`SensorFrame::keyframe`).
    pub keyframe: bool,
}

/// The grid a BEV feature map covers.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct BevGrid {
    pub x_range: [f32; 2],
    pub y_range: [f32; 2],
    /// Metres per cell.
    pub resolution: f32,
    /// Cells along y (rows) and x (columns).
    pub height: usize,
    pub width: usize,
}

/// A `[C, H, W]` feature map; row i, column j covers y in `y_range[0] + i * resolution` and
/// x in `x_range[0] + j * resolution`.
#[derive(Clone, Debug)]
pub struct BevFeatures {
    pub meta: FrameMeta,
    pub grid: BevGrid,
    /// What each channel means, in order.
    pub channels: Vec<String>,
    pub data: Vec<f32>,
    /// The producing model's name and a hash of its weights ("none" for weight-free products).
    pub model: String,
    pub weights_hash: String,
}
