//! Sensor sources: dataset readers and the graph node that replays them.

pub mod dataset;
pub mod error;
pub mod inspect;
pub mod kitti;
pub mod lidar_file;
pub mod nuscenes;
pub mod source;
pub mod synth;

pub use dataset::{Dataset, DatasetFormat, DatasetOptions};
pub use error::SensorError;
pub use lidar_file::NonFinitePolicy;

/// Registers this family's node kinds.
pub fn register(registry: &mut bevworld_graph::Registry) {
    source::register(registry);
}
