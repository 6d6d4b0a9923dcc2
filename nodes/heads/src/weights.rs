//! Detector weights on disk: a burnpack file and beside it `<name>.meta.json`, which holds the
//! detector's config, what it reads (`InputSpec`: the product, its grid, frames, the model and
//! weights digest that made the features, the standardisation), how long it trained, and the
//! digest of the burnpack file. Loading refuses weights changed after they were written, and
//! `check_features` refuses features made by another model than the one the detector was
//! trained on, as the world model refuses another tokenizer's latents.

use std::path::{Path, PathBuf};

use bevworld_blocks::module_file::{self, ModuleFileError};
use burn::prelude::*;
use serde::{Deserialize, Serialize};

use crate::config::{DetectorConfig, InputSpec};
use crate::model::Detector;

const WHAT: &str = "detector";

/// What a detector's weights file says of itself.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DetectorMeta {
    pub config: DetectorConfig,
    pub input: InputSpec,
    /// How the encoder was initialised (`frozen`, `scratch`, `tokenizer`).
    pub init: String,
    pub steps: usize,
    /// The command that made them.
    pub command: String,
    /// `file_digest` of the burnpack file beside it; filled in when saved.
    #[serde(default)]
    pub weights_hash: String,
}

#[derive(Debug, thiserror::Error)]
pub enum DetectorWeightsError {
    #[error(transparent)]
    Module(#[from] ModuleFileError),
    #[error("detector weights {path}: {message}")]
    Meta { path: PathBuf, message: String },
    #[error(
        "detector weights {path} were changed after they were written: the file digests to {found}, but {meta} records {recorded}; restore the weights that go with it, or retrain"
    )]
    WeightsChanged {
        path: PathBuf,
        meta: PathBuf,
        found: String,
        recorded: String,
    },
    #[error(
        "detector {path} was trained on the {kind} of {trained}, but it is given the {kind} of {given}; export the features with the weights it was trained on, or retrain with `bevworld train detector`"
    )]
    OtherFeatures {
        path: PathBuf,
        kind: &'static str,
        /// "'model' with weights HASH".
        trained: String,
        given: String,
    },
}

/// Where the metadata of a weights file lives.
pub fn meta_path_for(weights: &Path) -> PathBuf {
    weights.with_extension("meta.json")
}

/// A loaded detector with what its file says of it.
pub struct DetectorWeights {
    pub model: Detector,
    pub meta: DetectorMeta,
    pub path: PathBuf,
}

/// Writes the weights and their metadata (with the weights' digest), each replaced whole.
pub fn save_detector(
    model: &Detector,
    meta: &DetectorMeta,
    path: &Path,
) -> Result<(), DetectorWeightsError> {
    module_file::save_module(model, WHAT, path)?;
    let meta_path = meta_path_for(path);
    let error = |message: String| DetectorWeightsError::Meta {
        path: meta_path.clone(),
        message,
    };
    let mut meta = meta.clone();
    meta.weights_hash = bevworld_types::file_digest(path).map_err(|e| error(e.to_string()))?;
    let text = serde_json::to_string_pretty(&meta).map_err(|e| error(e.to_string()))?;
    bevworld_graph::io::write_atomic_now(&meta_path, text.as_bytes())
        .map_err(|e| error(e.to_string()))
}

/// Reads the metadata beside `path`, every field present and of its type, the config and the
/// input consistent.
pub fn load_meta(path: &Path) -> Result<DetectorMeta, DetectorWeightsError> {
    let meta_path = meta_path_for(path);
    let error = |message: String| DetectorWeightsError::Meta {
        path: meta_path.clone(),
        message,
    };
    let text = std::fs::read_to_string(&meta_path).map_err(|e| error(e.to_string()))?;
    let mut deserializer = serde_json::Deserializer::from_str(&text);
    let meta: DetectorMeta = serde_path_to_error::deserialize(&mut deserializer)
        .map_err(|e| error(format!("field `{}`: {}", e.path(), e.inner())))?;
    let mut problems = meta.config.problems();
    problems.extend(meta.config.input_problems(&meta.input));
    if let Some(problem) = problems.first() {
        return Err(error(format!("config.{problem}")));
    }
    Ok(meta)
}

/// Loads a detector: its metadata, the weights' digest against it, then every tensor.
pub fn load_detector(
    path: &Path,
    device: &Device,
) -> Result<DetectorWeights, DetectorWeightsError> {
    let meta = load_meta(path)?;
    let found = bevworld_types::file_digest(path).map_err(|e| DetectorWeightsError::Meta {
        path: path.to_path_buf(),
        message: e.to_string(),
    })?;
    if found != meta.weights_hash {
        return Err(DetectorWeightsError::WeightsChanged {
            path: path.to_path_buf(),
            meta: meta_path_for(path),
            found,
            recorded: meta.weights_hash.clone(),
        });
    }
    let model = module_file::load_module(
        meta.config.init(&meta.input, device),
        WHAT,
        &meta.config.name,
        path,
    )?;
    Ok(DetectorWeights {
        model,
        meta,
        path: path.to_path_buf(),
    })
}

impl DetectorWeights {
    /// Refuses features made by another model, or other weights, than the detector's.
    pub fn check_features(
        &self,
        model: &str,
        weights_hash: &str,
    ) -> Result<(), DetectorWeightsError> {
        let input = &self.meta.input;
        if input.model == model && input.weights_hash == weights_hash {
            return Ok(());
        }
        Err(DetectorWeightsError::OtherFeatures {
            path: self.path.clone(),
            kind: input.kind.name(),
            trained: format!("'{}' with weights {}", input.model, input.weights_hash),
            given: format!("'{model}' with weights {weights_hash}"),
        })
    }
}
