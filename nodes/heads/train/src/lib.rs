//! Training the detection and motion heads (`bevworld_heads`) on exported BEV features: the
//! keyframes of annotated sets with their maps and agents (`data.rs`), the loss on batches
//! and validation with the nuScenes detection metrics and minADE/minFDE (`trainer.rs`,
//! `evaluate.rs`), the tokenizer's encoder trained with the heads for the paper's pretraining
//! arms (`encoder.rs`), and the whole run with its test score (`run.rs`).

// Libraries return errors; a panic belongs to a broken invariant, said with `expect`.
#![cfg_attr(not(test), warn(clippy::unwrap_used))]

pub mod config;
pub mod data;
pub mod encoder;
pub mod evaluate;
pub mod run;
pub mod trainer;

pub use config::{FeatureSet, TrainDetectorConfig};
pub use data::{DataError, DetectionSet, LabelledFrame, agents_of, load_set};
pub use evaluate::{Evaluation, MotionScores, evaluate_set, motion_scores, predict};
pub use run::{Init, RunError, TrainRequest, TrainSummary, effective_config, train};
pub use trainer::{DetectorTrainer, TrainError};
