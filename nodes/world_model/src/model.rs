//! The world model (BEVWorld, "Latent BEV Sequence Diffusion"): a spatial-temporal diffusion
//! transformer over the BEV latents of P past frames, the current frame and N future frames.
//!
//! - Each frame `[C', H, W]` is cut into `p × p` patches, embedded to width D, and given the
//!   fixed 2D sine-cosine position of its token and the 1D position of its frame (any frame
//!   count: the count changes between training stages).
//! - Each frame carries the condition `c_i = [MLP(action_i), MLP(sin(t_i))]`; condition frames
//!   are clean (t = 0), the future frames carry the noise level they were given.
//! - Blocks of causal temporal attention, spatial attention and an MLP, each modulated by
//!   adaLN-Zero (`block.rs`).
//! - A final adaLN-modulated linear layer, zero at initialisation, maps the future frames'
//!   tokens back to patches: the prediction (ε, v or x₀, `diffusion.target`) for them only.

use bevworld_blocks::{
    AdaLnModulation, AdaLnModulationConfig, TensorCache, causal_mask, layer_norm, modulate,
    sinusoidal_1d, sinusoidal_2d,
};
use burn::nn::{Initializer, Linear, LinearConfig};
use burn::prelude::*;

use crate::block::{NORM_EPSILON, SpatialTemporalBlock, SpatialTemporalBlockConfig};
use crate::condition::{Condition, ConditionConfig};
use crate::config::WorldModelConfig;
use crate::patch::{patchify, unpatchify};

#[derive(Module, Debug)]
pub struct WorldModel {
    patch_embed: Linear,
    condition: Condition,
    blocks: Vec<SpatialTemporalBlock>,
    final_modulation: AdaLnModulation,
    head: Linear,
    #[module(skip)]
    patch: usize,
    #[module(skip)]
    channels: usize,
    #[module(skip)]
    size: [usize; 2],
    #[module(skip)]
    width: usize,
    /// The 2D token positions, built once per device.
    #[module(skip)]
    space: TensorCache<usize, 2>,
}

impl WorldModelConfig {
    pub fn init(&self, device: &Device) -> WorldModel {
        let condition = ConditionConfig::new(self.condition_half).init(device);
        let condition_width = condition.width();
        WorldModel {
            patch_embed: LinearConfig::new(self.patch_values(), self.width).init(device),
            condition,
            blocks: (0..self.depth)
                .map(|_| {
                    SpatialTemporalBlockConfig::new(
                        self.width,
                        self.heads,
                        self.mlp_hidden(),
                        condition_width,
                    )
                    .init(device)
                })
                .collect(),
            final_modulation: AdaLnModulationConfig::new(condition_width, self.width, 2)
                .init(device),
            head: LinearConfig::new(self.width, self.patch_values())
                .with_initializer(Initializer::Zeros)
                .init(device),
            patch: self.patch,
            channels: self.latent_channels,
            size: self.latent_size,
            width: self.width,
            space: TensorCache::default(),
        }
    }
}

impl WorldModel {
    /// Embeds every frame's tokens and runs the blocks, returning the tokens of all frames.
    /// `levels` holds each frame's noise level, row-major `[B, F]` (0: a clean condition
    /// frame).
    // latents: [B, F, C', H, W], actions: [B, F, 5] -> tokens [B, F, L, D], condition [B, F, c]
    pub fn encode(
        &self,
        latents: Tensor<5>,
        actions: Tensor<3>,
        levels: &[f32],
    ) -> (Tensor<4>, Tensor<3>) {
        let [_, frames, _, _, _] = latents.dims();
        let device = latents.device();
        let [rows, columns] = [self.size[0] / self.patch, self.size[1] / self.patch];
        let tokens = rows * columns;
        let width = self.width;
        let space = self.space.get_or_build(self.patch, &device, || {
            sinusoidal_2d(rows, columns, width, &device)
        }); // [L, D]
        let time = sinusoidal_1d(frames, width, &device); // [F, D]
        let x = self.patch_embed.forward(patchify(latents, self.patch)) // [B, F, L, D]
            + space.reshape([1, 1, tokens, width])
            + time.reshape([1, frames, 1, width]);
        let condition = self.condition.forward(actions, levels);
        let causal = causal_mask(frames, &device);
        let x = self.blocks.iter().fold(x, |x, block| {
            block.forward(x, condition.clone(), causal.clone())
        });
        (x, condition)
    }

    /// The prediction for the last `future` frames.
    // latents: [B, F, C', H, W], actions: [B, F, 5], levels: B·F -> [B, future, C', H, W]
    pub fn forward(
        &self,
        latents: Tensor<5>,
        actions: Tensor<3>,
        levels: &[f32],
        future: usize,
    ) -> Tensor<5> {
        let [_, frames, _, _, _] = latents.dims();
        let (x, condition) = self.encode(latents, actions, levels);
        let first = frames - future;
        self.head(
            x.narrow(1, first, future),
            condition.narrow(1, first, future),
        )
    }

    /// The final adaLN-modulated projection back to latent patches.
    // x: [B, N, L, D], condition: [B, N, c] -> [B, N, C', H, W]
    fn head(&self, x: Tensor<4>, condition: Tensor<3>) -> Tensor<5> {
        let m: Vec<Tensor<4>> = self
            .final_modulation
            .forward(condition)
            .into_iter()
            .map(|v| v.unsqueeze_dim(2))
            .collect();
        let h = modulate(layer_norm(x, NORM_EPSILON), m[0].clone(), m[1].clone());
        unpatchify(self.head.forward(h), self.patch, self.channels, self.size)
    }

    /// The blocks, for tests of their initial state.
    pub fn blocks(&self) -> &[SpatialTemporalBlock] {
        &self.blocks
    }
}
