//! The spatial-temporal transformer block (BEVWorld, "Latent BEV Sequence Diffusion"):
//!
//! 1. causal temporal attention: each spatial token attends to the same token in its own frame
//!    and in earlier frames only;
//! 2. spatial attention among the tokens of one frame;
//! 3. an MLP.
//!
//! Each sub-layer is modulated by its frame's condition (adaLN-Zero, DiT):
//! `x ← x + g · f(LN(x)·(1 + γ) + β)` with `(β, γ, g) = Linear(SiLU(c))` started at zero, so the
//! block starts as the identity.

use bevworld_blocks::attention_on_host::SequenceRows;
use bevworld_blocks::host::runs_on_host;
use bevworld_blocks::{
    AdaLnModulation, AdaLnModulationConfig, Mlp, MlpConfig, MultiHeadAttention,
    MultiHeadAttentionConfig, gated_residual, modulated_layer_norm,
};
use burn::prelude::*;

/// LayerNorm's ε, as DiT's.
pub const NORM_EPSILON: f64 = 1e-6;

#[derive(Config, Debug)]
pub struct SpatialTemporalBlockConfig {
    pub width: usize,
    pub heads: usize,
    pub mlp_hidden: usize,
    pub condition: usize,
}

#[derive(Module, Debug)]
pub struct SpatialTemporalBlock {
    temporal: MultiHeadAttention,
    spatial: MultiHeadAttention,
    mlp: Mlp,
    /// Shift, scale and gate of each of the three sub-layers.
    modulation: AdaLnModulation,
}

impl SpatialTemporalBlockConfig {
    pub fn init(&self, device: &Device) -> SpatialTemporalBlock {
        SpatialTemporalBlock {
            temporal: MultiHeadAttentionConfig::new(self.width, self.heads).init(device),
            spatial: MultiHeadAttentionConfig::new(self.width, self.heads).init(device),
            mlp: MlpConfig::new(self.width, self.mlp_hidden).init(device),
            modulation: AdaLnModulationConfig::new(self.condition, self.width, 9).init(device),
        }
    }
}

impl SpatialTemporalBlock {
    /// `causal` is the additive mask over frames (`bevworld_blocks::causal_mask`).
    // x: [B, F, L, D], condition: [B, F, c], causal: [F, F] -> [B, F, L, D]
    pub fn forward(&self, x: Tensor<4>, condition: Tensor<3>, causal: Tensor<2>) -> Tensor<4> {
        self.run(x, condition, None, causal, false).0
    }

    /// The block over frames that follow `prefix` frames already run through it: their
    /// temporal keys and values, `[B·L, H, P, d]` each, are attended to before the frames' own.
    /// Condition frames never attend to later ones, so theirs are the same whatever follows
    /// them, and a forecast computes them once for all its sampling steps
    /// (`forward_keeping`). `mask` is the additive mask of these F frames over the P + F.
    // x: [B, F, L, D], condition: [B, F, c], prefix: 2 × [B·L, H, P, d], mask: [F, P + F]
    //   -> [B, F, L, D]
    pub fn forward_after(
        &self,
        x: Tensor<4>,
        condition: Tensor<3>,
        prefix: &[Tensor<4>; 2],
        mask: Tensor<2>,
    ) -> Tensor<4> {
        self.run(x, condition, Some(prefix), mask, false).0
    }

    /// `forward`, also returning the frames' temporal keys and values, `[B·L, H, F, d]` each:
    /// a later call's `prefix`.
    // x: [B, F, L, D], condition: [B, F, c], causal: [F, F]
    //   -> [B, F, L, D], 2 × [B·L, H, F, d]
    pub fn forward_keeping(
        &self,
        x: Tensor<4>,
        condition: Tensor<3>,
        causal: Tensor<2>,
    ) -> (Tensor<4>, [Tensor<4>; 2]) {
        let (x, kept) = self.run(x, condition, None, causal, true);
        (x, kept.expect("kept when asked"))
    }

    // x: [B, F, L, D], condition: [B, F, c], prefix: 2 × [B·L, H, P, d], mask: [F, P + F]
    //   -> [B, F, L, D], with `keep` 2 × [B·L, H, F, d]
    fn run(
        &self,
        x: Tensor<4>,
        condition: Tensor<3>,
        prefix: Option<&[Tensor<4>; 2]>,
        mask: Tensor<2>,
        keep: bool,
    ) -> (Tensor<4>, Option<[Tensor<4>; 2]>) {
        let [batch, frames, tokens, width] = x.dims();
        // Nine [B, F, 1, D] vectors, broadcast over the frame's tokens.
        let m: Vec<Tensor<4>> = self
            .modulation
            .forward(condition)
            .into_iter()
            .map(|v| v.unsqueeze_dim(2))
            .collect();
        let on_host = runs_on_host(&x);

        // 1. Causal temporal attention: one sequence of frames per spatial token.
        let h = modulated_layer_norm(x.clone(), m[0].clone(), m[1].clone(), NORM_EPSILON);
        let (h, kept) = if on_host {
            // The [B, F, L, D] rows read in place, one sequence per (b, l).
            let across = SequenceRows::across_frames(batch, frames, tokens);
            self.temporal
                .forward_rows_on_host(h, across, prefix, Some(mask), keep)
        } else {
            let h = h
                .swap_dims(1, 2) // [B, L, F, D]
                .reshape([batch * tokens, frames, width]);
            let (h, keys_values) =
                self.temporal
                    .forward_after(h, prefix, Some(mask.unsqueeze::<4>())); // mask: [1, 1, F, P + F]
            let h = h.reshape([batch, tokens, frames, width]).swap_dims(1, 2); // [B, F, L, D]
            (h, keep.then_some(keys_values))
        };
        let x = gated_residual(x, m[2].clone(), h);

        // 2. Spatial attention within each frame.
        let h = modulated_layer_norm(x.clone(), m[3].clone(), m[4].clone(), NORM_EPSILON);
        let h = if on_host {
            let within = SequenceRows::consecutive(batch * frames, tokens);
            self.spatial
                .forward_rows_on_host(h, within, None, None, false)
                .0
        } else {
            self.spatial
                .forward(h.reshape([batch * frames, tokens, width]), None)
                .reshape([batch, frames, tokens, width])
        };
        let x = gated_residual(x, m[5].clone(), h);

        // 3. The MLP.
        let h = modulated_layer_norm(x.clone(), m[6].clone(), m[7].clone(), NORM_EPSILON);
        (gated_residual(x, m[8].clone(), self.mlp.forward(h)), kept)
    }
}
