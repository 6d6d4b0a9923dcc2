//! NeRF-style rendering of the voxel field: trilinear sampling along rays and log-space
//! volume rendering weights.

pub mod rays;
pub mod trilinear;
pub mod volume;

pub use trilinear::sample_trilinear;
pub use volume::{expected_depth, expected_feature, log_transmittance_after, render_weights};
