//! The world model a node runs, from its graph's model bundle (`models:`; `WorldModelFiles`,
//! beside the `TokenizerFiles` whose latents it reads): checked at validation (`check_files`,
//! `check_pairing`: the config, the sealed `.meta.json`, and that the weights were trained on
//! the bundle's tokenizer and statistics), loaded once per graph (`load_shared`) and shared by
//! every node that names the bundle. Every problem is a parameter error naming the field.

use std::sync::Arc;

use bevworld_graph::{Models, ParamError};
use bevworld_types::{LatentStatsFile, ModelBundle, WorldModelFiles};
use serde::{Deserialize, Serialize};

use crate::config::WorldModelConfig;
use crate::rollout::LoadedWorldModel;
use crate::weights::{WeightsMeta, check_weights_digest, load_sealed_meta};

const ACCEPTED_CONFIG: &str =
    "a world model config file, e.g. configs/models/world-model-tiny.yaml";
const ACCEPTED_WEIGHTS: &str =
    "a burnpack file written by `bevworld train world-model`, with its .meta.json beside it";

/// What a node that runs the world model takes: the bundle of the graph's `models:` section.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct WorldModelParams {
    /// A bundle of the graph's `models:` section with a `tokenizer:` and a `world_model:`.
    pub model: String,
}

/// The bundle, as the world model's nodes read it.
fn bundle_of(bundle: &serde_json::Value) -> Result<ModelBundle, ParamError> {
    ModelBundle::from_json(bundle).map_err(|error| ParamError::field("model", error.to_string()))
}

/// The config and the sealed metadata of the bundle's world model, checked to belong together
/// and to the weights' bytes. Errors name `world_model.config` or `world_model.weights`.
pub fn check_files(files: &WorldModelFiles) -> Result<(WorldModelConfig, WeightsMeta), ParamError> {
    let config = WorldModelConfig::from_yaml_file(&files.config).map_err(|error| {
        ParamError::field("world_model.config", error.to_string()).with_accepted(ACCEPTED_CONFIG)
    })?;
    let refused = |error: String| {
        ParamError::field("world_model.weights", error).with_accepted(ACCEPTED_WEIGHTS)
    };
    bevworld_blocks::check_file("world model", &files.weights)
        .map_err(|error| refused(error.to_string()))?;
    let sealed = load_sealed_meta(&files.weights).map_err(|error| refused(error.to_string()))?;
    check_weights_digest(&files.weights, &sealed.weights_hash)
        .map_err(|error| refused(error.to_string()))?;
    let meta = sealed.meta;
    if meta.model != config.name {
        return Err(refused(format!(
            "{} holds model '{}', but its config is '{}'",
            files.weights.display(),
            meta.model,
            config.name
        )));
    }
    Ok((config, meta))
}

/// The world model's weights were trained on the latents of one tokenizer (name, weights
/// digest), standardised by that tokenizer's statistics: the bundle's tokenizer and statistics
/// must be those. A mismatched pair is named at `world_model.weights`.
pub fn check_pairing(
    config: &WorldModelConfig,
    meta: &WeightsMeta,
    tokenizer: (&str, &str),
    stats: &LatentStatsFile,
) -> Result<(), ParamError> {
    let (name, hash) = tokenizer;
    if stats.stats.mean.len() != config.latent_channels {
        return Err(ParamError::field(
            "tokenizer.latent_stats",
            format!(
                "statistics of {} channels, but the world model's latent has {}",
                stats.stats.mean.len(),
                config.latent_channels
            ),
        ));
    }
    if (
        meta.tokenizer_model.as_str(),
        meta.tokenizer_weights_hash.as_str(),
    ) != (name, hash)
    {
        return Err(ParamError::field(
            "world_model.weights",
            format!(
                "the world model was trained on the latents of tokenizer '{}' with weights {}, but the bundle's tokenizer is '{name}' with weights {hash}",
                meta.tokenizer_model, meta.tokenizer_weights_hash
            ),
        )
        .with_accepted("the tokenizer the world model was trained with, or a world model trained on this tokenizer's latents"));
    }
    if (stats.model.as_str(), stats.weights_hash.as_str()) != (name, hash) {
        return Err(ParamError::field(
            "tokenizer.latent_stats",
            format!(
                "the statistics are of tokenizer '{}' with weights {}, not of the bundle's '{name}' with weights {hash}",
                stats.model, stats.weights_hash
            ),
        )
        .with_accepted("the file `bevworld tokenizer stats` writes for these weights"));
    }
    Ok(())
}

impl WorldModelParams {
    /// At validation: the bundle has a world model (its files are checked with the bundle,
    /// once); its config and metadata, which the node plans with.
    pub fn check(&self, models: &Models) -> Result<(WorldModelConfig, WeightsMeta), ParamError> {
        let bundle = bundle_of(models.require(&self.model, &["tokenizer", "world_model"])?)?;
        let files = bundle
            .world_model
            .ok_or_else(|| ParamError::field("model", "the bundle has no `world_model`"))?;
        check_files(&files).map_err(|error| ParamError {
            field: Some("model".into()),
            message: format!(
                "bundle '{}', {}: {}",
                self.model,
                error.field.unwrap_or_default(),
                error.message
            ),
            accepted: error.accepted,
        })
    }

    /// The bundle's world model with its latent statistics, loaded by the first node that asks
    /// and shared after that.
    pub fn load_shared(&self, models: &Models) -> Result<Arc<LoadedWorldModel>, ParamError> {
        models.load(&self.model, |bundle| {
            let bundle = bundle_of(bundle)?;
            let (Some(tokenizer), Some(world_model)) = (bundle.tokenizer, bundle.world_model)
            else {
                return Err(ParamError::field(
                    "model",
                    "the bundle needs a `tokenizer` and a `world_model`",
                ));
            };
            let stats = tokenizer.latent_stats_path().ok_or_else(|| {
                ParamError::field(
                    "model",
                    "an untrained tokenizer has no latent statistics for the world model",
                )
            })?;
            let (_, device) = bevworld_device::from_env().map_err(|error| {
                ParamError::field("model", format!("no device to run it on: {error}"))
            })?;
            LoadedWorldModel::load(&world_model.config, &world_model.weights, &stats, device)
                .map_err(|error| ParamError::field("model", error.to_string()))
        })
    }
}
