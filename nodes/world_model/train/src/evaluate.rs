//! A world model's forecasts scored on a held-out cache: every keyframe window of every
//! scene, the standardised latent L1 per horizon beside copy-last and ego-warp, as a mean over
//! scenes with its spread, so that a figure says how much it moves from scene to scene.

use std::path::Path;

use bevworld_world_model::weights::load_weights;
use bevworld_world_model::{DdimConfig, WorldModelConfig};
use burn::prelude::*;

use crate::config::{CacheConfig, KEYFRAMES_INDEX, TrainWorldModelConfig};
use crate::data::load_sequences;
use crate::run::{RunError, tokenizer_identity};
use crate::trainer::{HorizonScores, score_windows};
use crate::window::{WindowShape, WindowValues};

/// Scores on one cache.
#[derive(Clone, Debug)]
pub struct Evaluation {
    /// Each scene's mean over its windows.
    pub scenes: Vec<(String, HorizonScores)>,
    /// The mean over scenes.
    pub mean: HorizonScores,
    /// The standard deviation over scenes (population).
    pub spread: HorizonScores,
    pub windows: usize,
}

/// Scores the weights at `weights` (the model `model_config`, trained with the run config
/// `config`) on `cache`'s keyframe windows; `stride` keeps every n-th window of a scene.
#[allow(clippy::too_many_arguments)]
pub fn evaluate(
    config: &TrainWorldModelConfig,
    model_config: &WorldModelConfig,
    weights: &Path,
    cache: &CacheConfig,
    sampler: &DdimConfig,
    stride: usize,
    threads: usize,
    device: &Device,
) -> Result<Evaluation, RunError> {
    let tokenizer = tokenizer_identity(&config.tokenizer_weights)?;
    let loaded = load_weights(
        model_config,
        weights,
        Some((&tokenizer.model, &tokenizer.weights_hash)),
        device,
    )?;
    let expected = tokenizer.expected(model_config, config.gap_factor);
    let sequences = load_sequences(&cache.latents, KEYFRAMES_INDEX, &expected)?;
    let shape = WindowShape::of(model_config);
    let frames = shape.context + shape.future;
    let mut scene_of = Vec::new();
    let mut windows = Vec::new();
    for (s, start) in sequences.windows(frames).into_iter().step_by(stride.max(1)) {
        let sequence = &sequences.sequences[s];
        scene_of.push(sequence.scene.clone());
        windows.push(WindowValues::cut(
            sequence,
            start,
            &shape,
            &loaded.meta.action_stats,
        ));
    }
    let items: Vec<&WindowValues> = windows.iter().collect();
    let scores = score_windows(
        &loaded.model,
        model_config,
        &items,
        sampler,
        threads,
        device,
    )?;
    let mut scenes: Vec<(String, Vec<HorizonScores>)> = Vec::new();
    for (scene, score) in scene_of.into_iter().zip(scores) {
        match scenes.last_mut() {
            Some((name, list)) if *name == scene => list.push(score),
            _ => scenes.push((scene, vec![score])),
        }
    }
    let scenes: Vec<(String, HorizonScores)> = scenes
        .into_iter()
        .map(|(name, list)| (name, HorizonScores::mean(&list)))
        .collect();
    let per_scene: Vec<HorizonScores> = scenes.iter().map(|(_, s)| s.clone()).collect();
    Ok(Evaluation {
        mean: HorizonScores::mean(&per_scene),
        spread: HorizonScores::spread(&per_scene),
        scenes,
        windows: windows.len(),
    })
}
