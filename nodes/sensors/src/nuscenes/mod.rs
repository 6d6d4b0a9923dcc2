//! The nuScenes dataset layout: `v1.0-*/` tables, `samples/` and `sweeps/`.

pub mod annotations;
pub mod reader;
pub mod tables;

pub use reader::{NuScenes, NuScenesOptions};
