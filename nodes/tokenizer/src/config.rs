//! The tokenizer's sizes, read from `configs/models/tokenizer-*.yaml`, and the sizes that
//! follow from them. `problems` reports every inconsistency at once, naming the field.

use std::path::Path;

use burn::prelude::*;

use crate::decoder::VoxelLiftConfig;
use crate::modality::Modality;
use crate::render::rays::{VoxelPlacement, sample_depths_near_dense};
use bevworld_blocks::swin::SwinConfig;
use bevworld_types::ConfigProblem;

/// The BEV region the latent covers, in the ego frame (metres), and its pillar grid.
#[derive(Config, Debug, PartialEq)]
pub struct BevRegion {
    pub x_range: [f64; 2],
    pub y_range: [f64; 2],
    pub z_range: [f64; 2],
    /// Pillars along x and along y (384 in the paper).
    pub pillar_grid: usize,
}

#[derive(Config, Debug, PartialEq)]
pub struct RenderConfig {
    /// Samples per ray, N_r (150 in the paper).
    pub samples: usize,
    pub near: f64,
    pub far: f64,
    /// Samples are evenly spaced in depth from `near` to here, then evenly spaced in disparity
    /// out to `far`; `far` gives the paper's uniform spacing.
    pub linear_until: f64,
    /// Camera rays are cast on a grid this many times coarser than the image (8).
    pub camera_stride: usize,
    /// Hidden width of the MLP that predicts α from a voxel feature.
    pub alpha_hidden: usize,
    /// Hidden width of the RGB upsampler.
    pub upsampler_hidden: usize,
    /// Hidden width of the background MLP, which gives camera rays leaving the grid a feature
    /// from their direction (`decoder::background`); 0: no background, rays see zero there.
    pub background_hidden: usize,
    /// A ray's remaining transmittance adds depth `far` to its expected depth, as 4D-Occ's
    /// renderer puts the probability that a ray escapes at the grid's exit. Without it (what
    /// the shipped tiny weights were trained with) the escaping mass adds nothing, and a ray
    /// the field leaves transparent ends near the sensor: inside the ROI, where a Chamfer
    /// distance counts it. With it, training keeps only the returns inside the voxel box
    /// (`bev`): a return beyond the box would ask the field for fog inside it.
    pub escape_at_far: bool,
}

#[derive(Config, Debug, PartialEq)]
pub struct TokenizerConfig {
    pub name: String,
    pub cameras: usize,
    /// Network input size of every camera image, [height, width].
    pub image_size: [usize; 2],
    pub bev: BevRegion,
    pub image_backbone: SwinConfig,
    /// Channels of the pillar feature net (64).
    pub pillar_channels: usize,
    /// Swin on the pillar BEV; its output grid is the latent grid, its width the fused width.
    pub lidar_backbone: SwinConfig,
    /// Reference points per BEV cell along the pillar's height (K = 4).
    pub fusion_heights: usize,
    /// Image backbone stages the fusion reads, counted from the last (1: the last stage's
    /// features only; 2: also the stage before it, at twice the resolution).
    pub fusion_levels: usize,
    pub latent_channels: usize,
    pub decoder: VoxelLiftConfig,
    pub render: RenderConfig,
    /// What the encoder reads and training renders: both, or one for the paper's modality
    /// ablation (C→C or L→L).
    pub modalities: Vec<Modality>,
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

impl RenderConfig {
    /// The fixed depths every ray is sampled at, metres.
    pub fn sample_depths(&self) -> Vec<f32> {
        sample_depths_near_dense(
            self.near as f32,
            self.linear_until as f32,
            self.far as f32,
            self.samples,
        )
    }
}

impl TokenizerConfig {
    /// Reads and checks a model YAML.
    pub fn from_yaml_file(path: &Path) -> Result<Self, ConfigError> {
        let shown = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|e| ConfigError::Read {
            path: shown.clone(),
            message: e.to_string(),
        })?;
        Self::from_yaml(&text, &shown)
    }

    /// The config as YAML, as `from_yaml` reads it back.
    pub fn to_yaml(&self) -> Result<String, ConfigError> {
        serde_saphyr::to_string(self).map_err(|e| ConfigError::Read {
            path: self.name.clone(),
            message: e.to_string(),
        })
    }

    pub fn from_yaml(text: &str, origin: &str) -> Result<Self, ConfigError> {
        let read_error = |message: String| ConfigError::Read {
            path: origin.to_string(),
            message,
        };
        let config: Self = serde_saphyr::from_str(text)
            .map_err(|e| read_error(bevworld_graph::yaml::describe_at(&e, text)))?;
        // burn's `Config` derive cannot deny unknown fields: compare the keys as written with
        // the config read back, so that a misspelt key is an error, not a silent default.
        let given: serde_json::Value = serde_saphyr::from_str(text)
            .map_err(|e| read_error(bevworld_graph::yaml::describe_at(&e, text)))?;
        let known = serde_json::to_value(&config).map_err(|e| read_error(e.to_string()))?;
        let mut problems = bevworld_types::problem::unknown_keys(&given, &known);
        problems.extend(config.problems());
        if problems.is_empty() {
            Ok(config)
        } else {
            Err(ConfigError::Invalid {
                path: origin.to_string(),
                problems,
            })
        }
    }

    /// Latent cells along y and x.
    pub fn latent_size(&self) -> usize {
        self.bev.pillar_grid / self.lidar_backbone.stride().max(1)
    }

    /// Channels of the fused BEV feature (before compression).
    pub fn fused_channels(&self) -> usize {
        self.lidar_backbone.out_channels()
    }

    /// Channels of the finer image feature levels the fusion reads besides the last stage's,
    /// finest first (`fusion_levels`).
    pub fn fusion_fine_channels(&self) -> Vec<usize> {
        let stages = self.image_backbone.depths.len();
        let first = stages.saturating_sub(self.fusion_levels.max(1));
        (first..stages.saturating_sub(1))
            .map(|stage| self.image_backbone.embed_dim << stage)
            .collect()
    }

    /// Image feature map size, [height, width].
    pub fn image_feature_size(&self) -> [usize; 2] {
        let stride = self.image_backbone.stride().max(1);
        [self.image_size[0] / stride, self.image_size[1] / stride]
    }

    /// Voxel grid `[C_v, Z, Y, X]`.
    pub fn voxel_shape(&self) -> [usize; 4] {
        let n = self.latent_size();
        self.decoder.voxel_shape(n, n)
    }

    /// Where the voxel grid sits in the ego frame.
    pub fn voxel_placement(&self) -> VoxelPlacement {
        let [_, z, y, x] = self.voxel_shape();
        let span = |r: [f64; 2], n: usize| ((r[1] - r[0]) / n.max(1) as f64) as f32;
        VoxelPlacement {
            min: [
                self.bev.x_range[0] as f32,
                self.bev.y_range[0] as f32,
                self.bev.z_range[0] as f32,
            ],
            voxel_size: [
                span(self.bev.x_range, x),
                span(self.bev.y_range, y),
                span(self.bev.z_range, z),
            ],
        }
    }

    /// Every inconsistency, one line each, naming the field.
    pub fn problems(&self) -> Vec<ConfigProblem> {
        let mut problems = self.image_backbone.problems("image_backbone");
        problems.extend(self.lidar_backbone.problems("lidar_backbone"));
        if self.image_backbone.in_channels != 3 {
            problems.push(ConfigProblem::new(
                "image_backbone.in_channels",
                "must be 3 (RGB)",
            ));
        }
        if self.lidar_backbone.in_channels != self.pillar_channels {
            problems.push(ConfigProblem::new(
                "lidar_backbone.in_channels",
                format!(
                    "{} but pillar_channels is {}",
                    self.lidar_backbone.in_channels, self.pillar_channels
                ),
            ));
        }
        for (name, r) in [
            ("bev.x_range", self.bev.x_range),
            ("bev.y_range", self.bev.y_range),
            ("bev.z_range", self.bev.z_range),
        ] {
            if !(r[0] < r[1]) {
                problems.push(ConfigProblem::new(
                    name,
                    format!("[{}, {}] is empty", r[0], r[1]),
                ));
            }
        }
        let stride = self.lidar_backbone.stride();
        if self.bev.pillar_grid == 0 || stride == 0 || !self.bev.pillar_grid.is_multiple_of(stride)
        {
            problems.push(ConfigProblem::new(
                "bev.pillar_grid",
                format!(
                    "{} is not a multiple of the LiDAR backbone's stride {stride}",
                    self.bev.pillar_grid
                ),
            ));
        }
        let image_stride = self.image_backbone.stride();
        if self
            .image_size
            .iter()
            .any(|&s| s == 0 || s % image_stride.max(1) != 0)
        {
            problems.push(ConfigProblem::new(
                "image_size",
                format!(
                    "{:?} is not a multiple of the image backbone's stride {image_stride}",
                    self.image_size
                ),
            ));
        }
        let camera_stride = self.render.camera_stride;
        if camera_stride == 0
            || !camera_stride.is_power_of_two()
            || self.image_size.iter().any(|&s| s % camera_stride != 0)
        {
            problems.push(ConfigProblem::new(
                "render.camera_stride",
                format!("{camera_stride} must be a power of two dividing image_size"),
            ));
        }
        if self.decoder.latent_channels != self.latent_channels {
            problems.push(ConfigProblem::new(
                "decoder.latent_channels",
                format!(
                    "{} but latent_channels is {}",
                    self.decoder.latent_channels, self.latent_channels
                ),
            ));
        }
        if !self.decoder.dim.is_multiple_of(2) {
            problems.push(ConfigProblem::new(
                "decoder.dim",
                "must be even (patch expanding halves it)",
            ));
        }
        if self.voxel_shape()[3] != self.bev.pillar_grid {
            problems.push(ConfigProblem::new(
                "decoder.cell_split",
                format!(
                    "the voxel grid has {} cells across, the pillar grid {}",
                    self.voxel_shape()[3],
                    self.bev.pillar_grid
                ),
            ));
        }
        if !(self.render.near > 0.0 && self.render.near < self.render.far)
            || self.render.samples == 0
        {
            problems.push(ConfigProblem::new(
                "render",
                "needs 0 < near < far and at least one sample",
            ));
        }
        if !(self.render.near < self.render.linear_until
            && self.render.linear_until <= self.render.far)
        {
            problems.push(ConfigProblem::new(
                "render.linear_until",
                format!(
                    "{} must lie in (near, far] = ({}, {}]",
                    self.render.linear_until, self.render.near, self.render.far
                ),
            ));
        }
        if self.fusion_levels == 0 || self.fusion_levels > self.image_backbone.depths.len() {
            problems.push(ConfigProblem::new(
                "fusion_levels",
                format!(
                    "{} must be between 1 and the image backbone's {} stages",
                    self.fusion_levels,
                    self.image_backbone.depths.len()
                ),
            ));
        }
        if self.cameras == 0 || self.fusion_heights == 0 || self.latent_channels == 0 {
            problems.push(ConfigProblem::new(
                "cameras",
                "cameras, fusion_heights and latent_channels must be positive",
            ));
        }
        if self.modalities.is_empty() {
            problems.push(ConfigProblem::new(
                "modalities",
                "needs camera, lidar, or both",
            ));
        }
        if (1..self.modalities.len()).any(|i| self.modalities[..i].contains(&self.modalities[i])) {
            problems.push(ConfigProblem::new(
                "modalities",
                format!("{:?} names one twice", self.modalities),
            ));
        }
        problems
    }

    /// Whether the encoder reads the cameras and training renders them.
    pub fn uses(&self, modality: Modality) -> bool {
        self.modalities.contains(&modality)
    }
}
