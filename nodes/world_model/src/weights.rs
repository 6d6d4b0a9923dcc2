//! World-model weights on disk: a burnpack file (`world-model-tiny.bpk`) and beside it
//! `world-model-tiny.meta.json`, which names the model config, the tokenizer whose latents it
//! was trained on (its name and weights digest) and the action statistics it normalises with.
//! Loading refuses weights that do not fit the config, hold a non-finite value, or pair with
//! another tokenizer.

use std::path::{Path, PathBuf};

use bevworld_blocks::module_file::{self, ModuleFileError};
use burn::prelude::*;
use serde::{Deserialize, Serialize};

use crate::actions::ActionStats;
use crate::config::WorldModelConfig;
use crate::model::WorldModel;

/// What the errors call these weights.
const WHAT: &str = "world model";

/// What a weights file says of itself.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WeightsMeta {
    /// The model config's `name`.
    pub model: String,
    /// The tokenizer config's name and the digest of the tokenizer weights whose latents the
    /// model was trained on.
    pub tokenizer_model: String,
    pub tokenizer_weights_hash: String,
    pub action_stats: ActionStats,
    /// Optimiser steps the weights were trained for, over all stages.
    pub steps: usize,
    /// The command that made them.
    pub command: String,
}

#[derive(Debug, thiserror::Error)]
pub enum WorldModelWeightsError {
    #[error(transparent)]
    Module(#[from] ModuleFileError),
    #[error("world model weights {path}: {message}")]
    Meta { path: PathBuf, message: String },
    #[error(
        "world model weights {path} were trained on the latents of tokenizer '{trained_model}' with weights {trained_hash}, not '{model}' with weights {hash}; use the tokenizer they pair with, or retrain with `bevworld train world-model`"
    )]
    Tokenizer {
        path: PathBuf,
        trained_model: String,
        trained_hash: String,
        model: String,
        hash: String,
    },
}

/// Where the metadata of a weights file lives.
pub fn meta_path_for(weights: &Path) -> PathBuf {
    weights.with_extension("meta.json")
}

/// A loaded model with what its file says of it.
pub struct WorldModelWeights {
    pub model: WorldModel,
    pub meta: WeightsMeta,
    /// `file_digest` of the burnpack file.
    pub digest: String,
}

/// Writes the weights and their metadata, each replaced whole.
pub fn save_weights(
    model: &WorldModel,
    meta: &WeightsMeta,
    path: &Path,
) -> Result<(), WorldModelWeightsError> {
    module_file::save_module(model, WHAT, path)?;
    let meta_path = meta_path_for(path);
    let error = |message: String| WorldModelWeightsError::Meta {
        path: meta_path.clone(),
        message,
    };
    let text = serde_json::to_string_pretty(meta).map_err(|e| error(e.to_string()))?;
    let partial = meta_path.with_extension("json.tmp");
    std::fs::write(&partial, text).map_err(|e| error(e.to_string()))?;
    std::fs::rename(&partial, &meta_path).map_err(|e| error(e.to_string()))
}

/// Reads the metadata beside `path`.
pub fn load_meta(path: &Path) -> Result<WeightsMeta, WorldModelWeightsError> {
    let meta_path = meta_path_for(path);
    let error = |message: String| WorldModelWeightsError::Meta {
        path: meta_path.clone(),
        message,
    };
    let text = std::fs::read_to_string(&meta_path).map_err(|e| error(e.to_string()))?;
    let mut deserializer = serde_json::Deserializer::from_str(&text);
    serde_path_to_error::deserialize(&mut deserializer)
        .map_err(|e| error(format!("field `{}`: {}", e.path(), e.inner())))
}

/// Builds the model of `config` and loads its weights from `path`, checking that they were
/// made for this config and, when `tokenizer` (name, weights digest) is given, for the latents
/// of that tokenizer.
pub fn load_weights(
    config: &WorldModelConfig,
    path: &Path,
    tokenizer: Option<(&str, &str)>,
    device: &Device,
) -> Result<WorldModelWeights, WorldModelWeightsError> {
    let meta = load_meta(path)?;
    if meta.model != config.name {
        return Err(WorldModelWeightsError::Meta {
            path: meta_path_for(path),
            message: format!(
                "the weights are of model '{}', the config is '{}'",
                meta.model, config.name
            ),
        });
    }
    if let Some((model, hash)) = tokenizer
        && (meta.tokenizer_model != model || meta.tokenizer_weights_hash != hash)
    {
        return Err(WorldModelWeightsError::Tokenizer {
            path: path.to_path_buf(),
            trained_model: meta.tokenizer_model.clone(),
            trained_hash: meta.tokenizer_weights_hash.clone(),
            model: model.to_string(),
            hash: hash.to_string(),
        });
    }
    let model = module_file::load_module(config.init(device), WHAT, &config.name, path)?;
    let digest = bevworld_types::file_digest(path).map_err(|e| ModuleFileError::Io {
        what: WHAT.into(),
        path: path.to_path_buf(),
        message: e.to_string(),
    })?;
    Ok(WorldModelWeights {
        model,
        meta,
        digest,
    })
}
