//! The tokenizer's decoder: the latent lifted to voxel features.

pub mod voxel_lift;

pub use voxel_lift::{VoxelLift, VoxelLiftConfig, blocks_to_voxels};
