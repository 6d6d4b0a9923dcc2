//! The training loop of one tokenizer: a step draws a frame, renders the step's rays (whole
//! cameras for the RGB upsampler, a random subset of LiDAR rays), takes the loss terms
//! (`terms.rs`) and, after `gan_start`, the adversarial term, clips the global gradient norm and
//! applies AdamW at the scheduled rate; then the patch discriminator takes its own step.
//!
//! A step whose loss or gradient norm is not finite is refused before any parameter changes,
//! with an error naming the step and the term; the last checkpoint stays the last good one.
//! The machinery (schedule, clipping, the weights' average, checkpoints, the data-parallel
//! step, the loop) is `bevworld_training`'s; this file keeps what is the tokenizer's own.

use std::path::{Path, PathBuf};

use bevworld_blocks::module_file::{load_module, save_module};
use bevworld_blocks::seeded_init;
use bevworld_metrics::{ImageMetricError, Planes, Roi, chamfer_in_roi, psnr, ssim};
use bevworld_tokenizer::render::rays::{VoxelPlacement, points_from_depths, sample_positions};
use bevworld_tokenizer::render::{VoxelField, VoxelScene};
use bevworld_tokenizer::weights::{WeightsError, load_weights, save_weights};
use bevworld_tokenizer::{Modality, Tokenizer, TokenizerConfig};
use bevworld_training::checkpoint::{self, CheckpointError, CheckpointState};
use bevworld_training::ema::{self, MismatchedModules};
use bevworld_training::metrics_log::MetricsLogError;
use bevworld_training::{
    Curve, Trainee, Validation, WorkerPanicked, clip_global_norm, parallel_map, replica,
    sum_in_order,
};
use bevworld_types::SplitMix64;
use burn::module::Module;
use burn::optim::GradientsParams;
use burn::prelude::*;

use crate::config::{TrainConfig, TrainedParts};
use crate::data::{TrainingFrame, draw_lidar};
use crate::discriminator::{
    PatchDiscriminator, PatchDiscriminatorConfig, discriminator_hinge, generator_hinge,
};
use crate::distortion::distortion;
use crate::losses::{l1, mse};
use crate::perceptual::{PerceptualError, PerceptualLoss, TORCHVISION_VGG16};
use crate::sparsity::density_sparsity;
use crate::termination::{termination_nll, termination_targets};
use crate::terms::{Term, TermValues};

/// The columns of the run's `metrics.csv`, in the order older logs have them; a column added
/// later goes at the end. Every `Term`'s column is here (a test checks it).
pub const COLUMNS: [&str; 19] = [
    "step",
    "phase",
    "lr",
    "loss",
    "loss_rgb",
    "loss_lidar",
    "loss_perceptual",
    "loss_gan",
    "loss_discriminator",
    "grad_norm",
    "psnr_db",
    "ssim",
    "chamfer_m2",
    "elapsed_s",
    "loss_distortion",
    "loss_termination",
    "loss_rgb_squared",
    "cameras_unscored",
    "loss_sparsity",
];

/// `RUN/curves.png`: the training loss, the validation PSNR and the validation Chamfer.
pub const CURVES: [Curve; 3] = [
    Curve {
        title: "training loss",
        phase: "train",
        column: "loss",
        log_scale: true,
    },
    Curve {
        title: "validation PSNR (dB)",
        phase: "val",
        column: "psnr_db",
        log_scale: false,
    },
    Curve {
        title: "validation Chamfer (m²)",
        phase: "val",
        column: "chamfer_m2",
        log_scale: true,
    },
];

/// The files of a tokenizer checkpoint.
pub mod files {
    pub const MODEL: &str = "model.bpk";
    pub const OPTIMIZER: &str = "optimizer.bpk";
    pub const DISCRIMINATOR: &str = "discriminator.bpk";
    pub const DISCRIMINATOR_OPTIMIZER: &str = "discriminator_optimizer.bpk";
    /// The parameters' moving average, when the run keeps one (`ema_decay`).
    pub const WEIGHT_AVERAGE: &str = "ema.bpk";
}

/// What one frame of a step renders, drawn from the run's RNG before any work starts, so the
/// draws, and so the run, do not depend on how the frames are spread over threads.
#[derive(Clone, Debug)]
struct FrameDraw {
    frame: usize,
    /// Cameras rendered whole; empty for a model that does not render cameras.
    cameras: Vec<usize>,
    /// LiDAR rays, by index into the frame's in-range rays; empty for a model without LiDAR.
    lidar: Vec<usize>,
}

/// One frame's contribution to a step, computed on a worker thread.
struct FrameOutcome {
    /// Gradients of this frame's loss, scaled by 1 / frames per step.
    grads: GradientsParams,
    loss: f64,
    terms: TermValues,
    /// The rendered cameras (detached) and their inputs, for the discriminator's step.
    images: Option<(Tensor<4>, Tensor<4>)>,
}

/// One frame's rendered cameras, their targets and L1 loss.
struct CameraLosses {
    /// `[k, 3, H, W]` in [0, 1].
    rgb: Tensor<4>,
    target: Tensor<4>,
    loss_rgb: Tensor<1>,
}

/// What every frame of a step reads.
struct StepInputs<'a> {
    config: &'a TrainConfig,
    model_config: &'a TokenizerConfig,
    frames: &'a [TrainingFrame],
    depths: &'a [f32],
    placement: &'a VoxelPlacement,
    perceptual: Option<&'a PerceptualLoss>,
    device: &'a Device,
    /// Whether the generator's adversarial term is on.
    gan: bool,
    /// The step being taken, counted from 1, for messages.
    step: usize,
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
    #[error(transparent)]
    Checkpoint(#[from] CheckpointError),
    #[error(transparent)]
    Weights(#[from] WeightsError),
    #[error(transparent)]
    Perceptual(#[from] PerceptualError),
    #[error("no training frames")]
    NoFrames,
    #[error("step {step}: a training frame failed ({source}); the step was not applied")]
    StepWorker { step: usize, source: WorkerPanicked },
    #[error(
        "validation failed: validation frame {} ({source}); no scores are reported for it",
        source.item
    )]
    ValidationWorker { source: WorkerPanicked },
    #[error(transparent)]
    WeightAverage(#[from] MismatchedModules),
    #[error(transparent)]
    Log(#[from] MetricsLogError),
}

/// What one step did.
#[derive(Clone, Debug, PartialEq)]
pub struct StepReport {
    /// Steps completed after this one.
    pub step: usize,
    pub lr: f64,
    pub loss: f64,
    /// The terms the step took: those of the modalities the model renders, the optional ones
    /// when weighted, the GAN's once it started.
    pub terms: TermValues,
    /// Before clipping.
    pub grad_norm: f64,
}

impl StepReport {
    pub fn term(&self, term: Term) -> Option<f64> {
        self.terms.get(term)
    }
}

/// Reconstruction quality on held-out frames.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ValidationReport {
    pub frames: usize,
    /// Mean over cameras and frames, images in [0, 1] at the model's size; `None` for a model
    /// that does not render cameras.
    pub psnr_db: Option<f64>,
    pub ssim: Option<f64>,
    /// Mean over frames, 4D-Occ ROI, rendered depth along the real rays; `None` for a model
    /// that does not render LiDAR.
    pub chamfer_m2: Option<f64>,
    /// Camera images whose PSNR or SSIM could not be computed, left out of the means.
    pub cameras_unscored: usize,
}

impl ValidationReport {
    /// The report as the training loop logs it.
    pub fn validation(&self, phase: &'static str, label: &'static str) -> Validation {
        Validation {
            phase,
            label,
            frames: self.frames,
            scores: vec![
                ("psnr_db", self.psnr_db),
                ("ssim", self.ssim),
                ("chamfer_m2", self.chamfer_m2),
                ("cameras_unscored", Some(self.cameras_unscored as f64)),
            ],
        }
    }
}

pub struct Trainer {
    pub config: TrainConfig,
    pub model_config: TokenizerConfig,
    model: Tokenizer,
    /// The parameters' moving average (`ema_decay`), on the inner device: the shipped weights.
    weight_average: Option<Tokenizer>,
    optimizer: burn::optim::ModuleOptimizer,
    discriminator: PatchDiscriminator,
    perceptual: Option<PerceptualLoss>,
    discriminator_optimizer: burn::optim::ModuleOptimizer,
    /// The autodiff device; validation runs on its inner device.
    device: Device,
    rng: SplitMix64,
    step: usize,
    train: Vec<TrainingFrame>,
    val: Vec<TrainingFrame>,
    depths: Vec<f32>,
    placement: VoxelPlacement,
    /// Worker threads a step's frames (and validation's) are spread over. The results do not
    /// depend on it.
    threads: usize,
    /// The shipped weights' latest validation, when one ran.
    last_validation: Option<ValidationReport>,
}

/// The discriminator's seed, apart from the generator's.
const DISCRIMINATOR_SEED: u64 = 0xd15c_0000;

/// An AdamW with the config's settings and the moments saved at `path`.
fn load_optimizer(
    config: &TrainConfig,
    path: &Path,
) -> Result<burn::optim::ModuleOptimizer, CheckpointError> {
    config
        .optimizer
        .adamw()
        .load(path)
        .map_err(|e| checkpoint::io_error(path, format!("{e:?}")))
}

/// The model with the parameters the config keeps fixed taking no gradients.
fn fixed_as_configured(config: &TrainConfig, model: Tokenizer) -> Tokenizer {
    match config.trains {
        TrainedParts::Whole => model,
        TrainedParts::Decoder => model.with_encoder_fixed(),
    }
}

fn scalar(tensor: Tensor<1>) -> f64 {
    let value: f32 = tensor.into_scalar();
    f64::from(value)
}

impl Trainer {
    /// A fresh run: the model initialised from `config.seed`, on one thread per available
    /// core (at most one per frame of a step).
    pub fn new(
        config: TrainConfig,
        model_config: TokenizerConfig,
        device: &Device,
        train: Vec<TrainingFrame>,
        val: Vec<TrainingFrame>,
    ) -> Result<Self, TrainError> {
        if train.is_empty() {
            return Err(TrainError::NoFrames);
        }
        let device = device.clone().autodiff();
        let model = fixed_as_configured(&config, model_config.init_seeded(config.seed, &device));
        let discriminator = seeded_init(config.seed ^ DISCRIMINATOR_SEED, &device, |device| {
            PatchDiscriminatorConfig::new(config.loss.discriminator_channels).init(device)
        });
        let perceptual = match (&config.perceptual_weights, config.loss.perceptual > 0.0) {
            (Some(path), true) => Some(PerceptualLoss::from_file(path, &device)?.no_grad()),
            (None, true) => {
                tracing::warn!(
                    "the perceptual loss is off: no VGG16 weights were given (set `perceptual_weights` to torchvision's {TORCHVISION_VGG16}); it never runs on random weights"
                );
                None
            }
            (_, false) => None,
        };
        let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
        let weight_average = config.ema_decay.map(|_| model.valid());
        Ok(Self {
            weight_average,
            optimizer: config.optimizer.adamw(),
            discriminator_optimizer: config.optimizer.adamw(),
            discriminator,
            perceptual,
            rng: SplitMix64::new(config.seed ^ 0x5e_ed0f_da7a),
            step: 0,
            depths: model_config.render.sample_depths(),
            placement: model_config.voxel_placement(),
            config,
            model_config,
            model,
            device,
            train,
            val,
            threads,
            last_validation: None,
        })
    }

    /// Starts from trained weights (`init`) instead of the seeded initialisation: the model
    /// and its moving average both begin there; the optimiser's moments start at zero.
    pub fn start_from(mut self, path: &Path) -> Result<Self, TrainError> {
        self.model = fixed_as_configured(
            &self.config,
            load_weights(&self.model_config, path, &self.device)?,
        );
        if self.weight_average.is_some() {
            self.weight_average = Some(self.model.valid());
        }
        Ok(self)
    }

    /// Spreads each step's frames, and validation's, over `threads` worker threads (at least
    /// one). Results are the same for any count: every frame's gradients are computed alone
    /// and summed in frame order.
    pub fn with_threads(mut self, threads: usize) -> Self {
        self.threads = threads.max(1);
        self
    }

    pub fn threads(&self) -> usize {
        self.threads
    }

    /// Continues the run in `run` from its newest checkpoint: parameters, optimiser moments,
    /// step and RNG state, so the continuation equals an uninterrupted run.
    pub fn resume(mut self, run: &Path) -> Result<Self, TrainError> {
        let (checkpoint, state) = checkpoint::latest(run)?;
        let file = |name: &str| checkpoint.file(name);
        self.model = fixed_as_configured(
            &self.config,
            load_weights(&self.model_config, &file(files::MODEL), &self.device)?,
        );
        self.optimizer = load_optimizer(&self.config, &file(files::OPTIMIZER))?;
        self.discriminator = load_module(
            PatchDiscriminatorConfig::new(self.config.loss.discriminator_channels)
                .init(&self.device),
            "discriminator",
            "discriminator",
            &file(files::DISCRIMINATOR),
        )?;
        self.discriminator_optimizer =
            load_optimizer(&self.config, &file(files::DISCRIMINATOR_OPTIMIZER))?;
        if self.config.ema_decay.is_some() {
            let inner = self.device.clone().inner();
            self.weight_average = Some(load_weights(
                &self.model_config,
                &file(files::WEIGHT_AVERAGE),
                &inner,
            )?);
        }
        self.step = state.step;
        self.rng = SplitMix64 {
            state: state.rng_state,
        };
        Ok(self)
    }

    pub fn step(&self) -> usize {
        self.step
    }

    /// The last iterate, on the autodiff device.
    pub fn model(&self) -> &Tokenizer {
        &self.model
    }

    /// The parameters' moving average, when the run keeps one (`ema_decay`).
    pub fn weight_average(&self) -> Option<&Tokenizer> {
        self.weight_average.as_ref()
    }

    /// The weights the run ships and validates: the moving average when kept, else the last
    /// iterate; on the inner device.
    pub fn shipped_model(&self) -> Tokenizer {
        self.weight_average
            .clone()
            .unwrap_or_else(|| self.model.valid())
    }

    pub fn is_done(&self) -> bool {
        self.step >= self.config.steps
    }

    /// Whether the step about to be taken includes the GAN terms.
    pub fn gan_active(&self) -> bool {
        self.step >= self.config.loss.gan_start
    }

    /// The frame and rays of one frame of the step: a frame, then its cameras, then its LiDAR
    /// rays, in that order from the run's RNG.
    fn draw(&mut self) -> FrameDraw {
        let frame = self.rng.below(self.train.len());
        let data = &self.train[frame];
        let cameras = if self.model_config.uses(Modality::Camera) {
            self.rng
                .choose(data.rays.cameras, self.config.rays.cameras_per_step)
        } else {
            Vec::new()
        };
        let lidar = if self.model_config.uses(Modality::Lidar) {
            draw_lidar(&mut self.rng, data, &self.config.rays)
        } else {
            Vec::new()
        };
        FrameDraw {
            frame,
            cameras,
            lidar,
        }
    }

    /// One optimiser step over `frames_per_step` frames: each frame's loss and gradients on a
    /// worker thread, the gradients of the mean loss summed in frame order, one clip and one
    /// AdamW update; then the discriminator's step on every frame's cameras.
    pub fn train_step(&mut self) -> Result<StepReport, TrainError> {
        // The GAN judges camera images: a LiDAR-only model has none.
        let gan = self.gan_active() && self.model_config.uses(Modality::Camera);
        let draws: Vec<FrameDraw> = (0..self.config.frames_per_step.max(1))
            .map(|_| self.draw())
            .collect();
        let inputs = StepInputs {
            config: &self.config,
            model_config: &self.model_config,
            frames: &self.train,
            depths: &self.depths,
            placement: &self.placement,
            perceptual: self.perceptual.as_ref(),
            device: &self.device,
            gan,
            step: self.step + 1,
        };
        let (model, discriminator) = (&self.model, &self.discriminator);
        let step = self.step + 1;
        let outcomes = parallel_map(
            &draws,
            self.threads,
            || (replica(model), replica(discriminator)),
            |(model, discriminator), draw| {
                frame_outcome(&inputs, model, discriminator, draw, draws.len())
            },
        )
        .map_err(|source| TrainError::StepWorker { step, source })?
        .into_iter()
        .collect::<Result<Vec<_>, _>>()?;

        let count = outcomes.len() as f64;
        let frame_terms: Vec<TermValues> = outcomes.iter().map(|o| o.terms.clone()).collect();
        let mut terms = TermValues::mean(&frame_terms);
        let loss = outcomes.iter().map(|o| o.loss).sum::<f64>() / count;
        let mut images = Vec::new();
        let mut parts = Vec::with_capacity(outcomes.len());
        for outcome in outcomes {
            parts.push(outcome.grads);
            images.extend(outcome.images);
        }
        let mut grads = sum_in_order(&self.model, parts);
        let grad_norm = clip_global_norm(
            &self.model,
            &mut grads,
            self.config.optimizer.grad_clip_norm,
        );
        if !grad_norm.is_finite() {
            return Err(TrainError::NonFinite {
                step,
                what: "gradient norm",
                value: grad_norm,
            });
        }
        let lr = self
            .config
            .optimizer
            .learning_rate(self.step, self.config.steps);
        self.model = self.optimizer.step(lr, self.model.clone(), grads);
        if let (Some(decay), Some(average)) = (self.config.ema_decay, self.weight_average.take()) {
            let average = ema::update(average, &self.model, decay, step)?;
            self.weight_average = Some(match self.config.trains {
                TrainedParts::Whole => average,
                TrainedParts::Decoder => average.with_encoder_of(&self.model.valid()),
            });
        }

        // The discriminator learns from the same images, the renders detached from the tokenizer.
        if gan && !images.is_empty() {
            terms.push(Term::Discriminator, self.discriminator_step(images, lr)?);
        }
        self.step = step;
        Ok(StepReport {
            step,
            lr,
            loss,
            terms,
            grad_norm,
        })
    }

    /// The discriminator's hinge step on every frame's renders and inputs; returns its loss.
    fn discriminator_step(
        &mut self,
        images: Vec<(Tensor<4>, Tensor<4>)>,
        lr: f64,
    ) -> Result<f64, TrainError> {
        let (fake, real): (Vec<Tensor<4>>, Vec<Tensor<4>>) = images.into_iter().unzip();
        let real = self.discriminator.forward(Tensor::cat(real, 0));
        let fake = self.discriminator.forward(Tensor::cat(fake, 0));
        let d_loss = discriminator_hinge(real, fake).mul_scalar(self.config.loss.gan_discriminator);
        let d_value = scalar(d_loss.clone());
        if !d_value.is_finite() {
            return Err(TrainError::NonFinite {
                step: self.step + 1,
                what: Term::Discriminator.name(),
                value: d_value,
            });
        }
        let mut d_grads = GradientsParams::from_grads(d_loss.backward(), &self.discriminator);
        clip_global_norm(
            &self.discriminator,
            &mut d_grads,
            self.config.optimizer.grad_clip_norm,
        );
        self.discriminator =
            self.discriminator_optimizer
                .step(lr, self.discriminator.clone(), d_grads);
        Ok(d_value)
    }

    /// PSNR, SSIM and Chamfer of the shipped weights (`shipped_model`) on the first
    /// `validation_frames` held-out frames, rendering every camera ray and every LiDAR ray of
    /// the sweep; the frames are spread over the worker threads. The rays whose return lies
    /// beyond the far plane are rendered too, as the `reconstruct` graph renders them and as 4D-Occ's protocol renders every ray with a
    /// return: a ray the field ends short puts a point inside the ROI, and the score must
    /// count it.
    pub fn validate(&self) -> Result<ValidationReport, TrainError> {
        self.validate_model(&self.shipped_model())
    }

    /// The same scores of the last iterate, when the run ships a moving average instead: what
    /// the average adds.
    pub fn validate_iterate(&self) -> Result<Option<ValidationReport>, TrainError> {
        self.weight_average
            .is_some()
            .then(|| self.validate_model(&self.model.valid()))
            .transpose()
    }

    /// A frame whose rendering fails (a worker's panic) fails the whole validation, with one
    /// thread as with many: scores over the frames that happened to survive would read as the
    /// model's.
    fn validate_model(&self, model: &Tokenizer) -> Result<ValidationReport, TrainError> {
        let device = self.device.clone().inner();
        let frames: Vec<&TrainingFrame> = self
            .val
            .iter()
            .take(self.config.validation_frames)
            .collect();
        let (cameras, lidar) = (
            self.model_config.uses(Modality::Camera),
            self.model_config.uses(Modality::Lidar),
        );
        let scores = parallel_map(
            &frames,
            self.threads,
            || (),
            |_, frame| {
                let latent = model.encode(frame.encoder.to_input(&device)).latent;
                let scene = VoxelScene::new(model, &self.model_config, model.voxels(latent));
                let camera = cameras.then(|| camera_scores(&scene, frame));
                let chamfer = lidar.then(|| {
                    let sweep = &frame.rays.lidar;
                    let rendered = scene.render_dense(sweep);
                    let to_f64 = |p: &[f32; 3]| [f64::from(p[0]), f64::from(p[1]), f64::from(p[2])];
                    let predicted: Vec<[f64; 3]> = points_from_depths(sweep, &rendered.depth)
                        .iter()
                        .map(to_f64)
                        .collect();
                    let truth: Vec<[f64; 3]> = frame.lidar_points.iter().map(to_f64).collect();
                    chamfer_in_roi(&predicted, &truth, &Roi::FOUR_D_OCC).chamfer
                });
                (camera, chamfer)
            },
        )
        .map_err(|source| TrainError::ValidationWorker { source })?;
        let (mut psnr_sum, mut ssim_sum, mut images, mut chamfer_sum) = (0.0, 0.0, 0usize, 0.0);
        let mut unscored = 0;
        for (camera, chamfer) in &scores {
            if let Some(frame) = camera {
                psnr_sum += frame.psnr_sum;
                ssim_sum += frame.ssim_sum;
                images += frame.scored;
                unscored += frame.unscored;
            }
            chamfer_sum += chamfer.unwrap_or(0.0);
        }
        let n = scores.len().max(1) as f64;
        // With no camera scored there is no mean to report: `None`, never a PSNR of 0 dB.
        let scored = cameras && images > 0;
        Ok(ValidationReport {
            frames: scores.len(),
            psnr_db: scored.then(|| psnr_sum / images as f64),
            ssim: scored.then(|| ssim_sum / images as f64),
            chamfer_m2: lidar.then(|| chamfer_sum / n),
            cameras_unscored: unscored,
        })
    }

    /// Writes a checkpoint of the current state into `run`.
    pub fn save_checkpoint(&self, run: &Path) -> Result<PathBuf, TrainError> {
        let staged = checkpoint::staging(run, self.step)?;
        let file = |name: &str| staged.file(name);
        // `valid()`: the weights without the autodiff wrapper (a module with running
        // statistics would also fold its pending update in here).
        save_weights(&self.model.valid(), &file(files::MODEL))?;
        if let Some(average) = &self.weight_average {
            save_weights(average, &file(files::WEIGHT_AVERAGE))?;
        }
        save_module(
            &self.discriminator.valid(),
            "discriminator",
            &file(files::DISCRIMINATOR),
        )?;
        for (optimizer, name) in [
            (
                &self.discriminator_optimizer,
                files::DISCRIMINATOR_OPTIMIZER,
            ),
            (&self.optimizer, files::OPTIMIZER),
        ] {
            optimizer
                .save(file(name))
                .map_err(|e| checkpoint::io_error(&file(name), format!("{e:?}")))?;
        }
        let state = CheckpointState {
            step: self.step,
            rng_state: self.rng.state,
        };
        Ok(checkpoint::commit(
            run,
            staged,
            &state,
            self.config.keep_checkpoints,
        )?)
    }

    /// The shipped weights' latest validation in the training loop, if one ran.
    pub fn last_validation(&self) -> Option<ValidationReport> {
        self.last_validation
    }

    /// The discriminator, for tests and inspection.
    pub fn discriminator(&self) -> &PatchDiscriminator {
        &self.discriminator
    }

    /// The shipped weights alone (`shipped_model`), for inference (`weights:` in the graphs).
    pub fn save_weights(&self, path: &Path) -> Result<(), TrainError> {
        Ok(save_weights(&self.shipped_model(), path)?)
    }
}

impl Trainee for Trainer {
    type Error = TrainError;

    fn step(&self) -> usize {
        self.step
    }

    fn train_step(&mut self) -> Result<bevworld_training::StepReport, TrainError> {
        let report = Trainer::train_step(self)?;
        Ok(bevworld_training::StepReport {
            step: report.step,
            lr: report.lr,
            loss: report.loss,
            grad_norm: report.grad_norm,
            terms: report.terms.columns(),
        })
    }

    /// With a moving average shipped, the last iterate's scores come first (phase
    /// `val_iterate`), to say what the average adds; a run's last row is the shipped weights'.
    fn validate(&mut self) -> Result<Vec<Validation>, TrainError> {
        let iterate = self.validate_iterate()?;
        let shipped = Trainer::validate(self)?;
        self.last_validation = Some(shipped);
        let label = if iterate.is_some() {
            "the weights' moving average"
        } else {
            "validation"
        };
        Ok(iterate
            .map(|v| v.validation("val_iterate", "the last iterate"))
            .into_iter()
            .chain([shipped.validation("val", label)])
            .collect())
    }

    fn save_checkpoint(&self, run: &Path) -> Result<(), TrainError> {
        Trainer::save_checkpoint(self, run).map(|_| ())
    }
}

/// One frame's losses and their gradients, on whichever thread runs it. `model` and
/// `discriminator` are this thread's replicas. The loss is scaled by `1 / frames` so that the
/// gradients summed over a step's frames are those of their mean.
fn frame_outcome(
    inputs: &StepInputs,
    model: &Tokenizer,
    discriminator: &PatchDiscriminator,
    draw: &FrameDraw,
    frames: usize,
) -> Result<FrameOutcome, TrainError> {
    let device = inputs.device;
    let frame = &inputs.frames[draw.frame];
    let weights = &inputs.config.loss;
    let latent = model.encode(frame.encoder.to_input(device)).latent;
    let voxels = model.voxels(latent);
    let depth_row = Tensor::<2>::from_data(
        TensorData::new(inputs.depths.to_vec(), [1, inputs.depths.len()]),
        device,
    );
    // Each term's tensor, in `Term::ALL`'s order, which is the order the loss sums them.
    let mut terms: Vec<(Term, Tensor<1>)> = Vec::new();
    if inputs.model_config.uses(Modality::Lidar) {
        let lidar = lidar_loss(
            inputs,
            model,
            frame,
            &draw.lidar,
            &voxels,
            depth_row.clone(),
        );
        terms.push((Term::Lidar, lidar.l1));
        terms.extend(lidar.distortion.map(|t| (Term::Distortion, t)));
        terms.extend(lidar.termination.map(|t| (Term::Termination, t)));
    }
    let mut images = None;
    if inputs.model_config.uses(Modality::Camera) {
        let camera = camera_losses(inputs, model, frame, &draw.cameras, &voxels, depth_row);
        terms.push((Term::Rgb, camera.loss_rgb));
        if weights.rgb_l2 > 0.0 {
            let squared = mse(camera.rgb.clone(), camera.target.clone());
            terms.push((Term::RgbSquared, squared));
        }
        if let Some(perceptual) = inputs.perceptual {
            let term = perceptual.forward(camera.rgb.clone(), camera.target.clone());
            terms.push((Term::Perceptual, term));
        }
        if inputs.gan {
            let adversarial = generator_hinge(discriminator.forward(camera.rgb.clone()));
            terms.push((Term::Gan, adversarial));
        }
        images = Some((camera.rgb.detach(), camera.target));
    }
    if weights.density_sparsity > 0.0 {
        terms.push((Term::Sparsity, density_sparsity(model, &voxels)));
    }
    let mut values = TermValues::default();
    let mut loss = Tensor::<1>::zeros([1], device);
    for (term, tensor) in terms {
        values.push(term, scalar(tensor.clone().detach()));
        loss = loss + tensor.mul_scalar(term.weight(weights));
    }
    let value = scalar(loss.clone().detach());
    if !value.is_finite() {
        return Err(TrainError::NonFinite {
            step: inputs.step,
            what: values.first_non_finite().map_or("loss", Term::name),
            value,
        });
    }
    let scaled = loss.mul_scalar(1.0 / frames as f64);
    Ok(FrameOutcome {
        grads: GradientsParams::from_grads(scaled.backward(), model),
        loss: value,
        terms: values,
        images,
    })
}

/// Renders whole cameras: the upsampler is a CNN and needs each camera's full ray grid.
fn camera_losses(
    inputs: &StepInputs,
    model: &Tokenizer,
    frame: &TrainingFrame,
    cameras: &[usize],
    voxels: &VoxelField,
    depth_row: Tensor<2>,
) -> CameraLosses {
    let device = inputs.device;
    let rays = &frame.rays;
    let per_camera = rays.rows * rays.columns;
    let indices: Vec<usize> = cameras
        .iter()
        .flat_map(|&c| c * per_camera..(c + 1) * per_camera)
        .collect();
    let camera_rays = rays.camera.subset(&indices);
    let positions = sample_positions(&camera_rays, inputs.depths, inputs.placement);
    let rendered = model.render_rays(voxels, &positions, camera_rays.len(), depth_row);
    let rgb = model.camera_rgb(
        rendered.features,
        rendered.opacity,
        camera_rays.directions_tensor(device),
        cameras.len(),
        rays.rows,
        rays.columns,
    );
    let [_, _, h, w] = frame.encoder.image_shape;
    let plane = 3 * h * w;
    let target: Vec<f32> = cameras
        .iter()
        .flat_map(|&c| {
            frame.encoder.images[c * plane..(c + 1) * plane]
                .iter()
                .copied()
        })
        .collect();
    let target = Tensor::<4>::from_data(TensorData::new(target, [cameras.len(), 3, h, w]), device);
    let loss_rgb = l1(rgb.clone(), target.clone());
    CameraLosses {
        rgb,
        target,
        loss_rgb,
    }
}

/// The LiDAR terms of one frame, over the drawn subset of the sweep's rays.
struct LidarLosses {
    /// L1 on the rendered depth, metres.
    l1: Tensor<1>,
    /// Distortion of the rays' render weights, when its loss weight is above 0.
    distortion: Option<Tensor<1>>,
    /// Termination likelihood of the rays' returns, when its loss weight is above 0.
    termination: Option<Tensor<1>>,
}

fn lidar_loss(
    inputs: &StepInputs,
    model: &Tokenizer,
    frame: &TrainingFrame,
    chosen: &[usize],
    voxels: &VoxelField,
    depth_row: Tensor<2>,
) -> LidarLosses {
    let device = inputs.device;
    if chosen.is_empty() {
        return LidarLosses {
            l1: Tensor::<1>::zeros([1], device),
            distortion: None,
            termination: None,
        };
    }
    let lidar_rays = frame.lidar.subset(chosen);
    let ranges: Vec<f32> = chosen.iter().map(|&i| frame.lidar_ranges[i]).collect();
    let positions = sample_positions(&lidar_rays, inputs.depths, inputs.placement);
    let rendered = model.render_rays(voxels, &positions, lidar_rays.len(), depth_row);
    let termination = (inputs.config.loss.lidar_termination > 0.0).then(|| {
        let targets = termination_targets(inputs.depths, &ranges);
        let targets = Tensor::<2>::from_data(
            TensorData::new(targets, [chosen.len(), inputs.depths.len()]),
            device,
        );
        termination_nll(rendered.weights.clone(), targets)
    });
    let target = Tensor::<1>::from_data(TensorData::new(ranges, [chosen.len()]), device);
    LidarLosses {
        l1: l1(rendered.depth, target),
        distortion: (inputs.config.loss.lidar_distortion > 0.0)
            .then(|| distortion(rendered.weights)),
        termination,
    }
}

/// One frame's camera scores: sums over the cameras that could be scored, and how many could
/// not (an image the metrics refuse is counted, never silently skipped).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct CameraScores {
    psnr_sum: f64,
    ssim_sum: f64,
    scored: usize,
    unscored: usize,
}

fn camera_scores(scene: &VoxelScene, frame: &TrainingFrame) -> CameraScores {
    let rays = &frame.rays;
    let rgb = scene.camera_planes(&scene.render_dense(&rays.camera), rays);
    score_cameras(
        &rgb,
        &frame.encoder.images,
        rays.cameras,
        frame.encoder.image_shape,
    )
}

/// PSNR and SSIM of each camera of `rendered` against `target`, both `[cameras, 3, H, W]` in
/// [0, 1].
fn score_cameras(
    rendered: &[f32],
    target: &[f32],
    cameras: usize,
    [_, _, h, w]: [usize; 4],
) -> CameraScores {
    let plane = 3 * h * w;
    let mut scores = CameraScores::default();
    for c in 0..cameras {
        fn planes(
            data: &[f32],
            range: std::ops::Range<usize>,
            h: usize,
            w: usize,
        ) -> Option<Planes<'_>> {
            data.get(range).map(|data| Planes {
                data,
                channels: 3,
                height: h,
                width: w,
            })
        }
        let range = c * plane..(c + 1) * plane;
        let scored = match (
            planes(rendered, range.clone(), h, w),
            planes(target, range, h, w),
        ) {
            (Some(a), Some(b)) => psnr(&a, &b, 1.0).and_then(|p| Ok((p, ssim(&a, &b, 1.0)?))),
            _ => Err(ImageMetricError::Empty),
        };
        match scored {
            Ok((p, s)) => {
                scores.psnr_sum += p.min(100.0);
                scores.ssim_sum += s;
                scores.scored += 1;
            }
            Err(error) => {
                tracing::warn!(camera = c, "a validation camera was not scored: {error}");
                scores.unscored += 1;
            }
        }
    }
    scores
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two 16 × 16 cameras: the rendering, and its target with `broken` cameras made NaN.
    fn cameras(broken: &[usize]) -> (Vec<f32>, Vec<f32>) {
        let plane = 3 * 16 * 16;
        let rendered: Vec<f32> = (0..2 * plane).map(|i| (i % 7) as f32 / 8.0).collect();
        let mut target: Vec<f32> = rendered.iter().map(|v| v + 0.1).collect();
        for &c in broken {
            target[c * plane] = f32::NAN;
        }
        (rendered, target)
    }

    #[test]
    fn a_camera_the_metrics_refuse_is_counted_and_left_out_of_the_means() {
        let (rendered, target) = cameras(&[]);
        let all = score_cameras(&rendered, &target, 2, [2, 3, 16, 16]);
        assert_eq!((all.scored, all.unscored), (2, 0));
        // A uniform error of 0.1: 20 dB per camera.
        assert!((all.psnr_sum - 40.0).abs() < 1e-3, "{}", all.psnr_sum);

        let (rendered, target) = cameras(&[1]);
        let one = score_cameras(&rendered, &target, 2, [2, 3, 16, 16]);
        assert_eq!((one.scored, one.unscored), (1, 1));
        assert!((one.psnr_sum - 20.0).abs() < 1e-3, "{}", one.psnr_sum);

        // Fewer values than cameras: the missing one is counted too, not skipped.
        let short = score_cameras(&rendered[..3 * 16 * 16], &target, 2, [2, 3, 16, 16]);
        assert_eq!((short.scored, short.unscored), (1, 1));
    }
}
