//! `configs/models/train-detector-*.yaml`: the detector, the tokenizer whose features it
//! reads, the three synthetic sets (training, validation tuned on, test touched only for the
//! reported figure) and where their exported features go, and the optimisation.

use std::path::{Path, PathBuf};

use bevworld_heads::config::{ConfigError, checked};
use bevworld_heads::{InputKind, LossWeights};
use bevworld_sensors::synth::SynthSet;
use bevworld_training::OptimizerConfig;
use bevworld_types::ConfigProblem;
use bevworld_types::problem::{require_count, require_non_negative};
use serde::{Deserialize, Serialize};

/// A set of annotated scenes and the folder its features are exported into: one subfolder per
/// input (`bev_stats/`, `latent/`, `feature/`), each with its `index.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FeatureSet {
    pub synth: SynthSet,
    pub features: PathBuf,
}

impl FeatureSet {
    /// Where the features of `input` are.
    pub fn folder(&self, input: InputKind) -> PathBuf {
        self.features.join(input.name())
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrainDetectorConfig {
    pub model: PathBuf,
    pub tokenizer_model: PathBuf,
    pub tokenizer_weights: PathBuf,
    pub train: FeatureSet,
    pub val: FeatureSet,
    pub test: FeatureSet,
    pub seed: u64,
    pub steps: usize,
    pub batch: usize,
    /// Keyframes per forward pass; the passes of a step spread over the worker threads and
    /// their gradients are summed in order, so the run does not depend on the thread count.
    pub micro_batch: usize,
    pub optimizer: OptimizerConfig,
    /// `--init tokenizer`: the pretrained encoder's learning rate as a fraction of the heads'
    /// (a fresh encoder, `--init scratch`, learns at the heads' rate: it has nothing to keep).
    pub fine_tune_lr_fraction: f64,
    pub loss: LossWeights,
    /// Validation (on `val`) every this many steps, and at the end.
    pub validate_every: usize,
    pub checkpoint_every: usize,
}

impl TrainDetectorConfig {
    pub fn from_yaml_file(path: &Path) -> Result<Self, ConfigError> {
        let config: Self = bevworld_graph::yaml::from_yaml_file(path)?;
        let problems = config.problems();
        checked(config, problems, &path.display().to_string())
    }

    /// Every inconsistency, naming the field: among them, seed ranges that overlap, since a
    /// figure on scenes trained or tuned on is not a test figure.
    pub fn problems(&self) -> Vec<ConfigProblem> {
        let mut problems = self.optimizer.problems("optimizer");
        for (field, value) in [
            ("steps", self.steps),
            ("batch", self.batch),
            ("micro_batch", self.micro_batch),
            ("validate_every", self.validate_every),
            ("checkpoint_every", self.checkpoint_every),
        ] {
            require_count(&mut problems, field, value);
        }
        if !(self.fine_tune_lr_fraction > 0.0 && self.fine_tune_lr_fraction <= 1.0) {
            problems.push(ConfigProblem::new(
                "fine_tune_lr_fraction",
                format!(
                    "{} is not in (0, 1]: the pretrained encoder learns at a fraction of the heads' rate",
                    self.fine_tune_lr_fraction
                ),
            ));
        }
        for (field, value) in [
            ("loss.heatmap", self.loss.heatmap),
            ("loss.boxes", self.loss.boxes),
            ("loss.motion", self.loss.motion),
        ] {
            require_non_negative(&mut problems, field, value);
        }
        if !(self.loss.moving.is_finite() && self.loss.moving >= 1.0) {
            problems.push(ConfigProblem::new(
                "loss.moving",
                format!(
                    "{} is not ≥ 1: a moving agent counts at least as much as a standing one",
                    self.loss.moving
                ),
            ));
        }
        let sets = [
            ("train", &self.train),
            ("val", &self.val),
            ("test", &self.test),
        ];
        for (i, (name, set)) in sets.iter().enumerate() {
            for (other, other_set) in &sets[..i] {
                let (a, b) = (set.synth.seeds(), other_set.synth.seeds());
                if a.start < b.end && b.start < a.end {
                    problems.push(ConfigProblem::new(
                        format!("{name}.synth.seed"),
                        format!(
                            "seeds {a:?} overlap the {other} set's {b:?}: the three sets must be disjoint"
                        ),
                    ));
                }
                if set.features == other_set.features {
                    problems.push(ConfigProblem::new(
                        format!("{name}.features"),
                        format!("the same folder as the {other} set's"),
                    ));
                }
            }
        }
        problems
    }
}
