//! What a camera ray sees beyond the voxel grid: sky, and structure taller or farther than the
//! grid. A small MLP maps the ray's direction (ego frame) to a voxel-space feature, and the
//! ray's rendered feature becomes `Σ wᵢ vᵢ + T · bg(d)`, with `T = 1 − Σ wᵢ` the light left
//! when the ray leaves the grid (the sky model of driving NeRFs such as EmerNeRF).
//!
//! Why: without it every ray that leaves the grid renders the zero feature, so the RGB
//! upsampler can only paint one colour there, while the sky's colour follows the elevation and
//! on nuScenes a third of each image lies above the grid's 15 m. The head reads the direction
//! alone, never the latent: it learns what is common to all scenes, and it cannot store a
//! scene's content. LiDAR depth is `Σ wᵢ tᵢ` as before: a return is always inside the scene.

use burn::nn::{Linear, LinearConfig};
use burn::prelude::*;
use burn::tensor::activation::relu;

/// Octaves of the direction's sinusoidal encoding.
const OCTAVES: usize = 4;

#[derive(Config, Debug, PartialEq)]
pub struct BackgroundConfig {
    /// Hidden width of the MLP.
    pub hidden: usize,
    /// Feature channels it predicts: the voxel channels C_v.
    pub channels: usize,
}

#[derive(Module, Debug)]
pub struct Background {
    hidden: Linear,
    output: Linear,
}

/// Encoded width of a direction: itself, and a sine and cosine per axis and octave.
pub fn encoded_width() -> usize {
    3 + 3 * 2 * OCTAVES
}

impl BackgroundConfig {
    pub fn init(&self, device: &Device) -> Background {
        Background {
            hidden: LinearConfig::new(encoded_width(), self.hidden).init(device),
            output: LinearConfig::new(self.hidden, self.channels).init(device),
        }
    }
}

/// `[d, sin(2ᵏ π d), cos(2ᵏ π d)]` for k = 0 .. OCTAVES, per axis.
// [R, 3] -> [R, 3 + 6 * OCTAVES]
pub fn encode_directions(directions: Tensor<2>) -> Tensor<2> {
    let mut parts = vec![directions.clone()];
    for k in 0..OCTAVES {
        let scaled = directions
            .clone()
            .mul_scalar(std::f64::consts::PI * (1 << k) as f64);
        parts.push(scaled.clone().sin());
        parts.push(scaled.cos());
    }
    Tensor::cat(parts, 1)
}

impl Background {
    /// The background feature of each ray direction (unit vectors, ego frame).
    // [R, 3] -> [R, C_v]
    pub fn forward(&self, directions: Tensor<2>) -> Tensor<2> {
        self.output
            .forward(relu(self.hidden.forward(encode_directions(directions))))
    }

    /// Rendered features with the background seen through what the grid left transparent.
    // features [R, C_v], opacity [R], directions [R, 3] -> [R, C_v]
    pub fn composite(
        &self,
        features: Tensor<2>,
        opacity: Tensor<1>,
        directions: Tensor<2>,
    ) -> Tensor<2> {
        let [rays] = opacity.dims();
        let transmittance = opacity.neg().add_scalar(1.0).reshape([rays, 1]);
        features + self.forward(directions) * transmittance
    }
}
