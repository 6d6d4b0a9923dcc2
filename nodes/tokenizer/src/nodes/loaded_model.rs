//! The model a tokenizer node runs: its config file, its weights file and the device, as
//! node params. Everything that can be wrong with them is a parameter error naming the field,
//! raised when the graph is built, before any frame flows.

use std::path::PathBuf;

use bevworld_graph::ParamError;
use burn::prelude::*;
use serde::{Deserialize, Serialize};

use crate::config::TokenizerConfig;
use crate::model::Tokenizer;
use crate::weights::{load_weights, weights_digest};
use bevworld_blocks::check_file;

/// The `weights` value that asks for a randomly initialised model, for plumbing tests and
/// latency measurements; its products are stamped `untrained`.
pub const UNTRAINED: &str = "untrained";

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct ModelParams {
    /// The model config, e.g. `configs/models/tokenizer-tiny.yaml`.
    pub model: PathBuf,
    /// A burnpack weights file written by `bevworld train tokenizer`, or `untrained`.
    pub weights: String,
}

/// A model ready to run, with what its products are stamped with.
pub struct LoadedModel {
    pub config: TokenizerConfig,
    pub model: Tokenizer,
    pub device: Device,
    /// The weights' digest, or `untrained`.
    pub weights_hash: String,
}

/// What `weights` accepts, for its errors.
const ACCEPTED_WEIGHTS: &str =
    "a burnpack file written by `bevworld train tokenizer` for this config, or `untrained`";

impl ModelParams {
    /// What validation can say without loading the model: the config reads and is consistent,
    /// and the weights file is a burnpack file (its header only is read).
    pub fn check(&self) -> Result<(), ParamError> {
        self.config()?;
        if self.weights != UNTRAINED {
            check_file("tokenizer", std::path::Path::new(&self.weights)).map_err(|error| {
                ParamError::field("weights", error.to_string()).with_accepted(ACCEPTED_WEIGHTS)
            })?;
        }
        Ok(())
    }

    fn config(&self) -> Result<TokenizerConfig, ParamError> {
        TokenizerConfig::from_yaml_file(&self.model).map_err(|error| {
            ParamError::field("model", error.to_string())
                .with_accepted("a tokenizer config file, e.g. configs/models/tokenizer-tiny.yaml")
        })
    }

    /// Builds the model and loads its weights.
    pub fn load(&self) -> Result<LoadedModel, ParamError> {
        let config = self.config()?;
        let (_, device) = bevworld_device::from_env().map_err(|error| {
            ParamError::field("model", format!("no device to run it on: {error}"))
        })?;
        if self.weights == UNTRAINED {
            tracing::warn!(
                model = %config.name,
                "running the tokenizer with untrained (random) weights: outputs are not reconstructions"
            );
            return Ok(LoadedModel {
                model: config.init_seeded(0, &device),
                config,
                device,
                weights_hash: UNTRAINED.into(),
            });
        }
        let path = PathBuf::from(&self.weights);
        let model = load_weights(&config, &path, &device).map_err(|error| {
            ParamError::field("weights", error.to_string()).with_accepted(ACCEPTED_WEIGHTS)
        })?;
        let weights_hash = weights_digest(&path).map_err(|error| {
            ParamError::field("weights", error.to_string()).with_accepted(ACCEPTED_WEIGHTS)
        })?;
        Ok(LoadedModel {
            config,
            model,
            device,
            weights_hash,
        })
    }
}
