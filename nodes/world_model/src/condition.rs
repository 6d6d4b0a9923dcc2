//! The per-frame condition `c_i = [action embedding, diffusion-timestep embedding]`
//! (BEVWorld, "Latent BEV Sequence Diffusion"): the ego's action taken into frame i, and the
//! noise level frame i carries (0 for the clean condition frames).

use bevworld_blocks::timestep_embedding;
use burn::nn::{Linear, LinearConfig};
use burn::prelude::*;
use burn::tensor::activation::silu;

use crate::actions::ACTION_FEATURES;

#[derive(Config, Debug)]
pub struct ConditionConfig {
    /// Width of each half of the condition.
    pub half: usize,
}

/// Two MLPs, one per half of the condition.
#[derive(Module, Debug)]
pub struct Condition {
    action_in: Linear,
    action_out: Linear,
    time_in: Linear,
    time_out: Linear,
    #[module(skip)]
    half: usize,
}

impl ConditionConfig {
    pub fn init(&self, device: &Device) -> Condition {
        Condition {
            action_in: LinearConfig::new(ACTION_FEATURES, self.half).init(device),
            action_out: LinearConfig::new(self.half, self.half).init(device),
            time_in: LinearConfig::new(self.half, self.half).init(device),
            time_out: LinearConfig::new(self.half, self.half).init(device),
            half: self.half,
        }
    }
}

impl Condition {
    /// Width of the whole condition vector.
    pub fn width(&self) -> usize {
        2 * self.half
    }

    /// `actions` are normalised action features (`ActionStats::normalise`); `levels` the noise
    /// level of every frame, row-major `[B, F]`.
    // actions: [B, F, 5], levels: B·F -> [B, F, 2·half]
    pub fn forward(&self, actions: Tensor<3>, levels: &[f32]) -> Tensor<3> {
        let [batch, frames, _] = actions.dims();
        let device = actions.device();
        let action = self
            .action_out
            .forward(silu(self.action_in.forward(actions)));
        let time = timestep_embedding(levels, self.half, &device); // [B·F, half]
        let time = self
            .time_out
            .forward(silu(self.time_in.forward(time)))
            .reshape([batch, frames, self.half]);
        Tensor::cat(vec![action, time], 2)
    }
}
