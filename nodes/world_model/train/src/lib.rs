//! Training the world model: latent sequences read from `export_features` caches
//! (`data.rs`), windows of condition and future frames with their actions and ego warps
//! (`window.rs`), the diffusion loss (weighted where the scene moves: `moving_weight.rs`) and
//! validation against copy-last and ego-warp (`trainer.rs`), the paper's three stages and our counterfactual fourth in one run (`run.rs`).

// Libraries return errors; a panic belongs to a broken invariant, said with `expect`.
#![cfg_attr(not(test), warn(clippy::unwrap_used))]

pub mod config;
pub mod data;
pub mod evaluate;
pub mod moving_weight;
pub mod run;
pub mod trainer;
pub mod window;

pub use config::{CacheConfig, Rate, StageConfig, TrainWorldModelConfig};
pub use data::{DataError, Expected, LatentSequences, load_sequences};
pub use evaluate::{Evaluation, evaluate};
pub use run::{
    Overrides, Progress, RunError, TrainRequest, TrainSummary, cache_is_complete,
    effective_configs, train,
};
pub use trainer::{HorizonScores, TrainError, TrainingData, WorldModelTrainer};
pub use window::{WindowBatch, WindowShape, WindowValues};
