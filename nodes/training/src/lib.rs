//! Training machinery that knows no model: the learning-rate schedule and AdamW settings,
//! global-norm clipping, the moving average of the weights, atomic checkpoints that resume
//! bit for bit (with the run's generator, `bevworld_types::SplitMix64`), data-parallel
//! replicas with gradients summed in a fixed order, the metrics log, its curves, and the loop
//! that ties them together.
//!
//! A model's trainer implements `Trainee` (one step, validation, a checkpoint) and keeps only
//! what is its own: its data, its losses and its scores.

// Libraries return errors; a panic belongs to a broken invariant, said with `expect`.
#![cfg_attr(not(test), warn(clippy::unwrap_used))]

pub mod checkpoint;
pub mod clip;
pub mod curves;
pub mod ema;
pub mod metrics_log;
pub mod optimizer;
pub mod parallel;
pub mod run;
pub mod schedule;

pub use bevworld_types::ConfigProblem;
pub use bevworld_types::problem::{require_count, require_non_negative, require_positive};
pub use checkpoint::{CheckpointError, CheckpointFiles, CheckpointState};
pub use clip::{
    NonFiniteGradient, Part, apply_gradients, apply_gradients_in_two, clip_global_norm, global_norm,
};
pub use curves::{Curve, plot_curves};
pub use metrics_log::{MetricsLog, Row};
pub use optimizer::OptimizerConfig;
pub use parallel::{WorkerPanicked, parallel_map, replica, sum_in_order};
pub use run::{LoopPlan, Observer, Scores, StepReport, Trainee, Validation, run_loop};
