//! The world model's training config (`configs/models/train-world-model-*.yaml`): the model,
//! the tokenizer whose latents it learns, the latent caches and the synthetic sets they are
//! exported from, the optimiser, the paper's three stages (and a counterfactual one of ours),
//! and validation.

use std::path::{Path, PathBuf};

use bevworld_sensors::synth::SynthSet;
use bevworld_training::{ConfigProblem, OptimizerConfig, require_count, require_positive};
use bevworld_world_model::DdimConfig;
use serde::{Deserialize, Serialize};

use crate::moving_weight::MovingWeight;

/// Which frames of a scene a stage learns from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Rate {
    /// Every LiDAR sweep (12 Hz).
    Sweeps,
    /// Keyframes only (2 Hz).
    Keyframes,
}

/// One of the paper's training stages.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StageConfig {
    pub name: String,
    pub rate: Rate,
    /// Condition frames (P past frames and the current one).
    pub context: usize,
    pub future: usize,
    pub steps: usize,
    /// Every `stride`-th frame of the rate: 6 at sweeps gives 2 Hz windows that start at
    /// every sweep, six times the windows of the keyframes at the same frame interval.
    #[serde(default = "one", skip_serializing_if = "is_one")]
    pub stride: usize,
    /// Also draw windows from the branched cache (`branches`): the same contexts driven under
    /// every manoeuvre, so that the action, not the road, decides where the future goes.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub with_branches: bool,
}

fn one() -> usize {
    1
}

fn is_one(stride: &usize) -> bool {
    *stride == 1
}

/// A latent cache: `export_features` output of a synthetic set, at 12 Hz (`index.json`) and
/// at keyframes (`index-keyframes.json`), in one folder.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CacheConfig {
    /// The exported latents.
    pub latents: PathBuf,
    /// The synthetic scenes they are encoded from, made on first use.
    pub synth: SynthSet,
}

/// The index files of a cache.
pub const SWEEPS_INDEX: &str = "index.json";
pub const KEYFRAMES_INDEX: &str = "index-keyframes.json";

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ValidationConfig {
    /// Keyframe windows validated, spread evenly over the validation set.
    pub windows: usize,
    pub sampler: DdimConfig,
    pub every: usize,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrainWorldModelConfig {
    /// The world model YAML.
    pub model: PathBuf,
    /// The tokenizer's model YAML and weights, whose latents are learned; their statistics
    /// file lies beside the weights.
    pub tokenizer_model: PathBuf,
    pub tokenizer_weights: PathBuf,
    pub train: CacheConfig,
    pub val: CacheConfig,
    /// The held-out test scenes, touched only for a reported figure
    /// (`bevworld eval world-model --split test`).
    #[serde(default)]
    pub test: Option<CacheConfig>,
    /// Training scenes branched into manoeuvres (`synth.branch`): what would have happened
    /// under each action from one context, which no log records. Read by the stages
    /// `with_branches`; the action statistics stay the training cache's.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub branches: Option<CacheConfig>,
    pub seed: u64,
    /// Windows per optimiser step.
    pub batch: usize,
    /// Windows per forward pass; a step's micro-batches run on the worker threads and their
    /// gradients are summed in order, so the run does not depend on the thread count.
    pub micro_batch: usize,
    pub optimizer: OptimizerConfig,
    /// Moving average of the weights, validated and shipped; absent: the last iterate.
    #[serde(default)]
    pub ema_decay: Option<f64>,
    /// A scene is split where two frames are more than this many usual intervals apart.
    pub gap_factor: f64,
    pub stages: Vec<StageConfig>,
    pub validation: ValidationConfig,
    pub checkpoint_every: usize,
    /// Count the cells where the future moves over the ego warp more in the loss
    /// (`moving_weight.rs`); absent: the plain L1. Residual models only.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub moving_weight: Option<MovingWeight>,
    /// Start from these trained weights (a world model's `.bpk`, with its `.meta.json`)
    /// instead of the seeded initialisation: a fine-tune. They must be of this model, on
    /// this tokenizer's latents, with the training cache's action statistics.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub init: Option<PathBuf>,
    /// `init`'s weights were trained on another tokenizer's latents, of which this run's
    /// tokenizer is a fine-tune: the run adapts them to its own latents instead of refusing
    /// them. The action statistics must still match. Off (the default): refused.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub init_from_other_tokenizer: bool,
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

impl TrainWorldModelConfig {
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

    /// The branched cache, when a stage reads it (`with_branches`): only then is it exported
    /// and loaded.
    pub fn branches_in_use(&self) -> Option<&CacheConfig> {
        self.branches
            .as_ref()
            .filter(|_| self.stages.iter().any(|s| s.with_branches))
    }

    /// Steps over all stages.
    pub fn total_steps(&self) -> usize {
        self.stages.iter().map(|s| s.steps).sum()
    }

    /// The stage step `step` (counted from 0) belongs to, with the step it starts at.
    pub fn stage_at(&self, step: usize) -> Option<(usize, &StageConfig, usize)> {
        let mut start = 0;
        for (index, stage) in self.stages.iter().enumerate() {
            if step < start + stage.steps {
                return Some((index, stage, start));
            }
            start += stage.steps;
        }
        None
    }

    pub fn problems(&self) -> Vec<ConfigProblem> {
        let mut problems = self.optimizer.problems("optimizer");
        if self.init_from_other_tokenizer && self.init.is_none() {
            problems.push(ConfigProblem::new(
                "init_from_other_tokenizer",
                "true without `init`: there are no weights to adapt",
            ));
        }
        require_count(&mut problems, "batch", self.batch);
        require_count(&mut problems, "micro_batch", self.micro_batch);
        if self.micro_batch > 0 && !self.batch.is_multiple_of(self.micro_batch) {
            problems.push(ConfigProblem::new(
                "micro_batch",
                format!("{} does not divide batch {}", self.micro_batch, self.batch),
            ));
        }
        require_positive(&mut problems, "gap_factor", self.gap_factor);
        if self.gap_factor <= 1.0 {
            problems.push(ConfigProblem::new(
                "gap_factor",
                format!(
                    "{} (accepted: > 1, in usual frame intervals)",
                    self.gap_factor
                ),
            ));
        }
        if let Some(decay) = self.ema_decay
            && !(0.0..1.0).contains(&decay)
        {
            problems.push(ConfigProblem::new(
                "ema_decay",
                format!("{decay} (accepted: [0, 1), or absent)"),
            ));
        }
        if self.stages.is_empty() {
            problems.push(ConfigProblem::new(
                "stages",
                "empty (accepted: 1 or more stages)",
            ));
        }
        for (i, stage) in self.stages.iter().enumerate() {
            let field = |name: &str| format!("stages[{i}].{name}");
            require_count(&mut problems, &field("context"), stage.context);
            require_count(&mut problems, &field("future"), stage.future);
            require_count(&mut problems, &field("steps"), stage.steps);
            require_count(&mut problems, &field("stride"), stage.stride);
            if stage.with_branches && self.branches.is_none() {
                problems.push(ConfigProblem::new(
                    field("with_branches"),
                    "true, but the config names no `branches` cache",
                ));
            }
        }
        require_count(&mut problems, "validation.windows", self.validation.windows);
        require_count(&mut problems, "validation.every", self.validation.every);
        require_count(&mut problems, "checkpoint_every", self.checkpoint_every);
        if let Some(weight) = &self.moving_weight {
            problems.extend(weight.problems("moving_weight"));
        }
        // The scenes learnt from and the scenes scored on never share a seed.
        let learnt = [
            ("training", Some(&self.train)),
            ("branches", self.branches.as_ref()),
        ];
        let scored = [("val", Some(&self.val)), ("test", self.test.as_ref())];
        for (learnt_name, learnt) in learnt.iter().filter_map(|(n, c)| Some((n, (*c)?))) {
            for (scored_name, scored) in scored.iter().filter_map(|(n, c)| Some((n, (*c)?))) {
                if learnt
                    .synth
                    .seeds()
                    .any(|s| scored.synth.seeds().contains(&s))
                {
                    problems.push(ConfigProblem::new(
                        format!("{scored_name}.synth.seed"),
                        format!(
                            "seeds {:?} overlap the {learnt_name} seeds {:?}",
                            scored.synth.seeds(),
                            learnt.synth.seeds()
                        ),
                    ));
                }
            }
        }
        problems
    }
}
