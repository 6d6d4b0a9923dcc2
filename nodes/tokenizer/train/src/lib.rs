//! Training the BEV tokenizer: its data (frames prepared from any dataset), its losses (L1 and
//! squared RGB, L1 LiDAR depth, distortion, termination, VGG16 perceptual, PatchGAN), its
//! validation scores (PSNR, SSIM, Chamfer), and the whole run the command line asks for. The
//! machinery that knows no model is `bevworld_training`'s.

// Libraries return errors; a panic belongs to a broken invariant, said with `expect`.
#![cfg_attr(not(test), warn(clippy::unwrap_used))]

pub mod config;
pub mod data;
pub mod discriminator;
pub mod distortion;
pub mod losses;
pub mod perceptual;
pub mod run;
pub mod sparsity;
pub mod termination;
pub mod terms;
pub mod trainer;

pub use config::{LidarDraw, LossWeights, TrainConfig, TrainedParts};
pub use run::{Overrides, Progress, RunError, Targets, TrainRequest, TrainSummary, train};
pub use terms::{Term, TermValues};
pub use trainer::{StepReport, TrainError, Trainer, ValidationReport};
