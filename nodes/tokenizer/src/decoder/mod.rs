//! The tokenizer's decoder: the latent lifted to voxel features, the background seen beyond
//! the grid, and the CNN that upsamples rendered camera features to RGB.

pub mod background;
pub mod rgb_upsampler;
pub mod voxel_lift;

pub use background::{Background, BackgroundConfig};
pub use rgb_upsampler::{RgbUpsampler, RgbUpsamplerConfig};
pub use voxel_lift::{VoxelLift, VoxelLiftConfig};
