//! Tokenizer weights on disk, as burnpack files. Loading builds the model from its config and
//! then requires every tensor to be in the file with the right shape: a missing file, another
//! model's weights, or a config that does not match the file are errors that say which.

use std::path::{Path, PathBuf};

use burn::module::Module;
use burn::prelude::*;
use burn::store::{BurnpackStore, ModuleSnapshot};

use crate::config::TokenizerConfig;
use crate::model::Tokenizer;

#[derive(Debug, thiserror::Error)]
pub enum WeightsError {
    #[error("tokenizer weights {path}: file not found")]
    NotFound { path: PathBuf },
    #[error("tokenizer weights {path}: {message}")]
    Io { path: PathBuf, message: String },
    #[error(
        "tokenizer weights {path} do not fit the config '{config}': {count} tensors missing or of \
         another shape, e.g. {examples}"
    )]
    Mismatch {
        path: PathBuf,
        config: String,
        count: usize,
        examples: String,
    },
}

/// Writes the model's weights (the file name is used as given).
pub fn save_weights(model: &Tokenizer, path: &Path) -> Result<(), WeightsError> {
    save_module(model, path)
}

/// Builds the model of `config` and loads every one of its tensors from `path`.
pub fn load_weights(
    config: &TokenizerConfig,
    path: &Path,
    device: &Device,
) -> Result<Tokenizer, WeightsError> {
    load_module(config.init(device), &config.name, path)
}

/// Writes any module's weights as burnpack (the file name is used as given).
pub fn save_module<M: Module>(module: &M, path: &Path) -> Result<(), WeightsError> {
    let mut store = BurnpackStore::from_file(path)
        .auto_extension(false)
        .overwrite(true);
    module.save_into(&mut store).map_err(|e| WeightsError::Io {
        path: path.to_path_buf(),
        message: e.to_string(),
    })
}

/// Loads every tensor of `module` (built for `name`) from `path`; a missing tensor or one of
/// another shape is an error naming a few of them.
pub fn load_module<M: Module>(mut module: M, name: &str, path: &Path) -> Result<M, WeightsError> {
    if !path.is_file() {
        return Err(WeightsError::NotFound {
            path: path.to_path_buf(),
        });
    }
    let mut store = BurnpackStore::from_file(path)
        .auto_extension(false)
        .allow_partial(true)
        // Collect shape errors into the result, to name a few instead of all of them.
        .validate(false);
    let result = module.load_from(&mut store).map_err(|e| WeightsError::Io {
        path: path.to_path_buf(),
        message: e.to_string(),
    })?;
    let mut problems: Vec<String> = result
        .missing
        .iter()
        .map(|(name, _)| format!("{name} (missing)"))
        .collect();
    problems.extend(result.errors.iter().map(|e| format!("{e:?}")));
    if problems.is_empty() {
        Ok(module)
    } else {
        Err(WeightsError::Mismatch {
            path: path.to_path_buf(),
            config: name.to_string(),
            count: problems.len(),
            examples: problems
                .iter()
                .take(3)
                .cloned()
                .collect::<Vec<_>>()
                .join("; "),
        })
    }
}

/// A short fingerprint of a weights file (FNV-1a, 64 bit, hex), stamped on every product so
/// that exported features say which weights made them.
pub fn weights_digest(path: &Path) -> Result<String, WeightsError> {
    let bytes = std::fs::read(path).map_err(|e| WeightsError::Io {
        path: path.to_path_buf(),
        message: e.to_string(),
    })?;
    let mut hash: u64 = 0xcbf2_9ce4_8422_2325;
    for byte in bytes {
        hash ^= u64::from(byte);
        hash = hash.wrapping_mul(0x0000_0100_0000_01b3);
    }
    Ok(format!("{hash:016x}"))
}
