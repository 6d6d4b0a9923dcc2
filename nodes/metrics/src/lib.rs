//! Evaluation metrics. Every claim about accuracy in this project rests on these.

// Libraries return errors; a panic belongs to a broken invariant, said with `expect`.
#![cfg_attr(not(test), warn(clippy::unwrap_used))]

pub mod agents;
pub mod best_of;
pub mod chamfer;
pub mod detection;
pub mod fid;
pub mod forecast_node;
pub mod frechet;
pub mod image;
pub mod inception;
pub mod reconstruction_node;
pub mod report_file;

pub use chamfer::{ChamferResult, Roi, chamfer, chamfer_in_roi};
pub use fid::{FidError, InceptionExtractor, load_inception};
pub use frechet::{FeatureExtractor, FrechetError, GaussianStats, frechet_distance};
pub use image::{ImageMetricError, Planes, psnr, rgb_planes, ssim};

/// Registers this family's node kinds.
pub fn register(registry: &mut bevworld_graph::Registry) {
    reconstruction_node::register(registry);
    forecast_node::register(registry);
}
