//! Evaluation metrics. Every claim about accuracy in this project rests on these.

pub mod chamfer;
pub mod fid;
pub mod frechet;
pub mod image;
pub mod inception;
pub mod reconstruction_node;
pub mod torch_weights;

pub use chamfer::{ChamferResult, Roi, chamfer, chamfer_in_roi};
pub use fid::{FidError, InceptionExtractor, load_inception};
pub use frechet::{FeatureExtractor, GaussianStats, frechet_distance};
pub use image::{Planes, psnr, rgb_planes, ssim};
pub use torch_weights::{TorchLoadError, load_torch_state_dict};

/// Registers this family's node kinds.
pub fn register(registry: &mut bevworld_graph::Registry) {
    reconstruction_node::register(registry);
}
