//! The training loop of one tokenizer: a step draws a frame, renders the step's rays (whole
//! cameras for the RGB upsampler, a random subset of LiDAR rays), takes the L1 losses and,
//! after `gan_start`, the adversarial term, clips the global gradient norm and applies AdamW at
//! the scheduled rate; then the patch discriminator takes its own step.
//!
//! A step whose loss or gradient norm is not finite is refused before any parameter changes,
//! with an error naming the step and the term; the last checkpoint stays the last good one.

use std::path::{Path, PathBuf};

use bevworld_metrics::{Planes, Roi, chamfer_in_roi, psnr, ssim};
use burn::module::Module;
use burn::optim::{AdamWConfig, GradientsAccumulator, GradientsParams};
use burn::prelude::*;

use crate::config::TokenizerConfig;
use crate::modality::Modality;
use crate::model::Tokenizer;
use crate::render::rays::{VoxelPlacement, points_from_depths, sample_positions};
use crate::render::{VoxelField, VoxelScene};
use crate::train::checkpoint::{self, CheckpointError, CheckpointState};
use crate::train::clip::clip_global_norm;
use crate::train::config::{LidarDraw, TrainConfig};
use crate::train::data::TrainingFrame;
use crate::train::discriminator::{
    PatchDiscriminator, PatchDiscriminatorConfig, discriminator_hinge, generator_hinge,
};
use crate::train::distortion::distortion;
use crate::train::ema::{self, MismatchedModules};
use crate::train::losses::{l1, mse};
use crate::train::perceptual::{PerceptualError, PerceptualLoss, TORCHVISION_VGG16};
use crate::train::replica::replica;
use crate::train::rng::SplitMix64;
use crate::train::schedule::learning_rate;
use crate::train::termination::{termination_nll, termination_targets};
use crate::weights::{WeightsError, load_module, load_weights, save_module, save_weights};

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
    rgb: Option<f64>,
    rgb_squared: Option<f64>,
    lidar: Option<f64>,
    distortion: Option<f64>,
    termination: Option<f64>,
    perceptual: Option<f64>,
    gan: Option<f64>,
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
    #[error("{path}: {message}")]
    Io { path: PathBuf, message: String },
    #[error(transparent)]
    Perceptual(#[from] PerceptualError),
    #[error("no training frames")]
    NoFrames,
    #[error("a training worker thread panicked; the step was not applied")]
    WorkerPanicked,
    #[error(transparent)]
    WeightAverage(#[from] MismatchedModules),
}

/// What one step did.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StepReport {
    /// Steps completed after this one.
    pub step: usize,
    pub lr: f64,
    pub loss: f64,
    /// The L1 terms of the modalities the model renders (`modalities`).
    pub loss_rgb: Option<f64>,
    /// The mean squared RGB error, when `loss.rgb_l2` is above 0.
    pub loss_rgb_squared: Option<f64>,
    pub loss_lidar: Option<f64>,
    /// The LiDAR rays' distortion term, when `loss.lidar_distortion` is above 0.
    pub loss_distortion: Option<f64>,
    /// The LiDAR rays' termination term, when `loss.lidar_termination` is above 0.
    pub loss_termination: Option<f64>,
    /// The perceptual term, when VGG16 weights were given.
    pub loss_perceptual: Option<f64>,
    /// The generator's adversarial term and the discriminator's loss, once the GAN started.
    pub loss_gan: Option<f64>,
    pub loss_discriminator: Option<f64>,
    /// Before clipping.
    pub grad_norm: f64,
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
}

fn scalar(tensor: Tensor<1>) -> f64 {
    let value: f32 = tensor.into_scalar();
    f64::from(value)
}

/// `f` of every item, on up to `threads` scoped threads (item `i` on thread `i mod threads`),
/// returned in item order. `prepare` runs on the calling thread once per thread and gives
/// that thread its own state (a model replica).
fn parallel_map<T: Sync, S: Send, R: Send>(
    items: &[T],
    threads: usize,
    prepare: impl Fn() -> S,
    f: impl Fn(&S, &T) -> R + Sync,
) -> Result<Vec<R>, TrainError> {
    let threads = threads.clamp(1, items.len().max(1));
    if threads == 1 {
        let state = prepare();
        return Ok(items.iter().map(|item| f(&state, item)).collect());
    }
    let f = &f;
    let mut slots: Vec<Option<R>> = std::iter::repeat_with(|| None).take(items.len()).collect();
    std::thread::scope(|scope| {
        let handles: Vec<_> = (0..threads)
            .map(|worker| {
                let state = prepare();
                scope.spawn(move || {
                    items
                        .iter()
                        .enumerate()
                        .skip(worker)
                        .step_by(threads)
                        .map(|(i, item)| (i, f(&state, item)))
                        .collect::<Vec<_>>()
                })
            })
            .collect();
        for handle in handles {
            let results = handle.join().map_err(|_| TrainError::WorkerPanicked)?;
            for (i, result) in results {
                slots[i] = Some(result);
            }
        }
        Ok::<(), TrainError>(())
    })?;
    slots
        .into_iter()
        .map(|slot| slot.ok_or(TrainError::WorkerPanicked))
        .collect()
}

impl Trainer {
    fn optimizer(config: &TrainConfig) -> burn::optim::ModuleOptimizer {
        let o = &config.optimizer;
        AdamWConfig::new()
            .with_beta_1(o.beta_1 as f32)
            .with_beta_2(o.beta_2 as f32)
            .with_epsilon(o.epsilon as f32)
            .with_weight_decay(o.weight_decay as f32)
            .init()
    }

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
        device.seed(config.seed);
        let model = model_config.init(&device);
        let discriminator =
            PatchDiscriminatorConfig::new(config.loss.discriminator_channels).init(&device);
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
            optimizer: Self::optimizer(&config),
            discriminator_optimizer: Self::optimizer(&config),
            discriminator,
            perceptual,
            rng: SplitMix64::new(config.seed ^ 0x5eed_0f_da7a),
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
        })
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
        let (files, state) = checkpoint::latest(run)?;
        self.model = load_weights(&self.model_config, &files.model(), &self.device)?;
        self.optimizer = Self::optimizer(&self.config)
            .load(files.optimizer())
            .map_err(|e| checkpoint::io_error(&files.optimizer(), format!("{e:?}")))?;
        self.discriminator = load_module(
            PatchDiscriminatorConfig::new(self.config.loss.discriminator_channels)
                .init(&self.device),
            "discriminator",
            &files.discriminator(),
        )?;
        self.discriminator_optimizer = Self::optimizer(&self.config)
            .load(files.discriminator_optimizer())
            .map_err(|e| {
                checkpoint::io_error(&files.discriminator_optimizer(), format!("{e:?}"))
            })?;
        if self.config.ema_decay.is_some() {
            let inner = self.device.clone().inner();
            self.weight_average = Some(load_weights(
                &self.model_config,
                &files.weight_average(),
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
            let count = self.config.rays.lidar_rays;
            match self.config.rays.lidar_draw {
                LidarDraw::Uniform => self.rng.choose(data.lidar.len(), count),
                LidarDraw::ByRange => self.rng.choose_weighted(&data.lidar_ranges, count),
            }
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
        let outcomes = parallel_map(
            &draws,
            self.threads,
            || (replica(model), replica(discriminator)),
            |(model, discriminator), draw| {
                frame_outcome(&inputs, model, discriminator, draw, draws.len())
            },
        )?
        .into_iter()
        .collect::<Result<Vec<_>, _>>()?;

        let count = outcomes.len() as f64;
        let mean = |part: fn(&FrameOutcome) -> Option<f64>| {
            let values: Option<Vec<f64>> = outcomes.iter().map(part).collect();
            values.map(|v| v.iter().sum::<f64>() / count)
        };
        let (loss_rgb, loss_lidar) = (mean(|o| o.rgb), mean(|o| o.lidar));
        let loss_rgb_squared = mean(|o| o.rgb_squared);
        let loss_distortion = mean(|o| o.distortion);
        let loss_termination = mean(|o| o.termination);
        let (loss_perceptual, loss_gan) = (mean(|o| o.perceptual), mean(|o| o.gan));
        let loss = outcomes.iter().map(|o| o.loss).sum::<f64>() / count;
        let mut accumulator = GradientsAccumulator::<Tokenizer>::new();
        let mut images = Vec::new();
        for outcome in outcomes {
            accumulator.accumulate(&self.model, outcome.grads);
            images.extend(outcome.images);
        }
        let mut grads = accumulator.grads();
        let grad_norm = clip_global_norm(
            &self.model,
            &mut grads,
            self.config.optimizer.grad_clip_norm,
        );
        if !grad_norm.is_finite() {
            return Err(TrainError::NonFinite {
                step: self.step + 1,
                what: "gradient norm",
                value: grad_norm,
            });
        }
        let o = &self.config.optimizer;
        let lr = learning_rate(
            o.lr,
            o.warmup_steps,
            o.decay_steps.unwrap_or(self.config.steps),
            o.final_lr_fraction,
            self.step,
        );
        self.model = self.optimizer.step(lr, self.model.clone(), grads);
        if let (Some(decay), Some(average)) = (self.config.ema_decay, self.weight_average.take()) {
            self.weight_average = Some(ema::update(average, &self.model, decay, self.step + 1)?);
        }

        // The discriminator learns from the same images, the renders detached from the tokenizer.
        let loss_discriminator = if gan && !images.is_empty() {
            Some(self.discriminator_step(images, lr)?)
        } else {
            None
        };
        self.step += 1;
        Ok(StepReport {
            step: self.step,
            lr,
            loss,
            loss_rgb,
            loss_rgb_squared,
            loss_lidar,
            loss_distortion,
            loss_termination,
            loss_perceptual,
            loss_gan,
            loss_discriminator,
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
                what: "discriminator loss",
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
    pub fn validate(&self) -> ValidationReport {
        self.validate_model(&self.shipped_model())
    }

    /// The same scores of the last iterate, when the run ships a moving average instead: what
    /// the average adds.
    pub fn validate_iterate(&self) -> Option<ValidationReport> {
        self.weight_average
            .is_some()
            .then(|| self.validate_model(&self.model.valid()))
    }

    fn validate_model(&self, model: &Tokenizer) -> ValidationReport {
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
        .unwrap_or_default();
        let (mut psnr_sum, mut ssim_sum, mut images, mut chamfer_sum) = (0.0, 0.0, 0usize, 0.0);
        for (camera, chamfer) in &scores {
            if let Some((p, s, n)) = camera {
                psnr_sum += p;
                ssim_sum += s;
                images += n;
            }
            chamfer_sum += chamfer.unwrap_or(0.0);
        }
        let n = scores.len().max(1) as f64;
        ValidationReport {
            frames: scores.len(),
            psnr_db: cameras.then(|| psnr_sum / images.max(1) as f64),
            ssim: cameras.then(|| ssim_sum / images.max(1) as f64),
            chamfer_m2: lidar.then(|| chamfer_sum / n),
        }
    }
    /// Writes a checkpoint of the current state into `run`.
    pub fn save_checkpoint(&self, run: &Path) -> Result<PathBuf, TrainError> {
        let staged = checkpoint::staging(run, self.step)?;
        // `valid()`: the weights without the autodiff wrapper (a module with running
        // statistics would also fold its pending update in here).
        save_weights(&self.model.valid(), &staged.model())?;
        if let Some(average) = &self.weight_average {
            save_weights(average, &staged.weight_average())?;
        }
        save_module(&self.discriminator.valid(), &staged.discriminator())?;
        self.discriminator_optimizer
            .save(staged.discriminator_optimizer())
            .map_err(|e| {
                checkpoint::io_error(&staged.discriminator_optimizer(), format!("{e:?}"))
            })?;
        self.optimizer
            .save(staged.optimizer())
            .map_err(|e| checkpoint::io_error(&staged.optimizer(), format!("{e:?}")))?;
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

    /// The discriminator, for tests and inspection.
    pub fn discriminator(&self) -> &PatchDiscriminator {
        &self.discriminator
    }

    /// The shipped weights alone (`shipped_model`), for inference (`weights:` in the graphs).
    pub fn save_weights(&self, path: &Path) -> Result<(), TrainError> {
        Ok(save_weights(&self.shipped_model(), path)?)
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
    let mut loss = Tensor::<1>::zeros([1], device);
    let (mut rgb_value, mut lidar_value) = (None, None);
    let mut rgb_squared_value = None;
    let (mut distortion_value, mut termination_value) = (None, None);
    if inputs.model_config.uses(Modality::Lidar) {
        let term = lidar_loss(
            inputs,
            model,
            frame,
            &draw.lidar,
            &voxels,
            depth_row.clone(),
        );
        lidar_value = Some(scalar(term.l1.clone().detach()));
        loss = loss + term.l1.mul_scalar(weights.lidar_l1);
        if let Some(distortion) = term.distortion {
            distortion_value = Some(scalar(distortion.clone().detach()));
            loss = loss + distortion.mul_scalar(weights.lidar_distortion);
        }
        if let Some(termination) = term.termination {
            termination_value = Some(scalar(termination.clone().detach()));
            loss = loss + termination.mul_scalar(weights.lidar_termination);
        }
    }
    let (mut perceptual_value, mut gan_value, mut images) = (None, None, None);
    if inputs.model_config.uses(Modality::Camera) {
        let camera = camera_losses(inputs, model, frame, &draw.cameras, &voxels, depth_row);
        rgb_value = Some(scalar(camera.loss_rgb.clone().detach()));
        loss = loss + camera.loss_rgb.mul_scalar(weights.rgb_l1);
        if weights.rgb_l2 > 0.0 {
            let squared = mse(camera.rgb.clone(), camera.target.clone());
            rgb_squared_value = Some(scalar(squared.clone().detach()));
            loss = loss + squared.mul_scalar(weights.rgb_l2);
        }
        if let Some(perceptual) = inputs.perceptual {
            let term = perceptual.forward(camera.rgb.clone(), camera.target.clone());
            perceptual_value = Some(scalar(term.clone().detach()));
            loss = loss + term.mul_scalar(weights.perceptual);
        }
        if inputs.gan {
            let adversarial = generator_hinge(discriminator.forward(camera.rgb.clone()));
            gan_value = Some(scalar(adversarial.clone().detach()));
            loss = loss + adversarial.mul_scalar(weights.gan_generator);
        }
        images = Some((camera.rgb.detach(), camera.target));
    }
    let value = scalar(loss.clone().detach());
    if !value.is_finite() {
        let what = if !rgb_value.is_none_or(f64::is_finite) {
            "RGB loss"
        } else if !rgb_squared_value.is_none_or(f64::is_finite) {
            "squared RGB loss"
        } else if !lidar_value.is_none_or(f64::is_finite) {
            "LiDAR loss"
        } else if !distortion_value.is_none_or(f64::is_finite) {
            "LiDAR distortion loss"
        } else if !termination_value.is_none_or(f64::is_finite) {
            "LiDAR termination loss"
        } else {
            "perceptual or GAN loss"
        };
        return Err(TrainError::NonFinite {
            step: inputs.step,
            what,
            value,
        });
    }
    let scaled = loss.mul_scalar(1.0 / frames as f64);
    Ok(FrameOutcome {
        grads: GradientsParams::from_grads(scaled.backward(), model),
        loss: value,
        rgb: rgb_value,
        rgb_squared: rgb_squared_value,
        lidar: lidar_value,
        distortion: distortion_value,
        termination: termination_value,
        perceptual: perceptual_value,
        gan: gan_value,
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

/// Summed PSNR and SSIM over one frame's cameras, and how many cameras were scored.
fn camera_scores(scene: &VoxelScene, frame: &TrainingFrame) -> (f64, f64, usize) {
    let (mut psnr_sum, mut ssim_sum, mut images) = (0.0, 0.0, 0usize);
    let rays = &frame.rays;
    let rgb = scene.camera_planes(&scene.render_dense(&rays.camera), rays);
    let [_, _, h, w] = frame.encoder.image_shape;
    let plane = 3 * h * w;
    for c in 0..rays.cameras {
        let planes = |data| Planes {
            data,
            channels: 3,
            height: h,
            width: w,
        };
        let (a, b) = (
            planes(&rgb[c * plane..(c + 1) * plane]),
            planes(&frame.encoder.images[c * plane..(c + 1) * plane]),
        );
        if let (Ok(p), Ok(s)) = (psnr(&a, &b, 1.0), ssim(&a, &b, 1.0)) {
            psnr_sum += p.min(100.0);
            ssim_sum += s;
            images += 1;
        }
    }
    (psnr_sum, ssim_sum, images)
}
