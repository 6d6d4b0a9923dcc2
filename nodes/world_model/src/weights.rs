//! World-model weights on disk: a burnpack file (`world-model-tiny.bpk`) and beside it
//! `world-model-tiny.meta.json`, which names the model config, the tokenizer whose latents it
//! was trained on (its name and weights digest) and the action statistics it normalises with.
//!
//! The metadata seal themselves and their weights: `weights_hash` is the burnpack file's
//! digest and `meta_hash` the digest of the metadata's other fields as written. Loading
//! refuses weights that were changed after they were written (a byte flipped, a file swapped)
//! and metadata edited by hand (an action mean moved, a tokenizer digest replaced), each
//! naming the file at fault, as well as weights that do not fit the config, hold a non-finite
//! value, normalise with impossible statistics or pair with another tokenizer.

use std::path::{Path, PathBuf};

use bevworld_blocks::module_file::{self, ModuleFileError};
use bevworld_types::bytes_digest;
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

/// The metadata file: `WeightsMeta`'s fields and the two digests that seal them.
#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct MetaFile {
    model: String,
    tokenizer_model: String,
    tokenizer_weights_hash: String,
    action_stats: ActionStats,
    steps: usize,
    command: String,
    /// `file_digest` of the burnpack file beside it.
    weights_hash: String,
    /// `meta_digest` of the fields above.
    meta_hash: String,
}

/// The digest of metadata as read from a file: their compact JSON, in the struct's order.
fn meta_digest(meta: &WeightsMeta) -> Result<String, String> {
    serde_json::to_vec(meta)
        .map(|bytes| bytes_digest(&bytes))
        .map_err(|e| e.to_string())
}

/// The digest the metadata will have when read back: serde_json's parser may land a float one
/// unit in the last place from the value it printed, so the seal is taken of the values a
/// reader gets, which every reader gets alike.
fn sealing_digest(meta: &WeightsMeta) -> Result<String, String> {
    let text = serde_json::to_vec(meta).map_err(|e| e.to_string())?;
    let read_back: WeightsMeta = serde_json::from_slice(&text).map_err(|e| e.to_string())?;
    meta_digest(&read_back)
}

#[derive(Debug, thiserror::Error)]
pub enum WorldModelWeightsError {
    #[error(transparent)]
    Module(#[from] ModuleFileError),
    #[error("world model weights {path}: {message}")]
    Meta { path: PathBuf, message: String },
    #[error(
        "world model weights {path} were changed after they were written: the file digests to {found}, but {meta} records {recorded}; restore the weights that go with it, or retrain"
    )]
    WeightsChanged {
        path: PathBuf,
        meta: PathBuf,
        found: String,
        recorded: String,
    },
    #[error(
        "world model metadata {path} was edited after it was written: its fields digest to {found}, but it records meta_hash {recorded}; restore the file the training run wrote, or retrain"
    )]
    MetaEdited {
        path: PathBuf,
        found: String,
        recorded: String,
    },
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

/// Writes the weights and their metadata, sealed (`weights_hash`, `meta_hash`), each replaced
/// whole.
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
    let weights_hash = bevworld_types::file_digest(path).map_err(|e| error(e.to_string()))?;
    let meta = meta.clone();
    let file = MetaFile {
        meta_hash: sealing_digest(&meta).map_err(error)?,
        weights_hash,
        model: meta.model,
        tokenizer_model: meta.tokenizer_model,
        tokenizer_weights_hash: meta.tokenizer_weights_hash,
        action_stats: meta.action_stats,
        steps: meta.steps,
        command: meta.command,
    };
    let text = serde_json::to_string_pretty(&file).map_err(|e| error(e.to_string()))?;
    bevworld_graph::io::write_atomic_now(&meta_path, text.as_bytes())
        .map_err(|e| error(e.to_string()))
}

/// Metadata read and checked: its fields, and the digest it records for the weights.
pub struct SealedMeta {
    pub meta: WeightsMeta,
    pub weights_hash: String,
}

/// Reads the metadata beside `path`: every field present and of its type, the action
/// statistics possible, and the fields as they were written (`meta_hash`).
pub fn load_meta(path: &Path) -> Result<WeightsMeta, WorldModelWeightsError> {
    load_sealed_meta(path).map(|sealed| sealed.meta)
}

/// `load_meta`, with the weights' recorded digest.
pub fn load_sealed_meta(path: &Path) -> Result<SealedMeta, WorldModelWeightsError> {
    let meta_path = meta_path_for(path);
    let error = |message: String| WorldModelWeightsError::Meta {
        path: meta_path.clone(),
        message,
    };
    let text = std::fs::read_to_string(&meta_path).map_err(|e| error(e.to_string()))?;
    let mut deserializer = serde_json::Deserializer::from_str(&text);
    let file: MetaFile = serde_path_to_error::deserialize(&mut deserializer)
        .map_err(|e| error(format!("field `{}`: {}", e.path(), e.inner())))?;
    let meta = WeightsMeta {
        model: file.model,
        tokenizer_model: file.tokenizer_model,
        tokenizer_weights_hash: file.tokenizer_weights_hash,
        action_stats: file.action_stats,
        steps: file.steps,
        command: file.command,
    };
    meta.action_stats
        .check()
        .map_err(|(field, message)| error(format!("field `action_stats.{field}`: {message}")))?;
    let found = meta_digest(&meta).map_err(error)?;
    if found != file.meta_hash {
        return Err(WorldModelWeightsError::MetaEdited {
            path: meta_path,
            found,
            recorded: file.meta_hash,
        });
    }
    Ok(SealedMeta {
        meta,
        weights_hash: file.weights_hash,
    })
}

/// Refuses weights whose bytes are not the ones their metadata were written with; returns
/// their digest.
pub fn check_weights_digest(path: &Path, recorded: &str) -> Result<String, WorldModelWeightsError> {
    let found = bevworld_types::file_digest(path).map_err(|e| ModuleFileError::Io {
        what: WHAT.into(),
        path: path.to_path_buf(),
        message: e.to_string(),
    })?;
    if found != recorded {
        return Err(WorldModelWeightsError::WeightsChanged {
            path: path.to_path_buf(),
            meta: meta_path_for(path),
            found,
            recorded: recorded.to_string(),
        });
    }
    Ok(found)
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
    let SealedMeta { meta, weights_hash } = load_sealed_meta(path)?;
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
    let digest = check_weights_digest(path, &weights_hash)?;
    let model = module_file::load_module(config.init(device), WHAT, &config.name, path)?;
    Ok(WorldModelWeights {
        model,
        meta,
        digest,
    })
}
