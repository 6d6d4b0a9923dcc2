//! The multi-modal BEV tokenizer of BEVWorld, as Burn modules: Swin backbones for the cameras
//! and the LiDAR BEV, and the NeRF-style renderer that turns voxel features back into images
//! and depths.

pub mod render;
pub mod swin;
