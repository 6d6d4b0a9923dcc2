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
//! - With `ego_warp_input`, each future frame's tokens also embed the current latent warped
//!   into that frame by the ego motion (`ego_warp.rs`): the network sees where the static
//!   world will be instead of working out a sub-token resampling from the actions.
//! - A final adaLN-modulated linear layer, zero at initialisation, maps the future frames'
//!   tokens back to patches: the prediction (ε, v or x₀, `diffusion.target`) for them only.
//! - With `fine_tokens`, the coarse tokens where the context moves (`fine_tokens.rs`) are
//!   opened into one token per latent cell, and a fine stage (`fine_stage.rs`) corrects their
//!   cells' prediction; the rest of the scene costs what it did.

use bevworld_blocks::linear_on_host::linear;
use bevworld_blocks::{
    AdaLnModulation, AdaLnModulationConfig, TensorCache, causal_mask, modulated_layer_norm,
    sinusoidal_1d, sinusoidal_2d,
};
use burn::nn::{Initializer, Linear, LinearConfig};
use burn::prelude::*;

use crate::block::{NORM_EPSILON, SpatialTemporalBlock, SpatialTemporalBlockConfig};
use crate::condition::{Condition, ConditionConfig};
use crate::config::WorldModelConfig;
use crate::fine_stage::{FineInputs, FineStage, FineStageConfig};
use crate::fine_tokens::FineTokenSelection;
use crate::patch::{patchify, unpatchify};

#[derive(Module, Debug)]
pub struct WorldModel {
    patch_embed: Linear,
    /// The future frames' ego-warped current latent, embedded like a frame (`ego_warp_input`).
    warp_embed: Option<Linear>,
    condition: Condition,
    blocks: Vec<SpatialTemporalBlock>,
    final_modulation: AdaLnModulation,
    head: Linear,
    /// One token per latent cell where the context moves (`fine_tokens`).
    fine: Option<FineStage>,
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
    /// The fine stage's sizes, for a model with `fine_tokens`.
    pub fn fine_stage(&self) -> Option<FineStageConfig> {
        self.fine_tokens.as_ref().map(|fine| {
            FineStageConfig::of(
                fine,
                self.latent_channels,
                self.patch,
                self.width,
                2 * self.condition_half,
            )
        })
    }

    pub fn init(&self, device: &Device) -> WorldModel {
        let condition = ConditionConfig::new(self.condition_half).init(device);
        let condition_width = condition.width();
        WorldModel {
            patch_embed: LinearConfig::new(self.patch_values(), self.width).init(device),
            warp_embed: self
                .ego_warp_input
                .then(|| LinearConfig::new(self.patch_values(), self.width).init(device)),
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
            fine: self.fine_stage().map(|fine| fine.init(device)),
            patch: self.patch,
            channels: self.latent_channels,
            size: self.latent_size,
            width: self.width,
            space: TensorCache::default(),
        }
    }
}

/// The condition frames' keys and values in every block's temporal attention. Attention over
/// frames is causal and the condition frames are clean (level 0), so these are the same at
/// every sampling step: a forecast computes them once (`WorldModel::context`) and each step
/// runs the future frames alone (`WorldModel::forward_future`).
pub struct ContextCache {
    /// Per block: keys and values, `[B·L, H, P+1, d]` each.
    keys_values: Vec<[Tensor<4>; 2]>,
    frames: usize,
    /// The condition frames and their condition, `[B, P+1, C', H, W]` and `[B, P+1, c]`: what
    /// the fine stage, which runs every frame at every step, reads of them.
    latents: Tensor<5>,
    condition: Tensor<3>,
}

impl ContextCache {
    /// The number of condition frames it holds.
    pub fn frames(&self) -> usize {
        self.frames
    }
}

impl WorldModel {
    /// Patch tokens of frames `first..first + F` of a sequence, with their 2D and 1D positions;
    /// with `warped` (the last N frames' ego-warped current latent) and `ego_warp_input`, the
    /// last N frames' tokens also embed it.
    // latents: [B, F, C', H, W], warped: [B, N, C', H, W] -> [B, F, L, D]
    fn embed(&self, latents: Tensor<5>, first: usize, warped: Option<Tensor<5>>) -> Tensor<4> {
        let [_, frames, _, _, _] = latents.dims();
        let device = latents.device();
        let [rows, columns] = [self.size[0] / self.patch, self.size[1] / self.patch];
        let tokens = rows * columns;
        let width = self.width;
        let space = self.space.get_or_build(self.patch, &device, || {
            sinusoidal_2d(rows, columns, width, &device)
        }); // [L, D]
        let time = sinusoidal_1d(first + frames, width, &device).narrow(0, first, frames); // [F, D]
        let x = linear(&self.patch_embed, patchify(latents, self.patch)) // [B, F, L, D]
            + space.reshape([1, 1, tokens, width])
            + time.reshape([1, frames, 1, width]);
        match (&self.warp_embed, warped) {
            (Some(warp_embed), Some(warped)) => {
                let [batch, future, _, _, _] = warped.dims();
                let w = linear(warp_embed, patchify(warped, self.patch)); // [B, N, L, D]
                let w = if future < frames {
                    let clean = Tensor::zeros([batch, frames - future, tokens, width], &device);
                    Tensor::cat(vec![clean, w], 1)
                } else {
                    w
                };
                x + w
            }
            _ => x,
        }
    }

    /// Embeds every frame's tokens and runs the blocks, returning the tokens of all frames.
    /// `levels` holds each frame's noise level, row-major `[B, F]` (0: a clean condition
    /// frame); `warped`, the last N frames' ego-warped current latent (used with
    /// `ego_warp_input`).
    // latents: [B, F, C', H, W], actions: [B, F, 5] -> tokens [B, F, L, D], condition [B, F, c]
    pub fn encode(
        &self,
        latents: Tensor<5>,
        actions: Tensor<3>,
        levels: &[f32],
        warped: Option<Tensor<5>>,
    ) -> (Tensor<4>, Tensor<3>) {
        let [_, frames, _, _, _] = latents.dims();
        let causal = causal_mask(frames, &latents.device());
        let x = self.embed(latents, 0, warped);
        let condition = self.condition.forward(actions, levels);
        let x = self.blocks.iter().fold(x, |x, block| {
            block.forward(x, condition.clone(), causal.clone())
        });
        (x, condition)
    }

    /// Runs the clean condition frames (level 0) through the blocks once and keeps what the
    /// future frames attend to.
    // context: [B, P+1, C', H, W], actions: [B, P+1, 5]
    pub fn context(&self, context: Tensor<5>, actions: Tensor<3>) -> ContextCache {
        let [batch, frames, _, _, _] = context.dims();
        let causal = causal_mask(frames, &context.device());
        let condition = self.condition.forward(actions, &vec![0.0; batch * frames]);
        let mut x = self.embed(context.clone(), 0, None);
        let mut keys_values = Vec::with_capacity(self.blocks.len());
        for block in &self.blocks {
            let (next, kv) = block.forward_keeping(x, condition.clone(), causal.clone());
            x = next;
            keys_values.push(kv);
        }
        ContextCache {
            keys_values,
            frames,
            latents: context,
            condition,
        }
    }

    /// The prediction for N future frames that follow the condition frames of `cache`: the
    /// same as `forward` on the whole sequence, without running the condition frames again.
    // future: [B, N, C', H, W], actions: [B, N, 5], levels: B·N, warped: [B, N, C', H, W]
    //   -> [B, N, C', H, W]
    pub fn forward_future(
        &self,
        cache: &ContextCache,
        future: Tensor<5>,
        actions: Tensor<3>,
        levels: &[f32],
        warped: Option<Tensor<5>>,
    ) -> Tensor<5> {
        let batch = future.dims()[0];
        self.forward_future_selected(
            cache,
            future,
            actions,
            levels,
            warped,
            &FineTokenSelection::none(batch),
        )
    }

    /// `forward_future` with fine tokens where `selection` puts them (a model without a fine
    /// stage ignores it).
    pub fn forward_future_selected(
        &self,
        cache: &ContextCache,
        future: Tensor<5>,
        actions: Tensor<3>,
        levels: &[f32],
        warped: Option<Tensor<5>>,
        selection: &FineTokenSelection,
    ) -> Tensor<5> {
        let [_, frames, _, _, _] = future.dims();
        let all = cache.frames + frames;
        let device = future.device();
        // The rows of the future frames in the causal mask of the whole sequence.
        let mask = causal_mask(all, &device).narrow(0, cache.frames, frames); // [N, P+1+N]
        let condition = self.condition.forward(actions, levels);
        let mut x = self.embed(future.clone(), cache.frames, warped.clone());
        for (block, prefix) in self.blocks.iter().zip(&cache.keys_values) {
            x = block.forward_after(x, condition.clone(), prefix, mask.clone());
        }
        // No token opened: the coarse prediction as it is, without gathering anything.
        let correction = self
            .fine
            .as_ref()
            .filter(|_| selection.count() > 0)
            .map(|fine| {
                fine.forward(FineInputs {
                    latents: Tensor::cat(vec![cache.latents.clone(), future], 1),
                    warped,
                    coarse: x.clone(),
                    condition: Tensor::cat(vec![cache.condition.clone(), condition.clone()], 1),
                    causal: causal_mask(all, &device),
                    selection,
                })
            });
        self.head(x, condition, correction)
    }

    /// The prediction for the last `future` frames; `warped` is their ego-warped current
    /// latent, which a model with `ego_warp_input` embeds (and any other ignores).
    // latents: [B, F, C', H, W], actions: [B, F, 5], levels: B·F, warped: [B, future, C', H, W]
    //   -> [B, future, C', H, W]
    pub fn forward(
        &self,
        latents: Tensor<5>,
        actions: Tensor<3>,
        levels: &[f32],
        future: usize,
        warped: Option<Tensor<5>>,
    ) -> Tensor<5> {
        let batch = latents.dims()[0];
        self.forward_selected(
            latents,
            actions,
            levels,
            future,
            warped,
            &FineTokenSelection::none(batch),
        )
    }

    /// `forward` with fine tokens where `selection` puts them (a model without a fine stage
    /// ignores it).
    pub fn forward_selected(
        &self,
        latents: Tensor<5>,
        actions: Tensor<3>,
        levels: &[f32],
        future: usize,
        warped: Option<Tensor<5>>,
        selection: &FineTokenSelection,
    ) -> Tensor<5> {
        let [_, frames, _, _, _] = latents.dims();
        let (x, condition) = self.encode(latents.clone(), actions, levels, warped.clone());
        let first = frames - future;
        let x = x.narrow(1, first, future);
        // No token opened: the coarse prediction as it is, without gathering anything.
        let correction = self
            .fine
            .as_ref()
            .filter(|_| selection.count() > 0)
            .map(|fine| {
                fine.forward(FineInputs {
                    latents,
                    warped,
                    coarse: x.clone(),
                    condition: condition.clone(),
                    causal: causal_mask(frames, &x.device()),
                    selection,
                })
            });
        self.head(x, condition.narrow(1, first, future), correction)
    }

    /// The final adaLN-modulated projection back to latent patches, plus the fine stage's
    /// correction of the tokens it opened.
    // x: [B, N, L, D], condition: [B, N, c], correction: [B, N, L, C'·p·p] -> [B, N, C', H, W]
    fn head(&self, x: Tensor<4>, condition: Tensor<3>, correction: Option<Tensor<4>>) -> Tensor<5> {
        let m: Vec<Tensor<4>> = self
            .final_modulation
            .forward(condition)
            .into_iter()
            .map(|v| v.unsqueeze_dim(2))
            .collect();
        let h = modulated_layer_norm(x, m[0].clone(), m[1].clone(), NORM_EPSILON);
        let patches = linear(&self.head, h);
        let patches = match correction {
            Some(correction) => patches + correction,
            None => patches,
        };
        unpatchify(patches, self.patch, self.channels, self.size)
    }

    /// This model with `stage` as its fine stage: a model with fine tokens started from the
    /// trained weights of the coarse model it extends (its head is zero, so it starts as that
    /// model).
    pub fn with_fine_stage(mut self, stage: FineStage) -> Self {
        self.fine = Some(stage);
        self
    }

    /// Its fine stage, if it has one.
    pub fn fine_stage(&self) -> Option<&FineStage> {
        self.fine.as_ref()
    }

    /// The blocks, for tests of their initial state.
    pub fn blocks(&self) -> &[SpatialTemporalBlock] {
        &self.blocks
    }
}
