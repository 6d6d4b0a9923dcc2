//! A whole world-model run, as `bevworld train world-model` asks for one: the configs, the
//! tokenizer the latents must come from, the latent caches, the action statistics, the
//! validation windows, the loop (`bevworld_training::run_loop`) over the stages, and the
//! shipped weights with their metadata and curves. The command line parses flags, exports the
//! caches through the graph, and prints.

use std::path::{Path, PathBuf};
use std::time::Instant;

use bevworld_training::checkpoint;
use bevworld_training::curves::CurvesError;
use bevworld_training::metrics_log::MetricsLogError;
use bevworld_training::{LoopPlan, MetricsLog, Observer, Trainee, plot_curves, run_loop};
use bevworld_types::file_digest;
use bevworld_types::{LatentStatsFile, StatsFileError, stats_path_for};
use bevworld_world_model::FineTokenRule;
use bevworld_world_model::config::ConfigError as ModelConfigError;
use bevworld_world_model::weights::{WorldModelWeightsError, save_weights};
use bevworld_world_model::{ActionStats, Target, WeightsMeta, WorldModelConfig};
use burn::prelude::*;

use crate::config::{
    CacheConfig, ConfigError, KEYFRAMES_INDEX, SWEEPS_INDEX, TrainWorldModelConfig,
};
use crate::data::{DataError, Expected, LatentSequences, load_sequences};
use crate::moving_weight::MovingWeight;
use crate::trainer::{CURVES, HorizonScores, TrainError, TrainingData, WorldModelTrainer, columns};
use crate::window::{WindowShape, WindowValues};

/// One run, as asked for.
#[derive(Clone, Debug, PartialEq)]
pub struct TrainRequest {
    pub config: PathBuf,
    /// The run folder: checkpoints, `metrics.csv`, `curves.png`, the weights at the end.
    pub out: PathBuf,
    pub resume: bool,
    /// Stop after this step, keeping the config's stages and schedules.
    pub until: Option<usize>,
    pub threads: Option<usize>,
    pub log_every: usize,
    /// The command line, recorded in the weights' metadata.
    pub command: String,
    pub overrides: Overrides,
}

/// What an ablation changes in the configs. The effective configs are written into the run
/// folder, so `eval world-model --model RUN/model-config.yaml` reads the weights back.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Overrides {
    /// The diffusion target; `epsilon` also turns zero terminal SNR off, under which it cannot
    /// be sampled.
    pub target: Option<Target>,
    pub residual_over_ego_warp: Option<bool>,
    /// `ego_warp_fade_s`: `Some(None)` removes the fade.
    pub ego_warp_fade_s: Option<Option<f64>>,
    pub ego_warp_input: Option<bool>,
    /// The stages kept, numbered from 1 (e.g. `[3]`: the long-sequence stage alone).
    pub stages: Option<Vec<usize>>,
    /// Steps of each kept stage.
    pub stage_steps: Option<Vec<usize>>,
    /// The trained weights a fine-tune starts from, in place of the config's `init`.
    pub init: Option<PathBuf>,
    /// The loss weighted where the residual moves, in place of the config's `moving_weight`.
    pub moving_weight: Option<MovingWeight>,
    /// Which tokens a model with fine tokens opens, in place of its `fine_tokens.select`.
    pub fine_select: Option<FineTokenRule>,
}

/// The configs as this run trains them: the files', then the overrides, checked again.
pub fn effective_configs(
    request: &TrainRequest,
) -> Result<(TrainWorldModelConfig, WorldModelConfig), RunError> {
    let mut config = TrainWorldModelConfig::from_yaml_file(&request.config)?;
    let mut model = WorldModelConfig::from_yaml_file(&config.model)?;
    let set = &request.overrides;
    if let Some(init) = &set.init {
        config.init = Some(init.clone());
    }
    if let Some(weight) = set.moving_weight {
        config.moving_weight = Some(weight);
    }
    if let Some(target) = set.target {
        model.diffusion.target = target;
        if target == Target::Epsilon {
            model.diffusion.zero_terminal_snr = false;
        }
    }
    if let Some(residual) = set.residual_over_ego_warp {
        model.residual_over_ego_warp = residual;
    }
    if let Some(fade) = set.ego_warp_fade_s {
        model.ego_warp_fade_s = fade;
    }
    if let Some(input) = set.ego_warp_input {
        model.ego_warp_input = input;
    }
    if let Some(rule) = set.fine_select {
        let Some(fine) = model.fine_tokens.as_mut() else {
            return Err(RunError::Override {
                flag: "--fine-select",
                message: format!(
                    "the model '{}' has no fine tokens (fine_tokens in its config)",
                    model.name
                ),
            });
        };
        fine.select = rule;
    }
    if let Some(kept) = &set.stages {
        let mut stages = Vec::new();
        for &number in kept {
            let stage = number
                .checked_sub(1)
                .and_then(|i| config.stages.get(i))
                .ok_or_else(|| RunError::Override {
                    flag: "--stages",
                    message: format!(
                        "stage {number} does not exist (the config has {})",
                        config.stages.len()
                    ),
                })?;
            stages.push(stage.clone());
        }
        config.stages = stages;
    }
    if let Some(steps) = &set.stage_steps {
        if steps.len() != config.stages.len() {
            return Err(RunError::Override {
                flag: "--stage-steps",
                message: format!(
                    "{} step counts for {} stages",
                    steps.len(),
                    config.stages.len()
                ),
            });
        }
        for (stage, &n) in config.stages.iter_mut().zip(steps) {
            stage.steps = n;
        }
    }
    let problems: Vec<String> = config
        .problems()
        .iter()
        .chain(&model.problems())
        .map(ToString::to_string)
        .collect();
    if !problems.is_empty() {
        return Err(RunError::Override {
            flag: "the overrides",
            message: problems.join("; "),
        });
    }
    // The weight reads the residual over the warp; a model of the latent itself has none.
    if config.moving_weight.is_some() && !model.residual_over_ego_warp {
        return Err(RunError::Config(ConfigError::Invalid {
            path: request.config.display().to_string(),
            problems: vec![bevworld_training::ConfigProblem::new(
                "moving_weight",
                format!(
                    "model '{}' predicts latents, not a residual over the ego warp: there is no moving residual to weight",
                    model.name
                ),
            )],
        }));
    }
    Ok((config, model))
}

#[derive(Debug, thiserror::Error)]
pub enum RunError {
    #[error(transparent)]
    Config(#[from] ConfigError),
    #[error(transparent)]
    ModelConfig(#[from] ModelConfigError),
    #[error(
        "{run} already holds checkpoints: pass --resume to continue that run, or choose another --out"
    )]
    Exists { run: PathBuf },
    #[error("{path}: {message}")]
    Tokenizer { path: PathBuf, message: String },
    #[error(transparent)]
    Stats(#[from] StatsFileError),
    #[error(transparent)]
    Data(#[from] DataError),
    #[error("actions of the training cache: {0}")]
    Actions(#[from] bevworld_world_model::actions::ActionStatsError),
    #[error(transparent)]
    Train(#[from] TrainError),
    #[error(transparent)]
    Weights(#[from] WorldModelWeightsError),
    #[error(transparent)]
    Log(#[from] MetricsLogError),
    #[error(transparent)]
    Curves(#[from] CurvesError),
    #[error("--until 0: a run of no steps would ship untrained weights")]
    NoSteps,
    #[error("{flag}: {message}")]
    Override { flag: &'static str, message: String },
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
}

impl From<checkpoint::CheckpointError> for RunError {
    fn from(error: checkpoint::CheckpointError) -> Self {
        Self::Train(TrainError::Checkpoint(error))
    }
}

/// The tokenizer whose latents a run learns: its name (from its statistics file) and the
/// digest of its weights, which the statistics file and every cached latent must carry.
#[derive(Clone, Debug, PartialEq)]
pub struct TokenizerIdentity {
    pub model: String,
    pub weights_hash: String,
    pub stats: LatentStatsFile,
}

impl TokenizerIdentity {
    /// What a cache of this tokenizer's latents must hold for `model`.
    pub fn expected(&self, model: &WorldModelConfig, gap_factor: f64) -> Expected {
        let grid = model.latent_grid();
        Expected {
            model: self.model.clone(),
            weights_hash: self.weights_hash.clone(),
            shape: [grid.channels, grid.height, grid.width],
            stats: self.stats.stats.clone(),
            gap_factor,
        }
    }
}

/// Reads the tokenizer's weights digest and its statistics file, refusing statistics made
/// with other weights.
pub fn tokenizer_identity(weights: &Path) -> Result<TokenizerIdentity, RunError> {
    let weights_hash = file_digest(weights).map_err(|e| RunError::Tokenizer {
        path: weights.to_path_buf(),
        message: format!("cannot read the tokenizer weights: {e}"),
    })?;
    let stats_path = stats_path_for(weights);
    let stats = LatentStatsFile::load(&stats_path)?;
    stats.check_matches(&stats.model, &weights_hash, &stats_path)?;
    Ok(TokenizerIdentity {
        model: stats.model.clone(),
        weights_hash,
        stats,
    })
}

/// Whether a cache holds both of its indexes.
pub fn cache_is_complete(cache: &CacheConfig) -> bool {
    cache.latents.join(SWEEPS_INDEX).is_file() && cache.latents.join(KEYFRAMES_INDEX).is_file()
}

/// What a finished run wrote and measured.
#[derive(Clone, Debug)]
pub struct TrainSummary {
    pub steps: usize,
    pub minutes: f64,
    pub weights: PathBuf,
    pub log: PathBuf,
    pub curves: PathBuf,
    pub scores: HorizonScores,
    pub action_stats: ActionStats,
    pub train_frames: (usize, usize),
    pub gaps: usize,
}

/// What a run reports as it goes, beside each step and validation.
pub trait Progress: Observer {
    fn prepared(&mut self, _message: &str) {}
    fn started(&mut self, _step: usize, _stop: usize, _resumed: bool) {}
}

impl Progress for () {}

fn io(path: &Path) -> impl Fn(std::io::Error) -> RunError + '_ {
    move |source| RunError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// `count` windows spread evenly over every window of `frames` frames.
fn spread_windows(sequences: &LatentSequences, frames: usize, count: usize) -> Vec<(usize, usize)> {
    let all = sequences.windows(frames);
    if all.len() <= count {
        return all;
    }
    (0..count).map(|i| all[i * all.len() / count]).collect()
}

/// Trains the world model on `device` (autodiff is added here); the caches must exist
/// (`cache_is_complete`).
pub fn train(
    request: &TrainRequest,
    device: &Device,
    progress: &mut dyn Progress,
) -> Result<TrainSummary, RunError> {
    let (config, model_config) = effective_configs(request)?;
    if request.until == Some(0) {
        return Err(RunError::NoSteps);
    }
    let has_checkpoint = existing_checkpoint(request)?;
    let device = device.clone().autodiff();
    let device = &device;
    let tokenizer = tokenizer_identity(&config.tokenizer_weights)?;
    let prepared = prepare_data(&config, &model_config, &tokenizer)?;
    progress.prepared(&prepared.description);
    write_configs(&request.out, &config, &model_config)?;
    let threads = request
        .threads
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, std::num::NonZero::get));
    let action_stats = prepared.action_stats.clone();
    let mut trainer = WorldModelTrainer::new(
        config.clone(),
        model_config.clone(),
        action_stats.clone(),
        prepared.data,
        device,
        threads,
    )?;
    if request.resume && has_checkpoint {
        trainer = trainer.resume(&request.out)?;
    } else if let Some(init) = &config.init {
        // Weights of another tokenizer's latents only where the config says so.
        let pairing = (!config.init_from_other_tokenizer)
            .then_some((tokenizer.model.as_str(), tokenizer.weights_hash.as_str()));
        trainer = trainer.start_from(init, pairing, &action_stats)?;
    }
    let total = config.total_steps();
    let stop = request.until.unwrap_or(total).min(total);
    let resumed_at = trainer.step();
    progress.started(resumed_at, stop, request.resume && has_checkpoint);
    let mut log = MetricsLog::open(
        &request.out,
        &columns(),
        (resumed_at > 0).then_some(resumed_at),
    )?;
    let started = Instant::now();
    let plan = LoopPlan {
        stop,
        log_every: request.log_every.max(1),
        validate_every: config.validation.every,
        checkpoint_every: config.checkpoint_every,
    };
    let last = run_loop(
        &mut trainer,
        &request.out,
        plan,
        &mut log,
        started,
        progress,
    )?;
    // The loop validates at its last step; a run resumed at its end validates here.
    let scores = match (last, trainer.last_scores()) {
        (Some(_), Some(scores)) => scores.clone(),
        _ => trainer.scores(&trainer.shipped_model())?,
    };
    let weights = request.out.join(format!("{}.bpk", model_config.name));
    let meta = WeightsMeta {
        model: model_config.name.clone(),
        tokenizer_model: tokenizer.model.clone(),
        tokenizer_weights_hash: tokenizer.weights_hash.clone(),
        action_stats: action_stats.clone(),
        steps: trainer.step(),
        command: request.command.clone(),
    };
    save_weights(&trainer.shipped_model(), &meta, &weights)?;
    let curves = request.out.join("curves.png");
    plot_curves(log.path(), &curves, &CURVES)?;
    Ok(TrainSummary {
        steps: trainer.step(),
        minutes: started.elapsed().as_secs_f64() / 60.0,
        weights,
        log: log.path().to_path_buf(),
        curves,
        scores,
        action_stats,
        train_frames: prepared.train_frames,
        gaps: prepared.gaps,
    })
}

/// Whether the run folder holds a checkpoint to resume. A checkpoint that fails its checks is
/// still a run's: never start over it, and refuse to resume from it before any data load.
fn existing_checkpoint(request: &TrainRequest) -> Result<bool, RunError> {
    match (checkpoint::latest(&request.out), request.resume) {
        (Err(checkpoint::CheckpointError::None { .. }), _) => Ok(false),
        (Ok(_), true) => Ok(true),
        (_, false) => Err(RunError::Exists {
            run: request.out.clone(),
        }),
        (Err(error), true) => Err(error.into()),
    }
}

/// What a run learns from, read from the caches.
struct PreparedData {
    data: TrainingData,
    /// The keyframe actions' statistics, which the model's actions are normalised with.
    action_stats: ActionStats,
    /// Training frames: (sweeps, keyframes).
    train_frames: (usize, usize),
    /// Time gaps the sequences were split at.
    gaps: usize,
    /// One line for the progress report.
    description: String,
}

/// The training caches (sweeps, keyframes, and the branched cache's when a stage uses it) and
/// the validation windows, each checked to hold the latents of `tokenizer` for the model.
fn prepare_data(
    config: &TrainWorldModelConfig,
    model_config: &WorldModelConfig,
    tokenizer: &TokenizerIdentity,
) -> Result<PreparedData, RunError> {
    let expected = tokenizer.expected(model_config, config.gap_factor);
    let sweeps = load_sequences(&config.train.latents, SWEEPS_INDEX, &expected)?;
    let keyframes = load_sequences(&config.train.latents, KEYFRAMES_INDEX, &expected)?;
    let val = load_sequences(&config.val.latents, KEYFRAMES_INDEX, &expected)?;
    let branches = match config.branches_in_use() {
        Some(cache) => Some((
            load_sequences(&cache.latents, SWEEPS_INDEX, &expected)?,
            load_sequences(&cache.latents, KEYFRAMES_INDEX, &expected)?,
        )),
        None => None,
    };
    // The model runs at keyframes: its actions are normalised with the keyframe actions'
    // statistics.
    let action_stats = ActionStats::compute(keyframes.actions().iter())?;
    let shape = WindowShape::of(model_config);
    let validation: Vec<WindowValues> = spread_windows(
        &val,
        shape.context + shape.future,
        config.validation.windows,
    )
    .into_iter()
    .map(|(s, start)| WindowValues::cut(&val.sequences[s], start, &shape, &action_stats))
    .collect();
    let train_frames = (sweeps.frames(), keyframes.frames());
    let gaps = sweeps.gaps + keyframes.gaps + val.gaps;
    let branched = branches
        .as_ref()
        .map_or(String::new(), |(sweeps, keyframes)| {
            format!(
                ", and {} branched sweeps ({} scenes)",
                sweeps.frames(),
                keyframes.sequences.len()
            )
        });
    let description = format!(
        "{} sweeps and {} keyframes to learn from ({} scenes){branched}, {} validation windows; {} gaps split",
        train_frames.0,
        train_frames.1,
        keyframes.sequences.len(),
        validation.len(),
        gaps
    );
    Ok(PreparedData {
        data: TrainingData {
            sweeps,
            keyframes,
            branches,
            validation,
        },
        action_stats,
        train_frames,
        gaps,
        description,
    })
}

/// The configs as trained, overrides applied, into the run folder (for `eval world-model
/// --model`).
fn write_configs(
    out: &Path,
    config: &TrainWorldModelConfig,
    model_config: &WorldModelConfig,
) -> Result<(), RunError> {
    std::fs::create_dir_all(out).map_err(io(out))?;
    let written = |name: &str, text: Result<String, String>| -> Result<(), RunError> {
        let target = out.join(name);
        let text = text.map_err(|message| RunError::Override {
            flag: "the overrides",
            message,
        })?;
        bevworld_atomic_file::write(&target, text.as_bytes()).map_err(io(&target))
    };
    written(
        "train-config.yaml",
        serde_saphyr::to_string(config).map_err(|e| e.to_string()),
    )?;
    written(
        "model-config.yaml",
        serde_saphyr::to_string(model_config).map_err(|e| e.to_string()),
    )
}
