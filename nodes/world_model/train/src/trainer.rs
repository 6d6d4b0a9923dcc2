//! The world model's side of training: a step draws windows of the current stage, a noise
//! level and seeded noise for each, and takes the L1 loss on the future frames only (the
//! paper's), on micro-batches spread over worker threads; validation samples keyframe windows
//! with DDIM and scores each horizon against copy-last and ego-warp, computed in the same
//! place. The machinery (schedule, clipping, the weights' average, checkpoints, the
//! data-parallel step, the loop) is `bevworld_training`'s.

use bevworld_types::mean_abs_difference;
use std::path::Path;

use bevworld_blocks::init::random_values;
use bevworld_blocks::module_file::{ModuleFileError, load_module, save_module};
use bevworld_blocks::seeded_init;
use bevworld_metrics::report_file::population_std;
use bevworld_training::checkpoint::{self, CheckpointError, CheckpointState};
use bevworld_training::ema::{self, MismatchedModules};
use bevworld_training::metrics_log::MetricsLogError;
use bevworld_training::{
    Curve, NonFiniteGradient, StepReport, Trainee, Validation, WorkerPanicked, apply_gradients,
    parallel_map, replica,
};
use bevworld_types::SplitMix64;
use bevworld_world_model::ddim::noisy_and_target;
use bevworld_world_model::weights::{load_meta, load_weights};
use bevworld_world_model::{
    ActionStats, DdimConfig, ForecastInputs, LatentGrid, NoiseSchedule, WorldModel,
    WorldModelConfig, forecast,
};
use burn::module::Module;
use burn::optim::{GradientsParams, ModuleOptimizer};
use burn::prelude::*;

use crate::config::{Rate, TrainWorldModelConfig};
use crate::data::LatentSequences;
use crate::window::{WindowBatch, WindowShape, WindowValues};

/// Horizons validation reports, at keyframes (0.5 s apart).
pub const HORIZONS: usize = 6;
/// `l1_0.5s` … `l1_3.0s`: the forecast's standardised latent L1 per horizon.
pub const FORECAST_COLUMNS: [&str; HORIZONS] = [
    "l1_0.5s", "l1_1.0s", "l1_1.5s", "l1_2.0s", "l1_2.5s", "l1_3.0s",
];
/// The same L1 for `x_t` repeated.
pub const COPY_LAST_COLUMNS: [&str; HORIZONS] = [
    "copy_last_0.5s",
    "copy_last_1.0s",
    "copy_last_1.5s",
    "copy_last_2.0s",
    "copy_last_2.5s",
    "copy_last_3.0s",
];
/// The same L1 for `x_t` warped by the known ego motion.
pub const EGO_WARP_COLUMNS: [&str; HORIZONS] = [
    "ego_warp_0.5s",
    "ego_warp_1.0s",
    "ego_warp_1.5s",
    "ego_warp_2.0s",
    "ego_warp_2.5s",
    "ego_warp_3.0s",
];

/// Every column of the run's `metrics.csv`.
pub fn columns() -> Vec<&'static str> {
    let mut columns = vec![
        "step",
        "phase",
        "elapsed_s",
        "lr",
        "loss",
        "grad_norm",
        "stage",
    ];
    columns.extend(FORECAST_COLUMNS);
    columns.extend(COPY_LAST_COLUMNS);
    columns.extend(EGO_WARP_COLUMNS);
    // With `moving_weight`: the share of the step's cells it counts more.
    columns.push("moving_share");
    // With `fine_tokens`: the share of the step's coarse tokens opened into fine ones.
    columns.push("fine_share");
    columns
}

/// `RUN/curves.png`.
pub const CURVES: [Curve; 3] = [
    Curve {
        title: "training loss (L1)",
        phase: "train",
        column: "loss",
        log_scale: true,
    },
    Curve {
        title: "validation latent L1 at 1 s",
        phase: "val",
        column: "l1_1.0s",
        log_scale: false,
    },
    Curve {
        title: "validation latent L1 at 3 s",
        phase: "val",
        column: "l1_3.0s",
        log_scale: false,
    },
];

/// The files of a world-model checkpoint.
pub mod files {
    pub const MODEL: &str = "model.bpk";
    pub const OPTIMIZER: &str = "optimizer.bpk";
    pub const WEIGHT_AVERAGE: &str = "ema.bpk";
}

#[derive(Debug, thiserror::Error)]
pub enum TrainError {
    #[error(
        "step {step}: the {what} is {value}; the step was not applied and the last checkpoint is the last good state (lower optimizer.lr or optimizer.grad_clip_norm)"
    )]
    NonFinite {
        step: usize,
        what: &'static str,
        value: f64,
    },
    #[error(
        "stage '{stage}': no window of {frames} consecutive {rate:?} frames (stride {stride}) in the training cache"
    )]
    NoWindows {
        stage: String,
        frames: usize,
        rate: Rate,
        stride: usize,
    },
    #[error(
        "stage '{stage}' draws from the branched cache, but no branched latents were loaded (name `branches` in the config)"
    )]
    NoBranches { stage: String },
    #[error("no validation window of {frames} consecutive keyframes")]
    NoValidationWindows { frames: usize },
    #[error("step {step}: a micro-batch failed ({source}); the step was not applied")]
    StepWorker { step: usize, source: WorkerPanicked },
    #[error("validation failed: window {} ({source})", source.item)]
    ValidationWorker { source: WorkerPanicked },
    #[error(transparent)]
    Checkpoint(#[from] CheckpointError),
    #[error(transparent)]
    Weights(#[from] ModuleFileError),
    #[error(transparent)]
    WeightAverage(#[from] MismatchedModules),
    #[error(transparent)]
    Log(#[from] MetricsLogError),
    #[error(transparent)]
    Sampler(#[from] bevworld_world_model::ddim::DdimError),
    #[error("init: {0}")]
    Init(#[from] bevworld_world_model::weights::WorldModelWeightsError),
    #[error(
        "init {path}: its actions were normalised with other statistics ({recorded}) than this training cache's ({cache}): fine-tune on the data it was trained on"
    )]
    InitActions {
        path: std::path::PathBuf,
        recorded: String,
        cache: String,
    },
}

/// The training data, already cut where it can be.
pub struct TrainingData {
    pub sweeps: LatentSequences,
    pub keyframes: LatentSequences,
    /// The branched cache's sequences, `(sweeps, keyframes)`, for the stages `with_branches`.
    pub branches: Option<(LatentSequences, LatentSequences)>,
    /// Validation keyframe windows, cut with the model's context and future.
    pub validation: Vec<WindowValues>,
}

impl TrainingData {
    /// The sequences at `rate`.
    pub fn at_rate(&self, rate: Rate) -> &LatentSequences {
        match rate {
            Rate::Sweeps => &self.sweeps,
            Rate::Keyframes => &self.keyframes,
        }
    }

    /// The branched cache's sequences at `rate`, when loaded.
    pub fn branches_at_rate(&self, rate: Rate) -> Option<&LatentSequences> {
        let (sweeps, keyframes) = self.branches.as_ref()?;
        Some(match rate {
            Rate::Sweeps => sweeps,
            Rate::Keyframes => keyframes,
        })
    }
}

/// One window of a step, drawn before any work starts so that the draws, and so the run, do
/// not depend on how the work is spread over threads.
#[derive(Clone, Debug)]
struct Draw {
    sequence: usize,
    start: usize,
    level: usize,
    noise_seed: u64,
}

pub struct WorldModelTrainer {
    config: TrainWorldModelConfig,
    model_config: WorldModelConfig,
    schedule: NoiseSchedule,
    grid: LatentGrid,
    action_stats: ActionStats,
    data: TrainingData,
    /// Each stage's own sequences where they are not its rate's: strided, or joined with the
    /// branched cache's; `None` where they are.
    stage_sequences: Vec<Option<LatentSequences>>,
    /// Windows of each stage: `(sequence, first frame)`.
    stage_windows: Vec<Vec<(usize, usize)>>,
    device: Device,
    model: WorldModel,
    optimizer: ModuleOptimizer,
    weight_average: Option<WorldModel>,
    rng: SplitMix64,
    step: usize,
    threads: usize,
    /// The last validation's scores.
    last_scores: Option<HorizonScores>,
}

fn scalar(tensor: Tensor<1>) -> f64 {
    f64::from(tensor.into_scalar::<f32>())
}

impl WorldModelTrainer {
    /// A fresh run, the model initialised from `config.seed`; `device` is an autodiff device.
    pub fn new(
        config: TrainWorldModelConfig,
        model_config: WorldModelConfig,
        action_stats: ActionStats,
        data: TrainingData,
        device: &Device,
        threads: usize,
    ) -> Result<Self, TrainError> {
        let grid = model_config.latent_grid();
        let mut stage_windows = Vec::new();
        let mut stage_sequences = Vec::new();
        for stage in &config.stages {
            let frames = stage.context + stage.future;
            let at_rate = data.at_rate(stage.rate);
            let joined = if stage.with_branches {
                let branches =
                    data.branches_at_rate(stage.rate)
                        .ok_or_else(|| TrainError::NoBranches {
                            stage: stage.name.clone(),
                        })?;
                Some(at_rate.joined(branches))
            } else {
                None
            };
            let own = if stage.stride > 1 {
                Some(joined.as_ref().unwrap_or(at_rate).strided(stage.stride))
            } else {
                joined
            };
            let windows = own.as_ref().unwrap_or(at_rate).windows(frames);
            stage_sequences.push(own);
            if windows.is_empty() {
                return Err(TrainError::NoWindows {
                    stage: stage.name.clone(),
                    frames,
                    rate: stage.rate,
                    stride: stage.stride,
                });
            }
            stage_windows.push(windows);
        }
        if data.validation.is_empty() {
            return Err(TrainError::NoValidationWindows {
                frames: model_config.context_frames + model_config.future_frames,
            });
        }
        let model = seeded_init(config.seed, device, |d| model_config.init(d));
        let weight_average = config.ema_decay.map(|_| model.valid());
        Ok(Self {
            schedule: NoiseSchedule::new(&model_config.diffusion),
            optimizer: config.optimizer.adamw(),
            rng: SplitMix64::new(config.seed ^ 0x005e_ed0f_d1ff),
            grid,
            action_stats,
            data,
            stage_sequences,
            stage_windows,
            device: device.clone(),
            model,
            weight_average,
            step: 0,
            threads: threads.max(1),
            last_scores: None,
            config,
            model_config,
        })
    }

    /// Continues from the run's newest checkpoint: parameters, optimiser moments, step and
    /// RNG state, so the continuation equals an uninterrupted run.
    pub fn resume(mut self, run: &Path) -> Result<Self, TrainError> {
        let (checkpoint, state) = checkpoint::latest(run)?;
        let file = |name: &str| checkpoint.file(name);
        let name = self.model_config.name.clone();
        self.model = load_module(
            self.model_config.init(&self.device),
            "world model",
            &name,
            &file(files::MODEL),
        )?;
        self.optimizer = self
            .config
            .optimizer
            .adamw()
            .load(file(files::OPTIMIZER))
            .map_err(|e| checkpoint::io_error(&file(files::OPTIMIZER), format!("{e:?}")))?;
        if self.config.ema_decay.is_some() {
            let inner = self.device.clone().inner();
            self.weight_average = Some(load_module(
                self.model_config.init(&inner),
                "world model",
                &name,
                &file(files::WEIGHT_AVERAGE),
            )?);
        }
        self.step = state.step;
        self.rng = SplitMix64 {
            state: state.rng_state,
        };
        Ok(self)
    }

    /// Starts from trained weights (`init`) instead of the seeded initialisation: the model
    /// and its moving average both begin there; the optimiser's moments start at zero. The
    /// weights must be of this model, trained on `tokenizer`'s latents (name, weights digest;
    /// `None`: the latents of any tokenizer, which the fine-tune adapts them to) with
    /// `action_stats`, or the actions would be normalised otherwise than they learnt.
    ///
    /// A model with `fine_tokens` may also start from the weights of the coarse model it
    /// extends (weights of another model name): their shapes must be its coarse part's, and
    /// its fine stage keeps its seeded initialisation, whose head is zero, so the fine-tune
    /// starts as that coarse model.
    pub fn start_from(
        mut self,
        path: &Path,
        tokenizer: Option<(&str, &str)>,
        action_stats: &ActionStats,
    ) -> Result<Self, TrainError> {
        let inner = self.device.clone().inner();
        let recorded = load_meta(path)?.model;
        let fine_stage = match self.model.fine_stage() {
            Some(stage) if recorded != self.model_config.name => Some(stage.clone()),
            _ => None,
        };
        let config = match fine_stage {
            Some(_) => WorldModelConfig {
                name: recorded,
                fine_tokens: None,
                ..self.model_config.clone()
            },
            None => self.model_config.clone(),
        };
        let loaded = load_weights(&config, path, tokenizer, &inner)?;
        if !loaded.meta.action_stats.matches(action_stats) {
            let describe =
                |stats: &ActionStats| format!("{} actions, mean {:?}", stats.count, stats.mean);
            return Err(TrainError::InitActions {
                path: path.to_path_buf(),
                recorded: describe(&loaded.meta.action_stats),
                cache: describe(action_stats),
            });
        }
        let model = load_module(config.init(&self.device), "world model", &config.name, path)?;
        let average = loaded.model;
        (self.model, self.weight_average) = match fine_stage {
            Some(stage) => (
                model.with_fine_stage(stage.clone()),
                self.weight_average
                    .map(|_| average.with_fine_stage(stage.valid())),
            ),
            None => (model, self.weight_average.map(|_| average)),
        };
        Ok(self)
    }

    /// How many windows each stage draws from.
    pub fn windows_per_stage(&self) -> Vec<usize> {
        self.stage_windows.iter().map(Vec::len).collect()
    }

    pub fn last_scores(&self) -> Option<&HorizonScores> {
        self.last_scores.as_ref()
    }

    pub fn model_config(&self) -> &WorldModelConfig {
        &self.model_config
    }

    /// The weights the run ships and validates: the moving average when kept, else the last
    /// iterate; on the inner device.
    pub fn shipped_model(&self) -> WorldModel {
        self.weight_average
            .clone()
            .unwrap_or_else(|| self.model.valid())
    }

    /// One optimiser step.
    pub fn train_step(&mut self) -> Result<StepReport, TrainError> {
        let step = self.step + 1;
        let Some((stage_index, stage, stage_start)) = self.config.stage_at(self.step) else {
            return Err(TrainError::NoWindows {
                stage: "after the last stage".into(),
                frames: 0,
                rate: Rate::Keyframes,
                stride: 1,
            });
        };
        let stage = stage.clone();
        let windows = &self.stage_windows[stage_index];
        let draws: Vec<Draw> = (0..self.config.batch)
            .map(|_| {
                let (sequence, start) = windows[self.rng.below(windows.len())];
                Draw {
                    sequence,
                    start,
                    level: 1 + self.rng.below(self.schedule.steps()),
                    noise_seed: self.rng.next_u64(),
                }
            })
            .collect();
        let micro: Vec<&[Draw]> = draws.chunks(self.config.micro_batch).collect();
        let shape = WindowShape {
            context: stage.context,
            future: stage.future,
            grid: self.grid,
            base: self.model_config.ego_warp_base(),
            fine: WindowShape::fine_of(&self.model_config),
        };
        let sequences = self.stage_sequences[stage_index]
            .as_ref()
            .unwrap_or(self.data.at_rate(stage.rate));
        let (model, schedule, stats, device) = (
            &self.model,
            &self.schedule,
            &self.action_stats,
            &self.device,
        );
        let target = self.model_config.diffusion.target;
        let moving_weight = self.config.moving_weight;
        let fine = self.model_config.fine_tokens.is_some();
        let tokens_per_frame = {
            let [rows, columns] = self.model_config.token_grid();
            rows * columns
        };
        let batch = self.config.batch as f64;
        let outcomes = parallel_map(
            &micro,
            self.threads,
            || replica(model),
            |model, draws| {
                let windows: Vec<WindowValues> = draws
                    .iter()
                    .map(|d| {
                        WindowValues::cut(&sequences.sequences[d.sequence], d.start, &shape, stats)
                    })
                    .collect();
                let refs: Vec<&WindowValues> = windows.iter().collect();
                let inputs = WindowBatch::new(&refs, &shape, device);
                let dims = inputs.diffused.dims();
                let per_window: usize = dims[1..].iter().product();
                let noise: Vec<f32> = draws
                    .iter()
                    .flat_map(|d| random_values(d.noise_seed, per_window, 0.0, 1.0, true))
                    .collect();
                let noise = Tensor::<5>::from_data(TensorData::new(noise, dims), device);
                let levels: Vec<usize> = draws.iter().map(|d| d.level).collect();
                // The clean residual, before noise: where the future moves over the warp.
                let clean = inputs.diffused.clone();
                let (noisy, wanted) =
                    noisy_and_target(schedule, target, inputs.diffused, noise, &levels);
                let frame_levels: Vec<f32> = levels
                    .iter()
                    .flat_map(|&l| {
                        std::iter::repeat_n(0.0, shape.context)
                            .chain(std::iter::repeat_n(l as f32, shape.future))
                    })
                    .collect();
                let frames = Tensor::cat(vec![inputs.context, noisy], 1);
                let share = draws.len() as f64 / batch;
                // The share of coarse tokens opened into fine ones, weighted as the loss.
                let fine_share = fine.then(|| inputs.fine_tokens.share(tokens_per_frame) * share);
                let output = model.forward_selected(
                    frames,
                    inputs.actions,
                    &frame_levels,
                    shape.future,
                    Some(inputs.warped),
                    &inputs.fine_tokens,
                );
                // The mean over the batch: each micro-batch's mean weighted by its share.
                let error = (output - wanted).abs();
                let (mean, moving) = match &moving_weight {
                    Some(weight) => {
                        let moving = scalar(weight.moving_cells(clean.clone()).mean()) * share;
                        (weight.loss(error, clean), Some(moving))
                    }
                    None => (error.mean(), None),
                };
                let loss = mean.mul_scalar(share);
                let value = scalar(loss.clone());
                let grads = GradientsParams::from_grads(loss.backward(), model);
                (value, moving, fine_share, grads)
            },
        )
        .map_err(|source| TrainError::StepWorker { step, source })?;
        let loss: f64 = outcomes.iter().map(|(v, _, _, _)| v).sum();
        let moving_share: Option<f64> = outcomes.iter().map(|(_, m, _, _)| *m).sum();
        let fine_share: Option<f64> = outcomes.iter().map(|(_, _, f, _)| *f).sum();
        if !loss.is_finite() {
            return Err(TrainError::NonFinite {
                step,
                what: "loss",
                value: loss,
            });
        }
        let lr = self
            .config
            .optimizer
            .learning_rate(self.step - stage_start, stage.steps);
        let (model, grad_norm) = apply_gradients(
            self.model.clone(),
            &mut self.optimizer,
            outcomes.into_iter().map(|(_, _, _, g)| g),
            self.config.optimizer.grad_clip_norm,
            lr,
        )
        .map_err(|NonFiniteGradient(value)| TrainError::NonFinite {
            step,
            what: "gradient norm",
            value,
        })?;
        self.model = model;
        if let (Some(decay), Some(average)) = (self.config.ema_decay, self.weight_average.take()) {
            self.weight_average = Some(ema::update(average, &self.model, decay, step)?);
        }
        self.step = step;
        Ok(StepReport {
            step,
            lr,
            loss,
            grad_norm,
            terms: std::iter::once(("stage", (stage_index + 1) as f64))
                .chain(moving_share.map(|m| ("moving_share", m)))
                .chain(fine_share.map(|f| ("fine_share", f)))
                .collect(),
        })
    }

    /// Scores of `model` on the validation windows: the forecast's standardised L1 per
    /// horizon, and copy-last's and ego-warp's.
    pub fn scores(&self, model: &WorldModel) -> Result<HorizonScores, TrainError> {
        let items: Vec<&WindowValues> = self.data.validation.iter().collect();
        let per_window = score_windows(
            model,
            &self.model_config,
            &items,
            &self.config.validation.sampler,
            self.threads,
            &self.device.clone().inner(),
        )?;
        Ok(HorizonScores::mean(&per_window))
    }
}

/// Forecasts each window with `model` (DDIM with `sampler`) and scores it, on up to
/// `threads` threads; the scores come back in window order.
pub fn score_windows(
    model: &WorldModel,
    config: &WorldModelConfig,
    windows: &[&WindowValues],
    sampler: &DdimConfig,
    threads: usize,
    device: &Device,
) -> Result<Vec<HorizonScores>, TrainError> {
    let shape = WindowShape::of(config);
    let schedule = NoiseSchedule::new(&config.diffusion);
    parallel_map(
        windows,
        threads,
        || model.clone(),
        |model, window| {
            let batch = WindowBatch::new(&[*window], &shape, device);
            let inputs = ForecastInputs {
                context: batch.context,
                actions: batch.actions,
                base: shape.base.residual.then_some(batch.base),
                warped: batch.warped,
                fine_tokens: batch.fine_tokens,
            };
            let predicted: Vec<f32> = forecast(model, config, &schedule, &inputs, sampler)?
                .into_data()
                .try_to_vec()
                .unwrap_or_default();
            Ok::<_, TrainError>(HorizonScores::of_window(window, &predicted, &shape))
        },
    )
    .map_err(|source| TrainError::ValidationWorker { source })?
    .into_iter()
    .collect()
}

/// Mean absolute standardised latent error per future frame.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct HorizonScores {
    pub forecast: Vec<f64>,
    pub copy_last: Vec<f64>,
    pub ego_warp: Vec<f64>,
}

impl HorizonScores {
    /// `predicted` is `[future, C, H, W]`, the forecast latents (the base already added).
    pub fn of_window(window: &WindowValues, predicted: &[f32], shape: &WindowShape) -> Self {
        let frame = shape.grid.len();
        let current = &window.context[(shape.context - 1) * frame..shape.context * frame];
        let mut scores = Self::default();
        for k in 0..shape.future {
            let truth = &window.future[k * frame..(k + 1) * frame];
            scores.forecast.push(mean_abs_difference(
                &predicted[k * frame..(k + 1) * frame],
                truth,
            ));
            scores.copy_last.push(mean_abs_difference(current, truth));
            scores.ego_warp.push(mean_abs_difference(
                &window.warped[k * frame..(k + 1) * frame],
                truth,
            ));
        }
        scores
    }

    pub fn mean(all: &[Self]) -> Self {
        let n = all.len().max(1) as f64;
        let average = |pick: &dyn Fn(&Self) -> &Vec<f64>| -> Vec<f64> {
            let len = all.first().map_or(0, |s| pick(s).len());
            (0..len)
                .map(|k| all.iter().map(|s| pick(s)[k]).sum::<f64>() / n)
                .collect()
        };
        Self {
            forecast: average(&|s| &s.forecast),
            copy_last: average(&|s| &s.copy_last),
            ego_warp: average(&|s| &s.ego_warp),
        }
    }

    /// The scores as a Markdown table, one column per future frame (`interval_s` apart), each
    /// cell the mean or, with `spread`, mean ± spread: the one table that training and
    /// evaluation print.
    pub fn markdown(&self, spread: Option<&Self>, interval_s: f64) -> String {
        let horizons: Vec<String> = (1..=self.forecast.len())
            .map(|k| format!("+{:.1} s", interval_s * k as f64))
            .collect();
        let mut lines = vec![
            format!("| latent L1 (standardised) | {} |", horizons.join(" | ")),
            format!("|---|{}", "---|".repeat(horizons.len())),
        ];
        let spreads = |pick: fn(&Self) -> &Vec<f64>| spread.map(pick);
        for (name, means, spreads) in [
            ("world model", &self.forecast, spreads(|s| &s.forecast)),
            ("ego-warp", &self.ego_warp, spreads(|s| &s.ego_warp)),
            ("copy-last", &self.copy_last, spreads(|s| &s.copy_last)),
        ] {
            let cells: Vec<String> = means
                .iter()
                .enumerate()
                .map(|(k, m)| match spreads.and_then(|s| s.get(k)) {
                    Some(s) => format!("{m:.4} ± {s:.4}"),
                    None => format!("{m:.4}"),
                })
                .collect();
            lines.push(format!("| {name} | {} |", cells.join(" | ")));
        }
        lines.join("\n")
    }

    /// The population standard deviation of each figure over `all` (0 for one).
    pub fn spread(all: &[Self]) -> Self {
        let deviation = |pick: &dyn Fn(&Self) -> &Vec<f64>| -> Vec<f64> {
            let len = all.first().map_or(0, |s| pick(s).len());
            (0..len)
                .map(|k| {
                    let values: Vec<f64> = all.iter().map(|s| pick(s)[k]).collect();
                    population_std(&values).unwrap_or(0.0)
                })
                .collect()
        };
        Self {
            forecast: deviation(&|s| &s.forecast),
            copy_last: deviation(&|s| &s.copy_last),
            ego_warp: deviation(&|s| &s.ego_warp),
        }
    }

    /// As metrics-log scores, the first `HORIZONS` frames.
    pub fn as_scores(&self) -> Vec<(&'static str, Option<f64>)> {
        let mut scores = Vec::new();
        for (columns, values) in [
            (FORECAST_COLUMNS, &self.forecast),
            (COPY_LAST_COLUMNS, &self.copy_last),
            (EGO_WARP_COLUMNS, &self.ego_warp),
        ] {
            for (k, column) in columns.iter().enumerate() {
                scores.push((*column, values.get(k).copied()));
            }
        }
        scores
    }
}

impl Trainee for WorldModelTrainer {
    type Error = TrainError;

    fn step(&self) -> usize {
        self.step
    }

    fn train_step(&mut self) -> Result<StepReport, TrainError> {
        WorldModelTrainer::train_step(self)
    }

    fn validate(&mut self) -> Result<Vec<Validation>, TrainError> {
        let scores = self.scores(&self.shipped_model())?;
        let as_scores = scores.as_scores();
        self.last_scores = Some(scores);
        Ok(vec![Validation {
            phase: "val",
            label: if self.weight_average.is_some() {
                "the weights' moving average"
            } else {
                "the last iterate"
            },
            frames: self.data.validation.len(),
            scores: as_scores,
        }])
    }

    fn save_checkpoint(&self, run: &Path) -> Result<(), TrainError> {
        let staged = checkpoint::staging(run, self.step)?;
        let file = |name: &str| staged.file(name);
        save_module(&self.model.valid(), "world model", &file(files::MODEL))?;
        if let Some(average) = &self.weight_average {
            save_module(average, "world model", &file(files::WEIGHT_AVERAGE))?;
        }
        self.optimizer
            .save(file(files::OPTIMIZER))
            .map_err(|e| checkpoint::io_error(&file(files::OPTIMIZER), format!("{e:?}")))?;
        let state = CheckpointState {
            step: self.step,
            rng_state: self.rng.state,
        };
        checkpoint::commit(run, staged, &state, 2)?;
        Ok(())
    }
}
