//! The world model's latent caches: a synthetic set encoded with the tokenizer through the
//! export graph (`configs/graphs/export_latents.yaml`), the same path and files a user's
//! export takes. Once at 12 Hz (`index.json`) and once at keyframes (`index-keyframes.json`)
//! into the same folder; a keyframe's file is written by the first pass and kept by the second.

use std::path::Path;

use anyhow::{Context, Result};
use bevworld_world_model_train::CacheConfig;

use crate::commands::{contracts, graph_run};
use bevworld_world_model_train::config::{KEYFRAMES_INDEX, SWEEPS_INDEX};

/// The graph the caches are exported with.
pub const EXPORT_GRAPH: &str = "configs/graphs/export_latents.yaml";

/// Makes the synthetic set if it is missing, then exports whichever index is missing.
pub fn ensure(cache: &CacheConfig, tokenizer_model: &Path, tokenizer_weights: &Path) -> Result<()> {
    cache
        .synth
        .ensure()
        .with_context(|| format!("making the synthetic set {}", cache.synth.dir.display()))?;
    // The bundle the export graph's encoder runs, whose tokenizer files the caches swap in.
    let mut bundle = None;
    for (sweeps, index) in [(true, SWEEPS_INDEX), (false, KEYFRAMES_INDEX)] {
        if cache.latents.join(index).is_file() {
            continue;
        }
        eprintln!(
            "encoding {} ({}) into {}",
            cache.synth.dir.display(),
            if sweeps { "every sweep" } else { "keyframes" },
            cache.latents.join(index).display()
        );
        let bundle = match &bundle {
            Some(name) => name,
            None => bundle.insert(graph_run::bundle_name(
                Path::new(EXPORT_GRAPH),
                &contracts::LATENT_CACHE,
            )?),
        };
        let set = [
            format!("data={}", cache.synth.dir.display()),
            format!("sweeps={sweeps}"),
            format!(
                "models.{bundle}.tokenizer.config={}",
                tokenizer_model.display()
            ),
            format!(
                "models.{bundle}.tokenizer.weights={}",
                tokenizer_weights.display()
            ),
            format!("out={}", cache.latents.display()),
            format!("index={index}"),
        ];
        let graph =
            graph_run::build_bound(Path::new(EXPORT_GRAPH), &contracts::LATENT_CACHE, &set)?;
        graph_run::run_built(graph)?;
    }
    Ok(())
}
