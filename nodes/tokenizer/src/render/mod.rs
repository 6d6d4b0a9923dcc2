//! NeRF-style rendering of the voxel field: trilinear sampling along rays and log-space
//! volume rendering weights.

pub mod batched;
pub mod field;
pub mod march;
pub mod occupancy;
pub mod rays;
pub mod rendered;
pub mod skipping;
pub mod trilinear;
pub mod volume;

pub use batched::{VoxelScene, camera_images};
pub use field::{FieldShape, VoxelField};
pub use march::{AlphaHead, March};
pub use occupancy::{OccupancyGrid, SkipOptions, Skipping};
pub use rendered::RenderedRays;
pub use trilinear::sample_trilinear;
pub use volume::{expected_depth, expected_feature, log_transmittance_after, render_weights};
