//! The tokenizer's decoder: the latent lifted to voxel features, and the CNN that upsamples
//! rendered camera features to RGB.

pub mod rgb_upsampler;
pub mod voxel_lift;

pub use rgb_upsampler::{RgbUpsampler, RgbUpsamplerConfig};
pub use voxel_lift::{VoxelLift, VoxelLiftConfig, blocks_to_voxels};
