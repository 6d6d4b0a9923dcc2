//! The detector's side of training: a step draws a batch of training keyframes, builds their
//! inputs (one frame, or two with the previous warped into the current) and targets, and
//! takes the heatmap, box and motion losses on micro-batches spread over worker threads;
//! validation detects on the validation set and scores it as the devkit does. The machinery
//! (schedule, clipping, checkpoints, the data-parallel step, the loop) is
//! `bevworld_training`'s.

use std::path::Path;

use bevworld_blocks::module_file::{ModuleFileError, load_module, save_module};
use bevworld_blocks::seeded_init;
use bevworld_heads::{Detector, DetectorConfig, FrameTargets, InputSpec};
use bevworld_metrics::detection::EvaluationError;
use bevworld_tokenizer::{EncoderArrays, Tokenizer, TokenizerConfig};
use bevworld_training::checkpoint::{self, CheckpointError, CheckpointState};
use bevworld_training::metrics_log::MetricsLogError;
use bevworld_training::{
    Curve, NonFiniteGradient, Part, StepReport, Trainee, Validation, WorkerPanicked,
    apply_gradients, apply_gradients_in_two, parallel_map, replica,
};
use bevworld_types::SplitMix64;
use burn::module::Module;
use burn::optim::{GradientsParams, ModuleOptimizer};
use burn::prelude::*;

use crate::config::TrainDetectorConfig;
use crate::data::{DataError, DetectionSet};
use crate::encoder::{encode_maps, encoded_batch};
use crate::evaluate::{Evaluation, evaluate_set, input_batch, predict};

/// Every column of the run's `metrics.csv`.
pub fn columns() -> Vec<&'static str> {
    vec![
        "step",
        "phase",
        "elapsed_s",
        "lr",
        "loss",
        "grad_norm",
        "loss_heatmap",
        "loss_boxes",
        "loss_motion",
        "nds",
        "map",
        "mate",
        "mase",
        "maoe",
        "mave",
        "maae",
        "min_ade",
        "min_fde",
        "miss_rate",
        "cv_ade",
        "cv_fde",
    ]
}

/// `RUN/curves.png`.
pub const CURVES: [Curve; 3] = [
    Curve {
        title: "training loss",
        phase: "train",
        column: "loss",
        log_scale: true,
    },
    Curve {
        title: "validation NDS",
        phase: "val",
        column: "nds",
        log_scale: false,
    },
    Curve {
        title: "validation minADE (m)",
        phase: "val",
        column: "min_ade",
        log_scale: false,
    },
];

/// The files of a detector checkpoint.
pub mod files {
    pub const MODEL: &str = "model.bpk";
    pub const OPTIMIZER: &str = "optimizer.bpk";
    /// With the encoder in the loop: the tokenizer being trained, and its optimiser.
    pub const ENCODER: &str = "encoder.bpk";
    pub const ENCODER_OPTIMIZER: &str = "encoder-optimizer.bpk";
}

/// The encoder trained with the heads (`--init tokenizer|scratch`): the tokenizer whose
/// product the detector reads, its own optimiser at a fraction of the heads' rate, and every
/// training and validation keyframe's encoder inputs.
pub struct EncoderInLoop {
    pub config: TokenizerConfig,
    /// On the trainer's autodiff device.
    pub tokenizer: Tokenizer,
    /// The encoder's learning rate as a fraction of the heads'.
    pub lr_fraction: f64,
    pub train: Vec<EncoderArrays>,
    pub val: Vec<EncoderArrays>,
    optimizer: ModuleOptimizer,
}

impl EncoderInLoop {
    pub fn new(
        config: TokenizerConfig,
        tokenizer: Tokenizer,
        optimizer: ModuleOptimizer,
        lr_fraction: f64,
        train: Vec<EncoderArrays>,
        val: Vec<EncoderArrays>,
    ) -> Self {
        Self {
            config,
            tokenizer,
            lr_fraction,
            train,
            val,
            optimizer,
        }
    }
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
    #[error("the training set has no keyframe")]
    NoFrames,
    #[error("step {step}: a micro-batch failed ({source}); the step was not applied")]
    StepWorker { step: usize, source: WorkerPanicked },
    #[error("detecting on the validation set failed: {0}")]
    Predict(WorkerPanicked),
    #[error(transparent)]
    Evaluation(#[from] EvaluationError),
    #[error("the encoder's maps: {0}")]
    Encoder(#[from] DataError),
    #[error(transparent)]
    Checkpoint(#[from] CheckpointError),
    #[error(transparent)]
    Weights(#[from] ModuleFileError),
    #[error(transparent)]
    Log(#[from] MetricsLogError),
}

pub struct DetectorTrainer {
    config: TrainDetectorConfig,
    detector: DetectorConfig,
    input: InputSpec,
    train: DetectionSet,
    val: DetectionSet,
    /// Each training frame's targets, built once.
    targets: Vec<FrameTargets>,
    device: Device,
    model: Detector,
    optimizer: ModuleOptimizer,
    rng: SplitMix64,
    step: usize,
    threads: usize,
    last: Option<Evaluation>,
    encoder: Option<EncoderInLoop>,
}

fn scalar(tensor: Tensor<1>) -> f64 {
    f64::from(tensor.into_scalar::<f32>())
}

impl DetectorTrainer {
    /// A fresh run, the detector initialised from `config.seed`; `device` is an autodiff
    /// device.
    pub fn new(
        config: TrainDetectorConfig,
        detector: DetectorConfig,
        input: InputSpec,
        train: DetectionSet,
        val: DetectionSet,
        device: &Device,
        threads: usize,
    ) -> Result<Self, TrainError> {
        if train.frames.is_empty() {
            return Err(TrainError::NoFrames);
        }
        let output_grid = detector.output_grid(&input);
        let targets = train
            .frames
            .iter()
            .map(|frame| detector.targets(&output_grid, &frame.agents))
            .collect();
        let model = seeded_init(config.seed, device, |d| detector.init(&input, d));
        Ok(Self {
            optimizer: config.optimizer.adamw(),
            rng: SplitMix64::new(config.seed ^ 0x0de7_ec70),
            device: device.clone(),
            model,
            step: 0,
            threads: threads.max(1),
            last: None,
            encoder: None,
            targets,
            train,
            val,
            input,
            detector,
            config,
        })
    }

    /// Continues from the run's newest checkpoint: parameters, optimiser moments, step and
    /// RNG state, so the continuation equals an uninterrupted run.
    pub fn resume(mut self, run: &Path) -> Result<Self, TrainError> {
        let (checkpoint, state) = checkpoint::latest(run)?;
        let file = |name: &str| checkpoint.file(name);
        self.model = load_module(
            self.detector.init(&self.input, &self.device),
            "detector",
            &self.detector.name,
            &file(files::MODEL),
        )?;
        self.optimizer = self
            .config
            .optimizer
            .adamw()
            .load(file(files::OPTIMIZER))
            .map_err(|e| checkpoint::io_error(&file(files::OPTIMIZER), format!("{e:?}")))?;
        if let Some(encoder) = self.encoder.as_mut() {
            encoder.tokenizer = load_module(
                encoder.config.init(&self.device),
                "tokenizer",
                &encoder.config.name,
                &file(files::ENCODER),
            )?;
            encoder.optimizer = self
                .config
                .optimizer
                .adamw()
                .load(file(files::ENCODER_OPTIMIZER))
                .map_err(|e| {
                    checkpoint::io_error(&file(files::ENCODER_OPTIMIZER), format!("{e:?}"))
                })?;
        }
        self.step = state.step;
        self.rng = SplitMix64 {
            state: state.rng_state,
        };
        Ok(self)
    }

    /// Trains `encoder` with the heads: each step's input is its product, not the exported
    /// maps, and validation detects on the maps it makes of the validation set.
    pub fn with_encoder(mut self, encoder: EncoderInLoop) -> Self {
        self.encoder = Some(encoder);
        self
    }

    pub fn input(&self) -> &InputSpec {
        &self.input
    }

    /// The encoder's weights as they stand, on the inner device, if it trains.
    pub fn shipped_encoder(&self) -> Option<Tokenizer> {
        self.encoder.as_ref().map(|e| e.tokenizer.valid())
    }

    pub fn last_evaluation(&self) -> Option<&Evaluation> {
        self.last.as_ref()
    }

    /// The weights as they stand, on the inner device.
    pub fn shipped_model(&self) -> Detector {
        self.model.valid()
    }

    /// One optimiser step.
    pub fn train_step(&mut self) -> Result<StepReport, TrainError> {
        let step = self.step + 1;
        let frames = self.train.frames.len();
        let draws: Vec<usize> = (0..self.config.batch)
            .map(|_| self.rng.below(frames))
            .collect();
        let micro: Vec<&[usize]> = draws.chunks(self.config.micro_batch.max(1)).collect();
        let (model, device, input, detector, targets, weights) = (
            &self.model,
            &self.device,
            &self.input,
            &self.detector,
            &self.targets,
            &self.config.loss,
        );
        let set_frames = &self.train.frames;
        let encoder = self.encoder.as_ref();
        let batch = self.config.batch as f64;
        let outcomes = parallel_map(
            &micro,
            self.threads,
            || (replica(model), encoder.map(|e| replica(&e.tokenizer))),
            |(model, tokenizer), draws| {
                let tensor = match (tokenizer, encoder) {
                    (Some(tokenizer), Some(encoder)) => {
                        encoded_batch(tokenizer, input, set_frames, &encoder.train, draws, device)
                    }
                    _ => input_batch(input, set_frames, draws, device),
                };
                let outputs = model.forward(tensor);
                let frame_targets: Vec<&FrameTargets> =
                    draws.iter().map(|&i| &targets[i]).collect();
                let loss = detector.loss(outputs, &frame_targets, weights);
                // The mean over the batch: each micro-batch's mean weighted by its share.
                let share = draws.len() as f64 / batch;
                let terms = [
                    scalar(loss.heatmap) * share,
                    scalar(loss.boxes) * share,
                    scalar(loss.motion) * share,
                ];
                let total = loss.total.mul_scalar(share);
                let value = scalar(total.clone());
                let mut grads = total.backward();
                let heads = GradientsParams::from_module(&mut grads, model);
                let encoder_grads = tokenizer
                    .as_ref()
                    .map(|tokenizer| GradientsParams::from_module(&mut grads, tokenizer));
                (value, terms, heads, encoder_grads)
            },
        )
        .map_err(|source| TrainError::StepWorker { step, source })?;
        let loss: f64 = outcomes.iter().map(|(v, _, _, _)| v).sum();
        let mut terms = [0.0; 3];
        for (_, t, _, _) in &outcomes {
            for k in 0..3 {
                terms[k] += t[k];
            }
        }
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
            .learning_rate(self.step, self.config.steps);
        let refused = |NonFiniteGradient(value)| TrainError::NonFinite {
            step,
            what: "gradient norm",
            value,
        };
        let max_norm = self.config.optimizer.grad_clip_norm;
        let (heads, encoder_grads): (Vec<_>, Vec<_>) =
            outcomes.into_iter().map(|(_, _, h, e)| (h, e)).unzip();
        let (model, grad_norm) = match self.encoder.as_mut() {
            Some(encoder) => {
                let (model, tokenizer, norm) = apply_gradients_in_two(
                    Part {
                        model: self.model.clone(),
                        optimizer: &mut self.optimizer,
                        grads: heads,
                        lr,
                    },
                    Part {
                        model: encoder.tokenizer.clone(),
                        optimizer: &mut encoder.optimizer,
                        grads: encoder_grads.into_iter().flatten().collect(),
                        lr: lr * encoder.lr_fraction,
                    },
                    max_norm,
                )
                .map_err(refused)?;
                encoder.tokenizer = tokenizer;
                (model, norm)
            }
            None => apply_gradients(self.model.clone(), &mut self.optimizer, heads, max_norm, lr)
                .map_err(refused)?,
        };
        self.model = model;
        self.step = step;
        Ok(StepReport {
            step,
            lr,
            loss,
            grad_norm,
            terms: vec![
                ("loss_heatmap", terms[0]),
                ("loss_boxes", terms[1]),
                ("loss_motion", terms[2]),
            ],
        })
    }

    /// Scores of `model` on `set`.
    pub fn evaluate(&self, model: &Detector, set: &DetectionSet) -> Result<Evaluation, TrainError> {
        let detections = predict(
            model,
            &self.detector,
            &self.input,
            set,
            self.threads,
            &self.device.clone().inner(),
        )
        .map_err(TrainError::Predict)?;
        Ok(evaluate_set(&self.detector, set, &detections)?)
    }
}

impl Trainee for DetectorTrainer {
    type Error = TrainError;

    fn step(&self) -> usize {
        self.step
    }

    fn train_step(&mut self) -> Result<StepReport, TrainError> {
        DetectorTrainer::train_step(self)
    }

    fn validate(&mut self) -> Result<Vec<Validation>, TrainError> {
        if let Some(encoder) = &self.encoder {
            let inference = self.device.clone().inner();
            let tokenizer = encoder.tokenizer.valid();
            encode_maps(
                &tokenizer,
                self.input.kind,
                &mut self.val,
                &encoder.val,
                &inference,
            )?;
        }
        let evaluation = self.evaluate(&self.shipped_model(), &self.val)?;
        let scores = evaluation.as_scores();
        let frames = evaluation.frames;
        self.last = Some(evaluation);
        Ok(vec![Validation {
            phase: "val",
            label: "the last iterate",
            frames,
            scores,
        }])
    }

    fn save_checkpoint(&self, run: &Path) -> Result<(), TrainError> {
        let staged = checkpoint::staging(run, self.step)?;
        let file = |name: &str| staged.file(name);
        save_module(&self.model.valid(), "detector", &file(files::MODEL))?;
        self.optimizer
            .save(file(files::OPTIMIZER))
            .map_err(|e| checkpoint::io_error(&file(files::OPTIMIZER), format!("{e:?}")))?;
        if let Some(encoder) = &self.encoder {
            save_module(
                &encoder.tokenizer.valid(),
                "tokenizer",
                &file(files::ENCODER),
            )?;
            encoder
                .optimizer
                .save(file(files::ENCODER_OPTIMIZER))
                .map_err(|e| {
                    checkpoint::io_error(&file(files::ENCODER_OPTIMIZER), format!("{e:?}"))
                })?;
        }
        let state = CheckpointState {
            step: self.step,
            rng_state: self.rng.state,
        };
        checkpoint::commit(run, staged, &state, 2)?;
        Ok(())
    }
}
