//! The world model's latent caches: a synthetic set encoded with the tokenizer through the
//! export graph (`configs/graphs/export_latents.yaml`), the same path and files a user's
//! export takes. Once at 12 Hz (`index.json`) and once at keyframes (`index-keyframes.json`)
//! into the same folder; a keyframe's file is written by the first pass and kept by the second.

use std::path::Path;

use anyhow::{Context, Result};
use bevworld_world_model_train::CacheConfig;
use bevworld_world_model_train::config::{KEYFRAMES_INDEX, SWEEPS_INDEX};

/// The graph the caches are exported with.
pub const EXPORT_GRAPH: &str = "configs/graphs/export_latents.yaml";

/// Makes the synthetic set if it is missing, then exports whichever index is missing.
pub fn ensure(cache: &CacheConfig, tokenizer_model: &Path, tokenizer_weights: &Path) -> Result<()> {
    cache
        .synth
        .ensure()
        .with_context(|| format!("making the synthetic set {}", cache.synth.dir.display()))?;
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
        let set = [
            format!("source.data={}", cache.synth.dir.display()),
            format!("source.sweeps={sweeps}"),
            format!("encode.model={}", tokenizer_model.display()),
            format!("encode.weights={}", tokenizer_weights.display()),
            format!("export.out={}", cache.latents.display()),
            format!("export.index={index}"),
        ];
        run_export(&set)?;
    }
    Ok(())
}

fn run_export(set: &[String]) -> Result<()> {
    crate::commands::graph_run::run_graph(Path::new(EXPORT_GRAPH), set).map(|_| ())
}
