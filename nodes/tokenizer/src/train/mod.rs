//! Training the tokenizer: configs, prepared frames, losses, the optimiser loop with global-norm
//! clipping, atomic checkpoints that resume exactly, validation, and the run's metrics log.

pub mod checkpoint;
pub mod clip;
pub mod config;
pub mod data;
pub mod discriminator;
pub mod distortion;
pub mod ema;
pub mod glyphs;
pub mod losses;
pub mod metrics_log;
pub mod perceptual;
pub mod plot;
pub mod replica;
pub mod rng;
pub mod schedule;
pub mod termination;
pub mod trainer;

pub use config::{LidarDraw, LossWeights, TrainConfig};
pub use trainer::{StepReport, TrainError, Trainer, ValidationReport};
