//! The world model's sizes and its diffusion process, read from
//! `configs/models/world-model-*.yaml`. `problems` reports every inconsistency at once, naming
//! the field.

use std::path::Path;

use bevworld_types::ConfigProblem;
use bevworld_types::problem::{require_count, require_positive};
use serde::{Deserialize, Serialize};

use crate::ego_warp::{EgoWarpBase, LatentGrid};
use crate::fine_tokens::FineTokensConfig;

/// What the network predicts for the noisy future frames.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Target {
    /// The noise ε (the paper's, with an L1 loss).
    Epsilon,
    /// The velocity `v = √ᾱ ε − √(1−ᾱ) x₀` (Salimans and Ho 2022).
    V,
    /// The clean latent x₀.
    X0,
}

/// How β grows over the diffusion steps.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ScheduleKind {
    /// DDPM's β linear from `beta_start` to `beta_end`.
    Linear,
    /// Nichol and Dhariwal's cosine ᾱ.
    Cosine,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DiffusionConfig {
    /// Diffusion steps T.
    pub steps: usize,
    pub schedule: ScheduleKind,
    /// β₁ of the linear schedule.
    #[serde(default = "default_beta_start")]
    pub beta_start: f64,
    /// β_T of the linear schedule.
    #[serde(default = "default_beta_end")]
    pub beta_end: f64,
    /// Rescale the schedule so that ᾱ_T = 0 (Lin et al. 2024): the last step sees pure noise,
    /// as sampling starts from it.
    pub zero_terminal_snr: bool,
    pub target: Target,
}

fn default_beta_start() -> f64 {
    1e-4
}

fn default_beta_end() -> f64 {
    0.02
}

/// The model YAML. Unknown keys are refused: a misspelt field must not silently take its
/// default.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WorldModelConfig {
    pub name: String,
    /// Latent channels C' (4).
    pub latent_channels: usize,
    /// Latent cells along y and x, [H, W].
    pub latent_size: [usize; 2],
    /// Spatial tokens are `patch × patch` latent cells.
    pub patch: usize,
    /// Token width D.
    pub width: usize,
    /// Spatial-temporal blocks.
    pub depth: usize,
    pub heads: usize,
    /// MLP hidden width / D.
    pub mlp_ratio: f64,
    /// Width of each half of the condition `c = [action embedding, timestep embedding]`.
    pub condition_half: usize,
    /// Condition frames the model is trained and run with: P past frames plus the current one.
    pub context_frames: usize,
    /// Future frames N forecast in one pass.
    pub future_frames: usize,
    /// Seconds between frames (0.5 at keyframes).
    pub frame_interval_s: f64,
    /// Diffuse the residual over the ego-warped current latent instead of the latent itself:
    /// the static world is moved by the known ego motion, and the network spends itself on
    /// what changes.
    pub residual_over_ego_warp: bool,
    /// With the residual, the warp's weight in the base falls linearly with the horizon, from
    /// 1 now to 0 at this many seconds: near frames keep the moved static world, far ones,
    /// where the warp's detail is more often wrong than right, are predicted as latents.
    /// Absent: the full warp at every horizon.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ego_warp_fade_s: Option<f64>,
    /// Each future frame's tokens also embed the current latent warped into that frame, so the
    /// network sees where the static world will be. Absent: false.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub ego_warp_input: bool,
    /// The BEV extent of the latent, metres, as the tokenizer's `bev` (for the ego warp).
    pub x_range: [f64; 2],
    pub y_range: [f64; 2],
    pub diffusion: DiffusionConfig,
    /// One token per latent cell where the context moves, corrected by a fine stage
    /// (`fine_tokens.rs`, `fine_stage.rs`). Absent: coarse tokens only.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fine_tokens: Option<FineTokensConfig>,
}

#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("{path}: {message}")]
    Read { path: String, message: String },
    #[error("{path}: {}", problems.iter().map(ToString::to_string).collect::<Vec<_>>().join("; "))]
    Invalid {
        path: String,
        problems: Vec<ConfigProblem>,
    },
}

impl WorldModelConfig {
    /// Reads and checks a model YAML.
    pub fn from_yaml_file(path: &Path) -> Result<Self, ConfigError> {
        let shown = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|e| ConfigError::Read {
            path: shown.clone(),
            message: e.to_string(),
        })?;
        Self::from_yaml(&text, &shown)
    }

    pub fn from_yaml(text: &str, origin: &str) -> Result<Self, ConfigError> {
        let config: Self = serde_saphyr::from_str(text).map_err(|e| ConfigError::Read {
            path: origin.to_string(),
            message: bevworld_graph::yaml::describe_at(&e, text),
        })?;
        let problems = config.problems();
        if problems.is_empty() {
            Ok(config)
        } else {
            Err(ConfigError::Invalid {
                path: origin.to_string(),
                problems,
            })
        }
    }

    /// Tokens per frame along y and x.
    pub fn token_grid(&self) -> [usize; 2] {
        let p = self.patch.max(1);
        [self.latent_size[0] / p, self.latent_size[1] / p]
    }

    /// Values of one patch token before embedding, `C' · p · p`.
    pub fn patch_values(&self) -> usize {
        self.latent_channels * self.patch * self.patch
    }

    pub fn mlp_hidden(&self) -> usize {
        (self.width as f64 * self.mlp_ratio).round() as usize
    }

    /// Where the latent lies: its shape and BEV extent.
    pub fn latent_grid(&self) -> LatentGrid {
        LatentGrid {
            channels: self.latent_channels,
            height: self.latent_size[0],
            width: self.latent_size[1],
            x_range: self.x_range,
            y_range: self.y_range,
        }
    }

    /// What the diffused future frames are the residual over.
    pub fn ego_warp_base(&self) -> EgoWarpBase {
        EgoWarpBase {
            residual: self.residual_over_ego_warp,
            fade_s: self.ego_warp_fade_s,
        }
    }

    /// Every inconsistency, one line each, naming the field.
    pub fn problems(&self) -> Vec<ConfigProblem> {
        let mut problems = Vec::new();
        for (field, value) in [
            ("latent_channels", self.latent_channels),
            ("patch", self.patch),
            ("width", self.width),
            ("depth", self.depth),
            ("heads", self.heads),
            ("condition_half", self.condition_half),
            ("context_frames", self.context_frames),
            ("future_frames", self.future_frames),
            ("diffusion.steps", self.diffusion.steps),
        ] {
            require_count(&mut problems, field, value);
        }
        require_positive(&mut problems, "mlp_ratio", self.mlp_ratio);
        require_positive(&mut problems, "frame_interval_s", self.frame_interval_s);
        if let Some(fade) = self.ego_warp_fade_s {
            require_positive(&mut problems, "ego_warp_fade_s", fade);
            if !self.residual_over_ego_warp {
                problems.push(ConfigProblem::new(
                    "ego_warp_fade_s",
                    "is set, but residual_over_ego_warp is false: there is no warp to fade",
                ));
            }
        }
        for (axis, size) in ["height", "width"].iter().zip(self.latent_size) {
            if self.patch > 0 && (size == 0 || !size.is_multiple_of(self.patch)) {
                problems.push(ConfigProblem::new(
                    "latent_size",
                    format!(
                        "{axis} {size} is not a positive multiple of patch {}",
                        self.patch
                    ),
                ));
            }
        }
        require_token_width(&mut problems, ("width", self.width), ("heads", self.heads));
        if !self.condition_half.is_multiple_of(2) {
            problems.push(ConfigProblem::new(
                "condition_half",
                format!(
                    "{} (the timestep embedding needs an even width)",
                    self.condition_half
                ),
            ));
        }
        for (field, range) in [("x_range", self.x_range), ("y_range", self.y_range)] {
            if !(range[0].is_finite() && range[1].is_finite() && range[1] > range[0]) {
                problems.push(ConfigProblem::new(
                    field,
                    format!("{range:?} (accepted: [low, high] with low < high)"),
                ));
            }
        }
        if let Some(fine) = &self.fine_tokens {
            problems.extend(fine.problems());
        }
        let diffusion = &self.diffusion;
        if diffusion.schedule == ScheduleKind::Linear
            && !(diffusion.beta_start > 0.0
                && diffusion.beta_start < diffusion.beta_end
                && diffusion.beta_end < 1.0)
        {
            problems.push(ConfigProblem::new(
                "diffusion.beta_end",
                format!(
                    "beta_start {} and beta_end {} (accepted: 0 < beta_start < beta_end < 1)",
                    diffusion.beta_start, diffusion.beta_end
                ),
            ));
        }
        if diffusion.zero_terminal_snr && diffusion.target == Target::Epsilon {
            // At ᾱ_T = 0 the noisy latent is pure noise, ε = x_T exactly, and x₀ cannot be
            // recovered from a predicted ε: sampling from t = T would divide by √ᾱ_T = 0.
            problems.push(ConfigProblem::new(
                "diffusion.target",
                "epsilon cannot be sampled under zero_terminal_snr (x0 = (x_T - sqrt(1 - a_T) eps) / sqrt(a_T) divides by 0); use v or x0",
            ));
        }
        problems
    }
}

/// A token width its attention heads divide and the 2D sine-cosine position encoding can
/// split (a multiple of 4): the coarse tokens' and the fine tokens' alike.
pub(crate) fn require_token_width(
    problems: &mut Vec<ConfigProblem>,
    (width_field, width): (&str, usize),
    (heads_field, heads): (&str, usize),
) {
    if heads > 0 && !width.is_multiple_of(heads) {
        problems.push(ConfigProblem::new(
            heads_field,
            format!("{heads} does not divide width {width}"),
        ));
    }
    if !width.is_multiple_of(4) {
        problems.push(ConfigProblem::new(
            width_field,
            format!("{width} (the 2D position encoding needs a multiple of 4)"),
        ));
    }
}
