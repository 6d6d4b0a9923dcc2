//! Sensor sources: dataset readers and the graph node that replays them.

// Libraries return errors; a panic belongs to a broken invariant, said with `expect`.
#![cfg_attr(not(test), warn(clippy::unwrap_used))]

pub mod dataset;
pub mod error;
pub mod image_file;
pub mod inspect;
pub mod kitti;
pub mod lidar_file;
pub mod nuscenes;
pub mod real_data;
pub mod source;
pub mod synth;

pub use dataset::{Dataset, DatasetFormat, DatasetOptions};
pub use error::SensorError;
pub use lidar_file::NonFinitePolicy;
pub use real_data::{data_root, real_dataset};

/// Registers this family's node kinds.
pub fn register(registry: &mut bevworld_graph::Registry) {
    source::register(registry);
}
