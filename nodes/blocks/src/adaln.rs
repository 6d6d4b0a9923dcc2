//! Adaptive layer norm (DiT's adaLN-Zero, Peebles and Xie 2023): a condition vector sets the
//! shift, scale and gate of each sub-layer, `x + g · f(LN(x)·(1 + γ) + β)`. The projection
//! starts at zero, so every gated sub-layer starts as the identity.

use burn::nn::{Initializer, Linear, LinearConfig};
use burn::prelude::*;
use burn::tensor::activation::silu;

/// Layer normalisation over the last axis without a learned affine (DiT's
/// `elementwise_affine=False`): AdaLN supplies the scale and shift.
// x: [..., C] -> [..., C]
pub fn layer_norm<const D: usize>(x: Tensor<D>, epsilon: f64) -> Tensor<D> {
    let (variance, mean) = x.clone().var_mean_bias(D - 1);
    (x - mean).div(variance.add_scalar(epsilon).sqrt())
}

/// `x · (1 + scale) + shift`, the modulation of a normalised activation.
// x: [..., C], shift and scale broadcastable to it -> [..., C]
pub fn modulate<const D: usize>(x: Tensor<D>, shift: Tensor<D>, scale: Tensor<D>) -> Tensor<D> {
    x.clone() + x * scale + shift
}

#[derive(Config, Debug)]
pub struct AdaLnModulationConfig {
    /// Width of the condition vector.
    pub condition: usize,
    /// Width of the modulated activations.
    pub dim: usize,
    /// Vectors produced, e.g. 3 per sub-layer (shift, scale, gate).
    pub chunks: usize,
}

/// `Linear(SiLU(c))`, split into `chunks` vectors of width `dim`; zero at initialisation.
#[derive(Module, Debug)]
pub struct AdaLnModulation {
    linear: Linear,
    #[module(skip)]
    chunks: usize,
}

impl AdaLnModulationConfig {
    pub fn init(&self, device: &Device) -> AdaLnModulation {
        AdaLnModulation {
            linear: LinearConfig::new(self.condition, self.chunks * self.dim)
                .with_initializer(Initializer::Zeros)
                .init(device),
            chunks: self.chunks,
        }
    }
}

impl AdaLnModulation {
    // c: [..., condition] -> chunks × [..., dim]
    pub fn forward<const D: usize>(&self, condition: Tensor<D>) -> Vec<Tensor<D>> {
        self.linear
            .forward(silu(condition))
            .chunk(self.chunks, D - 1)
    }
}
