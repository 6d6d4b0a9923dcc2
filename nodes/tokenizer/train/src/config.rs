//! The training config (`configs/models/train-tokenizer-*.yaml`): which model, the optimiser and
//! its schedule, the rays per step, the loss weights, checkpointing and validation, and the
//! synthetic datasets by seed range. Every problem is reported at once, naming its field.

use std::path::{Path, PathBuf};

use bevworld_sensors::synth::SynthSet;
use bevworld_tokenizer::TokenizerConfig;
use bevworld_tokenizer::config::ConfigError;
use bevworld_training::{ConfigProblem, OptimizerConfig, require_count, require_non_negative};
use serde::{Deserialize, Serialize};

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RayConfig {
    /// Cameras rendered whole per step (their ray grids, upsampled to RGB).
    pub cameras_per_step: usize,
    /// LiDAR rays drawn at random per step.
    pub lidar_rays: usize,
    /// How the LiDAR rays are drawn.
    #[serde(default)]
    pub lidar_draw: LidarDraw,
    /// The share of each step's LiDAR rays drawn from the returns on annotated vehicles (moving
    /// or parked), uniformly among them; the rest are drawn as `lidar_draw` says, from every
    /// return. Vehicles hold a few percent of a sweep's returns, so a uniform draw all but
    /// ignores them, and the agent scores show the renderer drawing cars as blobs. 0 (the
    /// default) leaves the draw as it was; a frame without annotations draws as with 0.
    #[serde(default)]
    pub lidar_vehicle_share: f64,
}

/// Which of a sweep's returns a step renders.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LidarDraw {
    /// Every return alike.
    #[default]
    Uniform,
    /// A return with probability proportional to its range. A spinning LiDAR's returns thin
    /// out with the square of the distance, so uniform draws leave the far scene almost
    /// untrained, and the far returns are where a Chamfer distance's error sits.
    ByRange,
}

/// A spelling that is not a `LidarDraw`.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("'{0}' is neither 'uniform' nor 'by_range'")]
pub struct UnknownLidarDraw(pub String);

impl std::str::FromStr for LidarDraw {
    type Err = UnknownLidarDraw;

    /// The config's spelling (`uniform`, `by_range`), so a flag reads as the YAML does.
    fn from_str(text: &str) -> Result<Self, Self::Err> {
        match text {
            "uniform" => Ok(Self::Uniform),
            "by_range" => Ok(Self::ByRange),
            other => Err(UnknownLidarDraw(other.to_string())),
        }
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LossWeights {
    /// L1 between rendered and input RGB, in [0, 1].
    pub rgb_l1: f64,
    /// Mean squared error between rendered and input RGB, in [0, 1]: the error PSNR measures.
    /// 0 (the default) leaves it out.
    #[serde(default)]
    pub rgb_l2: f64,
    /// L1 between rendered depth and LiDAR range, in metres.
    pub lidar_l1: f64,
    /// The distortion loss (Mip-NeRF 360) on the LiDAR rays' render weights: pulls each ray's
    /// weight onto one surface, so that its expected depth does not float between two. 0 (the
    /// default) leaves it out.
    #[serde(default)]
    pub lidar_distortion: f64,
    /// The termination loss on the LiDAR rays' render weights: the negative log-likelihood of
    /// each return under its ray's termination distribution (free space up to the return, a
    /// stop there). 0 (the default) leaves it out.
    #[serde(default)]
    pub lidar_termination: f64,
    /// The sparsity prior on the field's opacity at every voxel centre
    /// (`sparsity::density_sparsity`): asks for empty air, which empty-space skipping then
    /// skips. 0 (the default) leaves it out.
    #[serde(default)]
    pub density_sparsity: f64,
    /// The perceptual (VGG16) term; needs `perceptual_weights`, else it is off with a warning.
    pub perceptual: f64,
    /// The generator's adversarial (hinge) term on the rendered cameras.
    pub gan_generator: f64,
    /// The discriminator's own hinge loss.
    pub gan_discriminator: f64,
    /// Steps before the GAN terms start (the paper: 30,000).
    pub gan_start: usize,
    /// Channels of the patch discriminator's first layer.
    pub discriminator_channels: usize,
}

/// Which parameters a run trains.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TrainedParts {
    /// Every parameter.
    #[default]
    Whole,
    /// The decoder alone (the lift, the alpha head, the RGB upsampler, the background): the
    /// encoder of `init` stays as it is, and so does every latent it makes
    /// (`Tokenizer::with_encoder_fixed`). Needs `init`.
    Decoder,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DataConfig {
    pub train: SynthSet,
    pub val: SynthSet,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrainConfig {
    /// The model config, relative to this file.
    pub model: PathBuf,
    pub steps: usize,
    /// Frames per optimiser step: each frame's loss is computed alone (on its own worker
    /// thread when cores allow) and the step follows the gradient of their mean.
    #[serde(default = "one")]
    pub frames_per_step: usize,
    pub seed: u64,
    pub optimizer: OptimizerConfig,
    /// An exponential moving average of the parameters with this decay per step (after a
    /// warm-up, `train::ema`): the weights validated, checkpointed beside the iterate, and
    /// shipped. Absent: the last iterate is shipped.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ema_decay: Option<f64>,
    pub rays: RayConfig,
    pub loss: LossWeights,
    pub checkpoint_every: usize,
    pub keep_checkpoints: usize,
    pub validate_every: usize,
    /// Validation frames evaluated each time (the first ones of the validation set).
    pub validation_frames: usize,
    /// torchvision's VGG16 weights for the perceptual term (relative to this file); absent
    /// turns the term off.
    #[serde(default)]
    pub perceptual_weights: Option<PathBuf>,
    /// Start from these trained weights (a tokenizer's `.bpk`, relative to the working
    /// directory, as the world model's `init`) instead of the seeded initialisation: a
    /// fine-tune. The model and its moving average begin there; the optimiser's moments at
    /// zero. They must be of this model.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub init: Option<PathBuf>,
    /// Which parameters train: `whole` (the default) or `decoder`, a fine-tune of `init`'s
    /// decoder that leaves its latents as they are.
    #[serde(default)]
    pub trains: TrainedParts,
    pub data: DataConfig,
}

fn one() -> usize {
    1
}

impl TrainConfig {
    /// Reads a training config and the model config it names.
    pub fn from_yaml_file(path: &Path) -> Result<(Self, TokenizerConfig), ConfigError> {
        let shown = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|e| ConfigError::Read {
            path: shown.clone(),
            message: e.to_string(),
        })?;
        let mut config: Self = serde_saphyr::from_str(&text).map_err(|e| ConfigError::Read {
            path: shown.clone(),
            message: bevworld_graph::yaml::describe_at(&e, &text),
        })?;
        let problems = config.problems();
        if !problems.is_empty() {
            return Err(ConfigError::Invalid {
                path: shown,
                problems,
            });
        }
        let folder = path.parent().unwrap_or(Path::new("."));
        config.model = folder.join(&config.model);
        config.perceptual_weights = config.perceptual_weights.map(|p| folder.join(p));
        let model = TokenizerConfig::from_yaml_file(&config.model)?;
        Ok((config, model))
    }

    /// The config as YAML: `model` and `perceptual_weights` as they are now (a path resolved
    /// by `from_yaml_file` is written resolved).
    pub fn to_yaml(&self) -> Result<String, ConfigError> {
        serde_saphyr::to_string(self).map_err(|e| ConfigError::Read {
            path: self.model.display().to_string(),
            message: e.to_string(),
        })
    }

    /// Every inconsistency, one per field at fault.
    pub fn problems(&self) -> Vec<ConfigProblem> {
        let mut problems = self.optimizer.problems("optimizer");
        if let Some(decay) = self.ema_decay
            && !(decay > 0.0 && decay < 1.0)
        {
            problems.push(ConfigProblem::new(
                "ema_decay",
                format!("{decay} (accepted: a number in (0, 1), or absent)"),
            ));
        }
        for (name, value) in [
            ("steps", self.steps),
            ("frames_per_step", self.frames_per_step),
            ("rays.cameras_per_step", self.rays.cameras_per_step),
            ("rays.lidar_rays", self.rays.lidar_rays),
            ("checkpoint_every", self.checkpoint_every),
            ("keep_checkpoints", self.keep_checkpoints),
            ("validate_every", self.validate_every),
            ("validation_frames", self.validation_frames),
        ] {
            require_count(&mut problems, name, value);
        }
        for (name, value) in [
            ("loss.rgb_l1", self.loss.rgb_l1),
            ("loss.rgb_l2", self.loss.rgb_l2),
            ("loss.lidar_l1", self.loss.lidar_l1),
            ("loss.lidar_distortion", self.loss.lidar_distortion),
            ("loss.lidar_termination", self.loss.lidar_termination),
            ("loss.density_sparsity", self.loss.density_sparsity),
        ] {
            require_non_negative(&mut problems, name, value);
        }
        if self.trains == TrainedParts::Decoder && self.init.is_none() {
            problems.push(ConfigProblem::new(
                "trains",
                "decoder, without init (a decoder fine-tune keeps the encoder of the weights it starts from: name them in init)",
            ));
        }
        let share = self.rays.lidar_vehicle_share;
        if !(0.0..=1.0).contains(&share) {
            problems.push(ConfigProblem::new(
                "rays.lidar_vehicle_share",
                format!("{share} (accepted: a share in [0, 1])"),
            ));
        }
        let (t, v) = (&self.data.train, &self.data.val);
        for (name, set) in [("data.train", t), ("data.val", v)] {
            if set.scenes == 0 || !(set.seconds > 0.0) {
                problems.push(ConfigProblem::new(
                    name,
                    "needs scenes >= 1 and seconds > 0",
                ));
            }
        }
        let (train, val) = (t.seeds(), v.seeds());
        if train.start < val.end && val.start < train.end {
            problems.push(ConfigProblem::new(
                "data.val.seed",
                format!(
                    "seeds {}..{} overlap the training seeds {}..{} (validation scenes must be held out)",
                    val.start, val.end, train.start, train.end
                ),
            ));
        }
        if t.dir == v.dir {
            problems.push(ConfigProblem::new(
                "data.val.dir",
                "the same folder as data.train.dir",
            ));
        }
        problems
    }
}
