//! The fine stage: one token per latent cell, only inside the coarse tokens that
//! `fine_tokens.rs` selects (where the context moves).
//!
//! The coarse transformer sees a scene at `p × p` cells a token, which is coarser than a car.
//! Where something moves, each selected coarse token is opened into its `p²` cells:
//!
//! - every cell of every frame is embedded from its own latent value; the future frames' cells
//!   also embed their ego-warped current latent and the coarse network's output token, which
//!   has seen the whole scene;
//! - fine blocks (the coarse model's `SpatialTemporalBlock`: causal attention over the frames
//!   of one cell, attention among the `p²` cells of one frame, an MLP, each under the frame's
//!   adaLN condition) run on the selected tokens only;
//! - an adaLN-modulated linear head, zero at initialisation, gives each future cell a
//!   correction that is added to the coarse prediction of that cell.
//!
//! So a model with a fine stage starts as the coarse model it extends, and where nothing moves
//! it is that model, at the coarse cost.

use bevworld_blocks::linear_on_host::linear;
use bevworld_blocks::{
    AdaLnModulation, AdaLnModulationConfig, modulated_layer_norm, sinusoidal_1d, sinusoidal_2d,
};
use burn::nn::{Initializer, Linear, LinearConfig};
use burn::prelude::*;
use burn::tensor::IndexingUpdateOp;

use crate::block::{NORM_EPSILON, SpatialTemporalBlock, SpatialTemporalBlockConfig};
use crate::fine_tokens::{FineTokenSelection, FineTokensConfig};
use crate::patch::patchify;

#[derive(Config, Debug)]
pub struct FineStageConfig {
    /// Latent channels C'.
    pub channels: usize,
    /// Cells per coarse token along each axis, p.
    pub patch: usize,
    /// The coarse token width D.
    pub coarse_width: usize,
    /// The fine token width.
    pub width: usize,
    pub depth: usize,
    pub heads: usize,
    /// The condition width c.
    pub condition: usize,
}

impl FineStageConfig {
    pub fn of(
        fine: &FineTokensConfig,
        channels: usize,
        patch: usize,
        coarse_width: usize,
        condition: usize,
    ) -> Self {
        Self::new(
            channels,
            patch,
            coarse_width,
            fine.width,
            fine.depth,
            fine.heads,
            condition,
        )
    }

    pub fn init(&self, device: &Device) -> FineStage {
        FineStage {
            value_embed: LinearConfig::new(self.channels, self.width).init(device),
            warp_embed: LinearConfig::new(self.channels, self.width).init(device),
            coarse_embed: LinearConfig::new(self.coarse_width, self.width).init(device),
            blocks: (0..self.depth)
                .map(|_| {
                    SpatialTemporalBlockConfig::new(
                        self.width,
                        self.heads,
                        2 * self.width,
                        self.condition,
                    )
                    .init(device)
                })
                .collect(),
            final_modulation: AdaLnModulationConfig::new(self.condition, self.width, 2)
                .init(device),
            head: LinearConfig::new(self.width, self.channels)
                .with_initializer(Initializer::Zeros)
                .init(device),
            patch: self.patch,
            channels: self.channels,
            width: self.width,
        }
    }
}

#[derive(Module, Debug)]
pub struct FineStage {
    /// A cell's latent value, every frame.
    value_embed: Linear,
    /// A future cell's ego-warped current latent.
    warp_embed: Linear,
    /// The coarse network's output token over a future cell.
    coarse_embed: Linear,
    blocks: Vec<SpatialTemporalBlock>,
    final_modulation: AdaLnModulation,
    head: Linear,
    #[module(skip)]
    patch: usize,
    #[module(skip)]
    channels: usize,
    #[module(skip)]
    width: usize,
}

/// What the fine stage reads of one forward pass.
pub struct FineInputs<'a> {
    /// Every frame, condition frames first: `[B, F, C', H, W]`.
    pub latents: Tensor<5>,
    /// The last N frames' ego-warped current latent, `[B, N, C', H, W]`, when the model has one.
    pub warped: Option<Tensor<5>>,
    /// The coarse network's output tokens of the last N frames, `[B, N, L, D]`.
    pub coarse: Tensor<4>,
    /// Every frame's condition, `[B, F, c]`.
    pub condition: Tensor<3>,
    /// The additive causal mask over the F frames, `[F, F]`.
    pub causal: Tensor<2>,
    pub selection: &'a FineTokenSelection,
}

impl FineStage {
    /// Each selected token's correction of the coarse head's patch values; zero in every
    /// token not selected.
    // -> [B, N, L, C'·p·p], in `patchify`'s value order
    pub fn forward(&self, inputs: FineInputs<'_>) -> Tensor<4> {
        let FineInputs {
            latents,
            warped,
            coarse,
            condition,
            causal,
            selection,
        } = inputs;
        let [batch, frames, _, _, _] = latents.dims();
        let [_, future, tokens, coarse_width] = coarse.dims();
        let device = latents.device();
        let (p, c, w) = (self.patch, self.channels, self.width);
        let cells = p * p;
        let values = c * cells;
        let zero = || Tensor::<4>::zeros([batch, future, tokens, values], &device);
        let (rows, items) = selection.rows_and_items(tokens);
        let selected = rows.len();
        assert_eq!(
            selection.tokens.len(),
            batch,
            "one selection per batch item"
        );
        if selected == 0 {
            return zero();
        }
        let rows = Tensor::<1, Int>::from_data(TensorData::new(rows, [selected]), &device);
        let items = Tensor::<1, Int>::from_data(TensorData::new(items, [selected]), &device);

        // The selected tokens' cells, one fine token each.
        // [B, F', C', H, W] -> [S, F', p², C']
        let cells_of = |x: Tensor<5>| -> Tensor<4> {
            let [_, f, _, _, _] = x.dims();
            patchify(x, p) // [B, F', L, C'·p²]
                .swap_dims(1, 2) // [B, L, F', C'·p²]
                .reshape([batch * tokens, f, values])
                .select(0, rows.clone()) // [S, F', C'·p²]
                .reshape([selected, f, c, cells])
                .swap_dims(2, 3)
        };
        let position = sinusoidal_2d(p, p, w, &device).reshape([1, 1, cells, w]);
        let time = sinusoidal_1d(frames, w, &device).reshape([1, frames, 1, w]);
        let mut future_part = coarse
            .swap_dims(1, 2) // [B, L, N, D]
            .reshape([batch * tokens, future, coarse_width])
            .select(0, rows.clone()); // [S, N, D]
        future_part = linear(&self.coarse_embed, future_part);
        let mut future_part = future_part
            .reshape([selected, future, 1, w])
            .repeat_dim(2, cells); // [S, N, p², w]
        if let Some(warped) = warped {
            future_part = future_part + linear(&self.warp_embed, cells_of(warped));
        }
        let future_part = if future < frames {
            let clean = Tensor::zeros([selected, frames - future, cells, w], &device);
            Tensor::cat(vec![clean, future_part], 1)
        } else {
            future_part
        };
        let x = linear(&self.value_embed, cells_of(latents)) + position + time + future_part; // [S, F, p², w]
        let condition = condition.select(0, items); // [S, F, c]
        let x = self.blocks.iter().fold(x, |x, block| {
            block.forward(x, condition.clone(), causal.clone())
        });

        // The head, on the future frames' cells.
        let first = frames - future;
        let m: Vec<Tensor<4>> = self
            .final_modulation
            .forward(condition.narrow(1, first, future))
            .into_iter()
            .map(|v| v.unsqueeze_dim(2))
            .collect();
        let h = modulated_layer_norm(
            x.narrow(1, first, future),
            m[0].clone(),
            m[1].clone(),
            NORM_EPSILON,
        );
        let correction = linear(&self.head, h) // [S, N, p², C']
            .swap_dims(2, 3) // [S, N, C', p²]
            .reshape([selected, future, values]);
        Tensor::<3>::zeros([batch * tokens, future, values], &device)
            .select_assign(0, rows, correction, IndexingUpdateOp::Add)
            .reshape([batch, tokens, future, values])
            .swap_dims(1, 2) // [B, N, L, C'·p²]
    }
}
