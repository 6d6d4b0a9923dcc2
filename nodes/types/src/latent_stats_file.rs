//! The latent statistics on disk: a JSON file beside the weights (`tokenizer-tiny.bpk` →
//! `tokenizer-tiny.stats.json`), naming the model and the digest of the weights they were
//! computed with, so that statistics of other weights are refused instead of silently used.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::latent_stats::LatentStats;

#[derive(Debug, thiserror::Error)]
pub enum StatsFileError {
    #[error(
        "latent statistics {path}: file not found (compute them with `bevworld tokenizer stats`)"
    )]
    NotFound { path: PathBuf },
    #[error("latent statistics {path}: {message}")]
    Io { path: PathBuf, message: String },
    #[error("latent statistics {path}: field `{field}`: {message}")]
    Invalid {
        path: PathBuf,
        field: String,
        message: String,
    },
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LatentStatsFile {
    /// The tokenizer config's name.
    pub model: String,
    /// `weights_digest` of the weights file.
    pub weights_hash: String,
    /// The dataset the statistics were computed over.
    pub data: String,
    pub stats: LatentStats,
}

/// Where the statistics of a weights file live.
pub fn stats_path_for(weights: &Path) -> PathBuf {
    weights.with_extension("stats.json")
}

impl LatentStatsFile {
    pub fn save(&self, path: &Path) -> Result<(), StatsFileError> {
        let io = |e: String| StatsFileError::Io {
            path: path.to_path_buf(),
            message: e,
        };
        let text = serde_json::to_string_pretty(self).map_err(|e| io(e.to_string()))?;
        // Whole or not at all: a crash never leaves a half-written file.
        bevworld_atomic_file::write(path, text.as_bytes()).map_err(|e| io(e.to_string()))
    }

    pub fn load(path: &Path) -> Result<Self, StatsFileError> {
        let text = std::fs::read_to_string(path).map_err(|e| match e.kind() {
            std::io::ErrorKind::NotFound => StatsFileError::NotFound {
                path: path.to_path_buf(),
            },
            _ => StatsFileError::Io {
                path: path.to_path_buf(),
                message: e.to_string(),
            },
        })?;
        let mut deserializer = serde_json::Deserializer::from_str(&text);
        let file: Self = serde_path_to_error::deserialize(&mut deserializer).map_err(|e| {
            StatsFileError::Invalid {
                path: path.to_path_buf(),
                field: e.path().to_string(),
                message: e.inner().to_string(),
            }
        })?;
        let invalid = |field: &str, message: String| StatsFileError::Invalid {
            path: path.to_path_buf(),
            field: field.into(),
            message,
        };
        let stats = &file.stats;
        if stats.mean.is_empty() || stats.mean.len() != stats.std.len() {
            return Err(invalid(
                "stats.std",
                format!(
                    "{} means but {} deviations",
                    stats.mean.len(),
                    stats.std.len()
                ),
            ));
        }
        if let Some(m) = stats.mean.iter().find(|m| !m.is_finite()) {
            return Err(invalid("stats.mean", format!("{m} is not finite")));
        }
        if let Some(s) = stats.std.iter().find(|s| !(s.is_finite() && **s > 0.0)) {
            return Err(invalid(
                "stats.std",
                format!("{s} is not a finite number > 0"),
            ));
        }
        Ok(file)
    }

    /// Refuses statistics of other weights or another model.
    pub fn check_matches(
        &self,
        model: &str,
        weights_hash: &str,
        path: &Path,
    ) -> Result<(), StatsFileError> {
        if self.model != model || self.weights_hash != weights_hash {
            return Err(StatsFileError::Invalid {
                path: path.to_path_buf(),
                field: "weights_hash".into(),
                message: format!(
                    "computed for model '{}' with weights {}, not for '{model}' with weights {weights_hash}; recompute with `bevworld tokenizer stats`",
                    self.model, self.weights_hash
                ),
            });
        }
        Ok(())
    }
}
