//! Downstream heads on the BEV features the tokenizer exports (or the weight-free pillar
//! statistics): a CenterPoint-style 3D detector whose motion head gives each agent K
//! trajectory modes. The paper's pretraining table ("Comparison of whether use pretrained
//! tokenizer") trains such heads on its tokenizer's features; `bevworld train detector` does
//! it here, and the `detect` node runs a trained detector in a graph.
//!
//! The model reads standardised maps (`InputSpec`, kept with the weights) on the feature's own
//! grid and predicts on `output_cells` cells; it knows no dataset.

// Libraries return errors; a panic belongs to a broken invariant, said with `expect`.
#![cfg_attr(not(test), warn(clippy::unwrap_used))]

pub mod config;
pub mod decode;
pub mod input;
pub mod loss;
pub mod model;
pub mod nodes;
pub mod targets;
pub mod weights;

pub use config::{BOX_CHANNELS, DetectorConfig, InputKind, InputSpec, MotionConfig, TrunkConfig};
pub use decode::FrameMaps;
pub use input::{InputError, PosedMap};
pub use loss::{DetectionLoss, LossWeights};
pub use model::{Detector, HeadOutputs};
pub use nodes::register;
pub use targets::{AgentTruth, FrameTargets, ObjectTarget, gaussian_radius};
pub use weights::{
    DetectorMeta, DetectorWeights, DetectorWeightsError, load_detector, save_detector,
};
