//! Tokenizer weights on disk, as burnpack files (`bevworld_blocks::module_file`). Loading
//! builds the model from its config and then requires every tensor to be in the file with the
//! right shape: a missing file, another model's weights, or a config that does not match the
//! file are errors that say which.

use std::path::Path;

use bevworld_blocks::module_file::{self, ModuleFileError};
use burn::prelude::*;

use crate::config::TokenizerConfig;
use crate::model::Tokenizer;

pub type WeightsError = ModuleFileError;

/// What the errors call these weights.
const WHAT: &str = "tokenizer";

/// Writes the model's weights (the file name is used as given).
pub fn save_weights(model: &Tokenizer, path: &Path) -> Result<(), WeightsError> {
    module_file::save_module(model, WHAT, path)
}

/// Builds the model of `config` and loads every one of its tensors from `path`.
pub fn load_weights(
    config: &TokenizerConfig,
    path: &Path,
    device: &Device,
) -> Result<Tokenizer, WeightsError> {
    module_file::load_module(config.init(device), WHAT, &config.name, path)
}

/// A short fingerprint of a weights file (FNV-1a, 64 bit, hex), stamped on every product so
/// that exported features say which weights made them.
pub fn weights_digest(path: &Path) -> Result<String, WeightsError> {
    bevworld_types::file_digest(path).map_err(|e| ModuleFileError::Io {
        what: WHAT.into(),
        path: path.to_path_buf(),
        message: e.to_string(),
    })
}
