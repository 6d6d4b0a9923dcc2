//! The transformer's position-wise MLP: `Linear → GELU → Linear` (GELU from `activation`,
//! vectorised for CPU inference).

use burn::nn::{Linear, LinearConfig};
use burn::prelude::*;

use crate::linear_on_host::{linear, linear_gelu};

/// `fc2(GELU(fc1(x)))`, the one definition Swin blocks (whose weights name the layers `fc1`
/// and `fc2` directly) and `Mlp` share.
// x: [..., C] -> [..., C_out]
pub fn gelu_mlp<const D: usize>(fc1: &Linear, fc2: &Linear, x: Tensor<D>) -> Tensor<D> {
    linear(fc2, linear_gelu(fc1, x))
}

#[derive(Config, Debug)]
pub struct MlpConfig {
    pub dim: usize,
    pub hidden: usize,
}

#[derive(Module, Debug)]
pub struct Mlp {
    fc1: Linear,
    fc2: Linear,
}

impl MlpConfig {
    pub fn init(&self, device: &Device) -> Mlp {
        Mlp {
            fc1: LinearConfig::new(self.dim, self.hidden).init(device),
            fc2: LinearConfig::new(self.hidden, self.dim).init(device),
        }
    }
}

impl Mlp {
    // [..., C] -> [..., C]
    pub fn forward<const D: usize>(&self, x: Tensor<D>) -> Tensor<D> {
        gelu_mlp(&self.fc1, &self.fc2, x)
    }
}
