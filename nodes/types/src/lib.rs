//! The domain types every node shares: frames, calibration, poses, point clouds, ego actions,
//! the latent's statistics (the contract between the tokenizer and the world model), the
//! typed config problem every config check reports, and the one seeded generator
//! (`splitmix.rs`).
//!
//! Transforms are named `a_from_b`: they map coordinates in frame `b` to frame `a`, so products
//! read right to left: `global_from_lidar = global_from_ego * ego_from_lidar`. Global poses are
//! f64 (nuScenes coordinates reach kilometres, where f32 loses centimetres).

// Libraries return errors; a panic belongs to a broken invariant, said with `expect`.
#![cfg_attr(not(test), warn(clippy::unwrap_used))]

pub mod action;
pub mod agent_returns;
pub mod agent_track;
pub mod agent_warp;
pub mod bev;
pub mod bev_warp;
pub mod camera;
pub mod detected_agents;
pub mod detection;
pub mod digest;
pub mod ego_body;
pub mod forecast;
pub mod frame;
pub mod latent_stats;
pub mod latent_stats_file;
pub mod manoeuvre;
pub mod model_bundle;
pub mod object_box;
pub mod pillars;
pub mod point_cloud;
pub mod pose;
pub mod problem;
pub mod score_table;
pub mod splitmix;

pub use action::EgoAction;
pub use agent_returns::{
    DetectionsWithReturns, ReturnsRule, frame_returns, register_returns, returns_of,
    track_velocity_on_returns, velocities_on_returns,
};
pub use agent_track::{AgentTrack, TrackParams, TrackRule, track_agents};
pub use agent_warp::{AgentMotion, Footprint, move_agents};
pub use bev::{BevFeatures, BevGrid, FrameMeta};
pub use bev_warp::{LatentGrid, PlanarMotion, WarpTaps, taps_at, warp_latent, warp_taps};
pub use camera::{CameraChannel, CameraImage, ImageSet, Intrinsics, NamedImage};
pub use detected_agents::{DetectedAgent, FrameDetections, TrajectoryMode};
pub use detection::{Detection, DetectionResults, SubmissionMeta, detection_name_of};
pub use digest::{bytes_digest, file_digest};
pub use ego_body::EgoBody;
pub use forecast::{
    Forecast, ForecastHorizon, ForecastMethod, FutureView, LatentWindow, LoggedPose,
    RenderedFuture, virtual_frame,
};
pub use frame::SensorFrame;
pub use latent_stats::{
    LatentStats, LatentStatsAccumulator, LatentStatsError, mean_abs_difference,
};
pub use latent_stats_file::{LatentStatsFile, StatsFileError, stats_path_for};
pub use manoeuvre::Manoeuvre;
pub use model_bundle::{ModelBundle, TokenizerFiles, WorldModelFiles};
pub use object_box::{MOVING_SPEED_MPS, ObjectBox, PointClass, classify_point};
pub use pillars::{GridError, PILLAR_FEATURES, PillarGrid, PillarStats, Pillars};
pub use point_cloud::{LidarPoint, PointCloud};
pub use pose::{Pose, pose_from_translation_quaternion};
pub use problem::ConfigProblem;
pub use score_table::ScoreTable;
pub use splitmix::SplitMix64;
