//! The detector's sizes (`configs/models/detector-*.yaml`) and what it reads: which BEV product,
//! on which grid, with how many channels, over how many frames. `problems` reports every
//! inconsistency at once, naming the field.

use std::path::Path;

use bevworld_blocks::swin::SwinConfig;
use bevworld_graph::yaml::YamlError;
use bevworld_types::detection::DETECTION_NAMES;
use bevworld_types::problem::{require_count, require_positive};
use bevworld_types::{BevGrid, ConfigProblem};
use serde::{Deserialize, Serialize};

/// The BEV product a detector reads: the three exports a user can make.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Hash, PartialOrd, Ord)]
#[serde(rename_all = "snake_case")]
pub enum InputKind {
    /// The weight-free pillar statistics of `export_bev_stats.yaml`.
    BevStats,
    /// The tokenizer's 4-channel latent.
    Latent,
    /// The tokenizer's fused BEV feature, before compression to the latent.
    Feature,
}

impl InputKind {
    pub const ALL: [InputKind; 3] = [InputKind::BevStats, InputKind::Latent, InputKind::Feature];

    /// The name on the command line and in files: `bev_stats`, `latent`, `feature`.
    pub fn name(self) -> &'static str {
        match self {
            InputKind::BevStats => "bev_stats",
            InputKind::Latent => "latent",
            InputKind::Feature => "feature",
        }
    }
}

/// What a detector's input is: fixed when training starts, from the exported features, and
/// kept with the weights.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InputSpec {
    pub kind: InputKind,
    /// Channels of one frame's map.
    pub channels: usize,
    pub grid: BevGrid,
    /// 1: the current frame; 2: the previous keyframe's map as well, warped into the current
    /// frame by the ego motion and stacked behind the current one.
    pub frames: usize,
    /// The model that made the maps and the digest of its weights (`none` for bev_stats): a
    /// detector reads only the features it was trained on.
    pub model: String,
    pub weights_hash: String,
    /// Per-channel mean and standard deviation of the training maps, which the detector
    /// standardises its input with.
    pub mean: Vec<f32>,
    pub std: Vec<f32>,
}

/// The motion head: K modes per agent, each a trajectory of `steps` positions `interval_s`
/// apart.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MotionConfig {
    pub modes: usize,
    pub steps: usize,
    pub interval_s: f64,
}

/// The trunk: a Swin stage over the BEV map (from `bevworld_blocks`), its patch chosen so that
/// every input lands on the same output grid.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrunkConfig {
    pub embed_dim: usize,
    pub depths: Vec<usize>,
    pub heads: Vec<usize>,
    pub window: usize,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DetectorConfig {
    pub name: String,
    /// Detection classes, each one of the nuScenes challenge's ten (`car`, `pedestrian`, …).
    pub classes: Vec<String>,
    /// Cells along each side of the output grid, on which every head predicts.
    pub output_cells: usize,
    pub trunk: TrunkConfig,
    /// Channels of each head's hidden 3×3 convolution.
    pub head_hidden: usize,
    pub motion: MotionConfig,
    /// The smallest radius, in output cells, of a box's Gaussian on the heatmap.
    pub min_radius: usize,
    /// Decoding: at most this many boxes per frame, each scoring at least `min_score`.
    pub max_detections: usize,
    pub min_score: f64,
}

/// Regression channels per cell: centre offset (2), height of the centre (1), log size (3),
/// sin and cos of the yaw (2), velocity (2).
pub const BOX_CHANNELS: usize = 10;

#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error(transparent)]
    Read(#[from] YamlError),
    #[error("{path}: {}", problems.iter().map(ToString::to_string).collect::<Vec<_>>().join("; "))]
    Invalid {
        path: String,
        problems: Vec<ConfigProblem>,
    },
}

/// `config` unless `problems` names something wrong with it.
pub fn checked<T>(config: T, problems: Vec<ConfigProblem>, path: &str) -> Result<T, ConfigError> {
    if problems.is_empty() {
        Ok(config)
    } else {
        Err(ConfigError::Invalid {
            path: path.to_string(),
            problems,
        })
    }
}

impl DetectorConfig {
    /// Reads and checks a model YAML.
    pub fn from_yaml_file(path: &Path) -> Result<Self, ConfigError> {
        let config: Self = bevworld_graph::yaml::from_yaml_file(path)?;
        let problems = config.problems();
        checked(config, problems, &path.display().to_string())
    }

    pub fn from_yaml(text: &str, origin: &str) -> Result<Self, ConfigError> {
        let config: Self = bevworld_graph::yaml::from_yaml_str(text, origin)?;
        let problems = config.problems();
        checked(config, problems, origin)
    }

    /// Every inconsistency, one line each, naming the field.
    pub fn problems(&self) -> Vec<ConfigProblem> {
        let mut problems = Vec::new();
        if self.classes.is_empty() {
            problems.push(ConfigProblem::new("classes", "needs at least one class"));
        }
        for (i, class) in self.classes.iter().enumerate() {
            if !DETECTION_NAMES.contains(&class.as_str()) {
                problems.push(ConfigProblem::new(
                    format!("classes[{i}]"),
                    format!(
                        "'{class}' (accepted: one of {})",
                        DETECTION_NAMES.join(", ")
                    ),
                ));
            }
            if self.classes[..i].contains(class) {
                problems.push(ConfigProblem::new(
                    format!("classes[{i}]"),
                    format!("'{class}' is listed twice"),
                ));
            }
        }
        for (field, value) in [
            ("output_cells", self.output_cells),
            ("head_hidden", self.head_hidden),
            ("motion.modes", self.motion.modes),
            ("motion.steps", self.motion.steps),
            ("min_radius", self.min_radius),
            ("max_detections", self.max_detections),
        ] {
            require_count(&mut problems, field, value);
        }
        require_positive(&mut problems, "motion.interval_s", self.motion.interval_s);
        if !(0.0..1.0).contains(&self.min_score) {
            problems.push(ConfigProblem::new(
                "min_score",
                format!("{} (accepted: [0, 1))", self.min_score),
            ));
        }
        if self.max_detections > bevworld_types::detection::MAX_BOXES_PER_SAMPLE {
            problems.push(ConfigProblem::new(
                "max_detections",
                format!(
                    "{} (the submission format allows {} per sample)",
                    self.max_detections,
                    bevworld_types::detection::MAX_BOXES_PER_SAMPLE
                ),
            ));
        }
        // The trunk with a patch of 1 stands for every patch: only the patch changes with the
        // input.
        problems.extend(self.swin(1, 1).problems("trunk"));
        if self.trunk.depths.len() > 1 {
            problems.push(ConfigProblem::new(
                "trunk.depths",
                "one stage: the heads predict at the trunk's own resolution",
            ));
        }
        if self.trunk.window > 0 && !self.output_cells.is_multiple_of(self.trunk.window) {
            problems.push(ConfigProblem::new(
                "trunk.window",
                format!(
                    "{} does not divide output_cells {}",
                    self.trunk.window, self.output_cells
                ),
            ));
        }
        problems
    }

    /// Problems of reading `input` with this detector, naming the input's field.
    pub fn input_problems(&self, input: &InputSpec) -> Vec<ConfigProblem> {
        let mut problems = Vec::new();
        let grid = &input.grid;
        if grid.height != grid.width
            || self.output_cells == 0
            || grid.height == 0
            || !grid.height.is_multiple_of(self.output_cells)
        {
            problems.push(ConfigProblem::new(
                "input.grid",
                format!(
                    "{} x {} cells: the detector needs a square grid, a multiple of its {} output cells",
                    grid.height, grid.width, self.output_cells
                ),
            ));
        }
        if !(1..=2).contains(&input.frames) {
            problems.push(ConfigProblem::new(
                "input.frames",
                format!("{} (accepted: 1 or 2)", input.frames),
            ));
        }
        require_count(&mut problems, "input.channels", input.channels);
        if input.mean.len() != input.channels || input.std.len() != input.channels {
            problems.push(ConfigProblem::new(
                "input.mean",
                format!(
                    "{} means and {} deviations for {} channels",
                    input.mean.len(),
                    input.std.len(),
                    input.channels
                ),
            ));
        }
        if input.std.iter().chain(&input.mean).any(|v| !v.is_finite())
            || input.std.iter().any(|s| *s <= 0.0)
        {
            problems.push(ConfigProblem::new(
                "input.std",
                "every mean must be finite and every deviation finite and above 0",
            ));
        }
        problems
    }

    /// The trunk for an input of `channels` channels (times frames) and patch `patch`.
    pub fn swin(&self, channels: usize, patch: usize) -> SwinConfig {
        SwinConfig::new(
            channels,
            patch,
            self.trunk.embed_dim,
            self.trunk.depths.clone(),
            self.trunk.heads.clone(),
            self.trunk.window,
        )
    }

    /// The trunk's patch for `input`: input cells per output cell.
    pub fn patch_for(&self, input: &InputSpec) -> usize {
        (input.grid.height / self.output_cells.max(1)).max(1)
    }

    /// The grid the heads predict on: the input's extent in `output_cells` cells.
    pub fn output_grid(&self, input: &InputSpec) -> BevGrid {
        let grid = input.grid;
        let cells = self.output_cells.max(1);
        BevGrid {
            x_range: grid.x_range,
            y_range: grid.y_range,
            resolution: (grid.x_range[1] - grid.x_range[0]) / cells as f32,
            height: cells,
            width: cells,
        }
    }

    /// The motion head's channels per cell: K modes of `steps` (x, y) offsets, then K logits.
    pub fn motion_channels(&self) -> usize {
        self.motion.modes * (2 * self.motion.steps + 1)
    }

    /// The class index of a detection name, when the detector predicts it.
    pub fn class_index(&self, detection_name: &str) -> Option<usize> {
        self.classes.iter().position(|c| c == detection_name)
    }
}
