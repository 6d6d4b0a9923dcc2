//! The world model of BEVWorld ("Latent BEV Sequence Diffusion"): it forecasts the future BEV
//! latents of a scene from its past ones, conditioned on the ego's actions. A spatial-temporal
//! transformer with adaLN-Zero and causal temporal attention predicts, for the noisy future
//! frames, the noise (or velocity, or clean latent); DDIM samples all future frames in one pass
//! per step.
//!
//! The model reads standardised latents (the tokenizer's statistics file) and normalised
//! actions (`ActionStats`, shipped with the weights); it knows no dataset.

// Libraries return errors; a panic belongs to a broken invariant, said with `expect`.
#![cfg_attr(not(test), warn(clippy::unwrap_used))]

pub mod actions;
pub mod block;
/// The manoeuvres live with the other shared types, since the synthetic world drives them too.
pub use bevworld_types::manoeuvre;
pub mod condition;
pub mod config;
pub mod ddim;
pub mod ego_warp;
pub mod fine_stage;
pub mod fine_tokens;
pub mod forecast;
pub mod model;
pub mod nodes;
pub mod patch;
pub mod rollout;
pub mod schedule;
pub mod shrink;
pub mod weights;

pub use actions::{ACTION_FEATURES, ActionStats};
pub use config::{DiffusionConfig, ScheduleKind, Target, WorldModelConfig};
pub use ddim::{DdimConfig, Spacing};
pub use ego_warp::{EgoWarpBase, LatentGrid, PlanarMotion, warp_latent};
pub use fine_tokens::{FineTokenRule, FineTokenSelection, FineTokensConfig};
pub use forecast::{ContextPasses, ForecastInputs, forecast, forecast_with};
pub use manoeuvre::Manoeuvre;
pub use model::{ContextCache, WorldModel};
pub use nodes::register;
pub use rollout::{LoadError, LoadedWorldModel, Rollout, RolloutError, RolloutOutput};
pub use schedule::NoiseSchedule;
pub use shrink::ResidualShrink;
pub use weights::{
    WeightsMeta, WorldModelWeights, WorldModelWeightsError, load_weights, save_weights,
};
