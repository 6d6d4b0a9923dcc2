//! A bundle of a graph's `models:` section, as the model crates and the CLI read it: the files
//! of the tokenizer and of the world model a graph runs, named once for every node.
//!
//! ```yaml
//! models:
//!   tiny:
//!     tokenizer: {config: configs/models/tokenizer-tiny.yaml, weights: nodes/tokenizer/weights/tokenizer-tiny.bpk}
//!     world_model: {config: configs/models/world-model-tiny.yaml, weights: nodes/world_model/weights/world-model-tiny.bpk}
//! ```

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use crate::latent_stats_file::stats_path_for;

/// The `weights` value that asks for a randomly initialised tokenizer (plumbing tests, latency
/// measurements); its products are stamped `untrained`.
pub const UNTRAINED: &str = "untrained";

#[derive(Clone, Debug, Default, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct ModelBundle {
    #[serde(default)]
    pub tokenizer: Option<TokenizerFiles>,
    /// A world model, which reads the latents of the bundle's tokenizer.
    #[serde(default)]
    pub world_model: Option<WorldModelFiles>,
}

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct TokenizerFiles {
    /// The model config, e.g. `configs/models/tokenizer-tiny.yaml`.
    pub config: PathBuf,
    /// A burnpack weights file written by `bevworld train tokenizer`, or `untrained`.
    pub weights: String,
    /// The latents' statistics; absent: the file beside the weights (`stats_path_for`).
    #[serde(default)]
    pub latent_stats: Option<PathBuf>,
}

impl TokenizerFiles {
    pub fn is_untrained(&self) -> bool {
        self.weights == UNTRAINED
    }

    /// The statistics file: the one named, or the one beside trained weights.
    pub fn latent_stats_path(&self) -> Option<PathBuf> {
        self.latent_stats.clone().or_else(|| {
            (!self.is_untrained()).then(|| stats_path_for(std::path::Path::new(&self.weights)))
        })
    }
}

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct WorldModelFiles {
    /// The model config, e.g. `configs/models/world-model-tiny.yaml`.
    pub config: PathBuf,
    /// The weights, with their `.meta.json` beside them.
    pub weights: PathBuf,
}

impl ModelBundle {
    /// The bundle of a graph's `models:` section, as the runtime hands it over.
    pub fn from_json(value: &serde_json::Value) -> Result<Self, serde_json::Error> {
        serde_json::from_value(value.clone())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_statistics_default_to_the_file_beside_trained_weights() {
        let bundle = ModelBundle::from_json(&serde_json::json!({
            "tokenizer": {"config": "c.yaml", "weights": "w/t.bpk"}
        }))
        .unwrap();
        let tokenizer = bundle.tokenizer.unwrap();
        assert_eq!(
            tokenizer.latent_stats_path(),
            Some(PathBuf::from("w/t.stats.json"))
        );
        let untrained = TokenizerFiles {
            weights: UNTRAINED.into(),
            ..tokenizer
        };
        assert_eq!(untrained.latent_stats_path(), None);
        assert!(ModelBundle::from_json(&serde_json::json!({"tokeniser": {}})).is_err());
    }
}
