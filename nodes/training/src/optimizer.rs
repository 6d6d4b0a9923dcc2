//! AdamW and its schedule, as a training config names them. Epsilon and weight decay are
//! always set explicitly: burn's defaults (1e-5, 1e-4) differ from PyTorch's (1e-8, 1e-2).

use burn::optim::{AdamWConfig, ModuleOptimizer};
use serde::{Deserialize, Serialize};

use crate::schedule::learning_rate;
use bevworld_types::ConfigProblem;
use bevworld_types::problem::require_positive;

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OptimizerConfig {
    pub lr: f64,
    pub beta_1: f64,
    pub beta_2: f64,
    pub epsilon: f64,
    pub weight_decay: f64,
    pub warmup_steps: usize,
    /// The cosine decay ends at `lr · final_lr_fraction`.
    pub final_lr_fraction: f64,
    /// The step at which the cosine decay reaches its floor; absent: the run's last step.
    /// Beyond it, a run stops on the way down, at the learning rate that step of the longer
    /// schedule has.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub decay_steps: Option<usize>,
    /// Clip the gradients' global norm to this.
    pub grad_clip_norm: f64,
}

impl OptimizerConfig {
    /// A fresh AdamW with these settings (no moments yet).
    pub fn adamw(&self) -> ModuleOptimizer {
        AdamWConfig::new()
            .with_beta_1(self.beta_1 as f32)
            .with_beta_2(self.beta_2 as f32)
            .with_epsilon(self.epsilon as f32)
            .with_weight_decay(self.weight_decay as f32)
            .init()
    }

    /// The learning rate of step `step` (counted from 0) of a run of `steps` steps.
    pub fn learning_rate(&self, step: usize, steps: usize) -> f64 {
        learning_rate(
            self.lr,
            self.warmup_steps,
            self.decay_steps.unwrap_or(steps),
            self.final_lr_fraction,
            step,
        )
    }

    /// Every problem, the fields named under `prefix` (e.g. `optimizer`).
    pub fn problems(&self, prefix: &str) -> Vec<ConfigProblem> {
        let mut problems = Vec::new();
        let field = |name: &str| format!("{prefix}.{name}");
        require_positive(&mut problems, &field("lr"), self.lr);
        require_positive(&mut problems, &field("epsilon"), self.epsilon);
        require_positive(&mut problems, &field("grad_clip_norm"), self.grad_clip_norm);
        for (name, value) in [("beta_1", self.beta_1), ("beta_2", self.beta_2)] {
            if !(0.0..1.0).contains(&value) {
                problems.push(ConfigProblem::new(
                    field(name),
                    format!("{value} (accepted: [0, 1))"),
                ));
            }
        }
        if !(self.weight_decay >= 0.0 && self.weight_decay.is_finite()) {
            problems.push(ConfigProblem::new(
                field("weight_decay"),
                format!("{} (accepted: >= 0)", self.weight_decay),
            ));
        }
        if !(0.0..=1.0).contains(&self.final_lr_fraction) {
            problems.push(ConfigProblem::new(
                field("final_lr_fraction"),
                format!("{} (accepted: [0, 1])", self.final_lr_fraction),
            ));
        }
        if self.decay_steps == Some(0) {
            problems.push(ConfigProblem::new(
                field("decay_steps"),
                "0 (accepted: an integer >= 1, or absent)",
            ));
        }
        problems
    }
}
