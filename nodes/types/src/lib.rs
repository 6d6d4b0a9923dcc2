//! The domain types every node shares: frames, calibration, poses, point clouds and ego actions.
//!
//! Transforms are named `a_from_b`: they map coordinates in frame `b` to frame `a`, so products
//! read right to left: `global_from_lidar = global_from_ego * ego_from_lidar`. Global poses are
//! f64 (nuScenes coordinates reach kilometres, where f32 loses centimetres).

pub mod action;
pub mod bev;
pub mod camera;
pub mod ego_body;
pub mod frame;
pub mod pillars;
pub mod point_cloud;
pub mod pose;

pub use action::EgoAction;
pub use bev::{BevFeatures, BevGrid, FrameMeta};
pub use camera::{CameraChannel, CameraImage, ImageSet, Intrinsics, NamedImage};
pub use ego_body::EgoBody;
pub use frame::SensorFrame;
pub use pillars::{PILLAR_FEATURES, PillarGrid, PillarStats, Pillars};
pub use point_cloud::{LidarPoint, PointCloud};
pub use pose::{Pose, pose_from_translation_quaternion};
