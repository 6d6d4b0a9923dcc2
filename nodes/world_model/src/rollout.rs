//! A forecast from raw latents and ego actions: what a graph node or a tool calls. The
//! context is standardised with the tokenizer's statistics and the actions normalised with the
//! model's; the future frames are sampled (residual models add the context's ego-warped
//! current latent) and de-standardised.

use std::path::Path;

use bevworld_types::{EgoAction, LatentStats, LatentStatsFile, StatsFileError};
use burn::prelude::*;

use crate::actions::{ACTION_FEATURES, ActionStats};
use crate::config::{ConfigError, WorldModelConfig};
use crate::ddim::{DdimConfig, DdimError};
use crate::ego_warp::{LatentGrid, PlanarMotion, warp_latent};
use crate::fine_tokens::{FineTokenSelection, select_for_context};
use crate::forecast::{ForecastInputs, forecast};
use crate::model::WorldModel;
use crate::schedule::NoiseSchedule;
use crate::weights::{WorldModelWeights, WorldModelWeightsError, load_weights};

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum RolloutError {
    #[error("a forecast needs {expected} context latents, got {found}")]
    ContextFrames { expected: usize, found: usize },
    #[error("a forecast needs {expected} future actions, got {found}")]
    FutureActions { expected: usize, found: usize },
    #[error("context latent {index} has {found} values, the model's latent {expected}")]
    Shape {
        index: usize,
        found: usize,
        expected: usize,
    },
    #[error("context latent {index} holds a non-finite value")]
    NonFinite { index: usize },
    /// A motion no road vehicle makes (`EgoAction::impossible`): a unit error, a typo or a
    /// corrupt pose, never forecast.
    #[error("the action into {which} frame {index} is impossible: {reason}")]
    ImpossibleAction {
        which: &'static str,
        index: usize,
        reason: String,
    },
    #[error(transparent)]
    Sampler(#[from] DdimError),
}

/// The future latents of a forecast and the ego-warp baseline for the same future, both in
/// the tokenizer's scale, `[C', H, W]` per future frame.
#[derive(Clone, Debug, PartialEq)]
pub struct RolloutOutput {
    pub future: Vec<Vec<f32>>,
    /// The current latent moved into each future ego frame by the future actions.
    pub ego_warped: Vec<Vec<f32>>,
    /// What the sampled frames were added to: each warped frame times its horizon's weight
    /// (`EgoWarpBase`), all of it for a residual model without a fade, none of it (the
    /// latent statistics' mean) for a model that predicts the latent itself.
    pub base: Vec<Vec<f32>>,
}

/// A model ready to forecast.
pub struct Rollout<'a> {
    pub model: &'a WorldModel,
    pub config: &'a WorldModelConfig,
    pub action_stats: &'a ActionStats,
    pub latent_stats: &'a LatentStats,
    pub device: Device,
}

impl Rollout<'_> {
    fn grid(&self) -> LatentGrid {
        self.config.latent_grid()
    }

    /// The N future latents (and the ego-warp baseline), given the context latents oldest
    /// first, the action into each context frame, and the action into each future frame.
    pub fn run(
        &self,
        context: &[Vec<f32>],
        context_actions: &[EgoAction],
        future_actions: &[EgoAction],
        sampler: &DdimConfig,
    ) -> Result<RolloutOutput, RolloutError> {
        let (p, n) = (self.config.context_frames, self.config.future_frames);
        if context.len() != p || context_actions.len() != p {
            return Err(RolloutError::ContextFrames {
                expected: p,
                found: context.len().min(context_actions.len()),
            });
        }
        if future_actions.len() != n {
            return Err(RolloutError::FutureActions {
                expected: n,
                found: future_actions.len(),
            });
        }
        for (which, actions) in [("context", context_actions), ("future", future_actions)] {
            for (index, action) in actions.iter().enumerate() {
                if let Some(reason) = action.impossible() {
                    return Err(RolloutError::ImpossibleAction {
                        which,
                        index,
                        reason,
                    });
                }
            }
        }
        let grid = self.grid();
        let mut standardised = Vec::with_capacity(p * grid.len());
        for (index, latent) in context.iter().enumerate() {
            if latent.len() != grid.len() {
                return Err(RolloutError::Shape {
                    index,
                    found: latent.len(),
                    expected: grid.len(),
                });
            }
            if latent.iter().any(|v| !v.is_finite()) {
                return Err(RolloutError::NonFinite { index });
            }
            let mut values = latent.clone();
            self.latent_stats.standardize(&mut values);
            standardised.extend(values);
        }
        let current = standardised[(p - 1) * grid.len()..].to_vec();
        let ego_warp_base = self.config.ego_warp_base();
        let mut warped = Vec::with_capacity(n * grid.len());
        let mut base = Vec::with_capacity(n * grid.len());
        let mut current_from_future = PlanarMotion::default();
        let mut horizon_s = 0.0;
        for action in future_actions {
            current_from_future = current_from_future.then(&PlanarMotion::of_action(action));
            horizon_s += action.dt_s;
            let frame = warp_latent(&current, &grid, &current_from_future, 0.0);
            let weight = ego_warp_base.weight(horizon_s);
            base.extend(frame.iter().map(|v| weight * v));
            warped.extend(frame);
        }
        let actions: Vec<f32> = context_actions
            .iter()
            .chain(future_actions)
            .flat_map(|a| self.action_stats.normalise(a))
            .collect();
        let shape = |frames: usize| [1, frames, grid.channels, grid.height, grid.width];
        let destandardised = |values: &[f32]| -> Vec<Vec<f32>> {
            values
                .chunks(grid.len())
                .map(|frame| {
                    let mut frame = frame.to_vec();
                    self.latent_stats.destandardize(&mut frame);
                    frame
                })
                .collect()
        };
        let ego_warped = destandardised(&warped);
        let base_destandardised = destandardised(&base);
        let fine_tokens = match &self.config.fine_tokens {
            Some(fine) => {
                // The ego motion into each condition frame after the first.
                let previous_from_frame: Vec<PlanarMotion> = context_actions[1..]
                    .iter()
                    .map(PlanarMotion::of_action)
                    .collect();
                FineTokenSelection {
                    tokens: vec![select_for_context(
                        &standardised,
                        &grid,
                        &previous_from_frame,
                        self.config.patch,
                        &fine.select,
                    )],
                }
            }
            None => FineTokenSelection::default(),
        };
        let inputs = ForecastInputs {
            fine_tokens,
            context: Tensor::from_data(TensorData::new(standardised, shape(p)), &self.device),
            actions: Tensor::from_data(
                TensorData::new(actions, [1, p + n, ACTION_FEATURES]),
                &self.device,
            ),
            base: self
                .config
                .residual_over_ego_warp
                .then(|| Tensor::from_data(TensorData::new(base, shape(n)), &self.device)),
            warped: Tensor::from_data(TensorData::new(warped, shape(n)), &self.device),
        };
        let schedule = NoiseSchedule::new(&self.config.diffusion);
        let values: Vec<f32> = forecast(self.model, self.config, &schedule, &inputs, sampler)?
            .into_data()
            .try_to_vec()
            .unwrap_or_default();
        Ok(RolloutOutput {
            future: destandardised(&values),
            ego_warped,
            base: base_destandardised,
        })
    }
}

/// Why a world model could not be loaded for forecasting.
#[derive(Debug, thiserror::Error)]
pub enum LoadError {
    #[error(transparent)]
    Config(#[from] ConfigError),
    #[error(transparent)]
    Stats(#[from] StatsFileError),
    #[error(transparent)]
    Weights(#[from] WorldModelWeightsError),
}

/// A world model loaded with the latent statistics it forecasts with: its config, its weights
/// (checked to pair with the statistics' tokenizer) and a device. What a tool, a benchmark or a
/// test loads to run `Rollout`s.
pub struct LoadedWorldModel {
    pub config: WorldModelConfig,
    pub weights: WorldModelWeights,
    pub latent_stats: LatentStatsFile,
    pub device: Device,
}

impl LoadedWorldModel {
    pub fn load(
        config: &Path,
        weights: &Path,
        latent_stats: &Path,
        device: Device,
    ) -> Result<Self, LoadError> {
        let config = WorldModelConfig::from_yaml_file(config)?;
        let latent_stats = LatentStatsFile::load(latent_stats)?;
        let weights = load_weights(
            &config,
            weights,
            Some((&latent_stats.model, &latent_stats.weights_hash)),
            &device,
        )?;
        Ok(Self {
            config,
            weights,
            latent_stats,
            device,
        })
    }

    /// The shipped tiny world model and the shipped tokenizer's statistics, from the
    /// repository at `root`.
    pub fn shipped_tiny(root: &Path, device: Device) -> Result<Self, LoadError> {
        Self::load(
            &root.join("configs/models/world-model-tiny.yaml"),
            &root.join("nodes/world_model/weights/world-model-tiny.bpk"),
            &root.join("nodes/tokenizer/weights/tokenizer-tiny.stats.json"),
            device,
        )
    }

    pub fn rollout(&self) -> Rollout<'_> {
        Rollout {
            model: &self.weights.model,
            config: &self.config,
            action_stats: &self.weights.meta.action_stats,
            latent_stats: &self.latent_stats.stats,
            device: self.device.clone(),
        }
    }
}
