//! The tokenizer a node runs, from its graph's model bundle (`models:`; `TokenizerFiles`):
//! checked at validation (`check_files`, which opens the weights' header and digests them, and
//! nothing heavier), loaded once per graph (`load_shared`) and shared by every node that names
//! the bundle. Every problem is a parameter error naming the bundle's field.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use bevworld_graph::{Models, ParamError};
use bevworld_types::{ModelBundle, TokenizerFiles};
use burn::prelude::*;
use serde::{Deserialize, Serialize};

use crate::config::TokenizerConfig;
use crate::model::Tokenizer;
use crate::weights::{load_weights, weights_digest};
use bevworld_blocks::check_file;

pub use bevworld_types::model_bundle::UNTRAINED;

/// What a node that runs the tokenizer takes: the bundle of the graph's `models:` section.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct ModelParams {
    /// A bundle of the graph's `models:` section with a `tokenizer:`.
    pub model: String,
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

/// The bundle's tokenizer files.
pub fn tokenizer_files(bundle: &serde_json::Value) -> Result<TokenizerFiles, ParamError> {
    ModelBundle::from_json(bundle)
        .map_err(|error| ParamError::field("model", error.to_string()))?
        .tokenizer
        .ok_or_else(|| ParamError::field("model", "the bundle has no `tokenizer`"))
}

/// The facts `check_files` finds: the config and the weights' digest (`untrained` for none).
pub struct CheckedTokenizer {
    pub config: TokenizerConfig,
    pub weights_hash: String,
}

/// What validation can say without loading the model: the config reads and is consistent, the
/// weights file is a burnpack file (its header only is read), and its digest. Errors name the
/// bundle's field (`tokenizer.config`, `tokenizer.weights`).
pub fn check_files(files: &TokenizerFiles) -> Result<CheckedTokenizer, ParamError> {
    let config = config(&files.config)?;
    if files.is_untrained() {
        return Ok(CheckedTokenizer {
            config,
            weights_hash: UNTRAINED.into(),
        });
    }
    let path = Path::new(&files.weights);
    let refused = |error: String| {
        ParamError::field("tokenizer.weights", error).with_accepted(ACCEPTED_WEIGHTS)
    };
    check_file("tokenizer", path).map_err(|error| refused(error.to_string()))?;
    let weights_hash = weights_digest(path).map_err(|error| refused(error.to_string()))?;
    Ok(CheckedTokenizer {
        config,
        weights_hash,
    })
}

fn config(path: &Path) -> Result<TokenizerConfig, ParamError> {
    TokenizerConfig::from_yaml_file(path).map_err(|error| {
        ParamError::field("tokenizer.config", error.to_string())
            .with_accepted("a tokenizer config file, e.g. configs/models/tokenizer-tiny.yaml")
    })
}

impl ModelParams {
    /// At validation: the bundle exists and has a tokenizer (its files are checked with the
    /// bundle, once).
    pub fn check(&self, models: &Models) -> Result<(), ParamError> {
        models.require(&self.model, &["tokenizer"]).map(|_| ())
    }

    /// The bundle's tokenizer, loaded by the first node that asks and shared after that.
    pub fn load_shared(&self, models: &Models) -> Result<Arc<LoadedModel>, ParamError> {
        models.load(&self.model, |bundle| load(&tokenizer_files(bundle)?))
    }
}

/// Builds the model and loads its weights.
pub fn load(files: &TokenizerFiles) -> Result<LoadedModel, ParamError> {
    let config = config(&files.config)?;
    let (_, device) = bevworld_device::from_env()
        .map_err(|error| ParamError::field("model", format!("no device to run it on: {error}")))?;
    if files.is_untrained() {
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
    let path = PathBuf::from(&files.weights);
    let refused = |error: String| {
        ParamError::field("tokenizer.weights", error).with_accepted(ACCEPTED_WEIGHTS)
    };
    let model =
        load_weights(&config, &path, &device).map_err(|error| refused(error.to_string()))?;
    let weights_hash = weights_digest(&path).map_err(|error| refused(error.to_string()))?;
    Ok(LoadedModel {
        config,
        model,
        device,
        weights_hash,
    })
}
