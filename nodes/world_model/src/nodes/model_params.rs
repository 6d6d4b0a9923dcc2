//! The world model a node runs, as node params: its config and its weights file (with the
//! `.meta.json` beside it, which names the tokenizer whose latents it reads). Everything that
//! can be wrong with them is a parameter error naming the field, raised when the graph is
//! built.

use std::path::PathBuf;

use bevworld_graph::ParamError;
use serde::{Deserialize, Serialize};

use crate::config::WorldModelConfig;
use crate::weights::{WeightsMeta, check_weights_digest, load_sealed_meta};

const ACCEPTED_MODEL: &str = "a world model config file, e.g. configs/models/world-model-tiny.yaml";
const ACCEPTED_WEIGHTS: &str =
    "a burnpack file written by `bevworld train world-model`, with its .meta.json beside it";

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct WorldModelParams {
    /// The model config, e.g. `configs/models/world-model-tiny.yaml`.
    pub model: PathBuf,
    /// The weights, e.g. `nodes/world_model/weights/world-model-tiny.bpk`.
    pub weights: PathBuf,
}

impl WorldModelParams {
    pub fn config(&self) -> Result<WorldModelConfig, ParamError> {
        WorldModelConfig::from_yaml_file(&self.model).map_err(|error| {
            ParamError::field("model", error.to_string()).with_accepted(ACCEPTED_MODEL)
        })
    }

    /// The weights' metadata, checked to belong to the config and to the weights' bytes
    /// (`weights_hash`), and to be as they were written (`meta_hash`).
    pub fn meta(&self, config: &WorldModelConfig) -> Result<WeightsMeta, ParamError> {
        let refused = |error: crate::weights::WorldModelWeightsError| {
            ParamError::field("weights", error.to_string()).with_accepted(ACCEPTED_WEIGHTS)
        };
        let sealed = load_sealed_meta(&self.weights).map_err(refused)?;
        check_weights_digest(&self.weights, &sealed.weights_hash).map_err(refused)?;
        let meta = sealed.meta;
        if meta.model != config.name {
            return Err(ParamError::field(
                "weights",
                format!(
                    "{} holds model '{}', but `model` is '{}'",
                    self.weights.display(),
                    meta.model,
                    config.name
                ),
            )
            .with_accepted(ACCEPTED_WEIGHTS));
        }
        Ok(meta)
    }

    /// What validation can say without loading the model.
    pub fn check(&self) -> Result<(WorldModelConfig, WeightsMeta), ParamError> {
        let config = self.config()?;
        bevworld_blocks::check_file("world model", &self.weights).map_err(|error| {
            ParamError::field("weights", error.to_string()).with_accepted(ACCEPTED_WEIGHTS)
        })?;
        let meta = self.meta(&config)?;
        Ok((config, meta))
    }
}
