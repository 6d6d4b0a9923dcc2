//! One training or validation example: `context` condition frames and `future` frames of a
//! sequence, with the action into every frame, the current latent warped into each future ego
//! frame (the ego-warp baseline, and the base a residual model adds to), and the target the
//! network learns to sample: the future latents, or their residual over that warp.

use bevworld_world_model::fine_tokens::select_for_context;
use bevworld_world_model::{
    ActionStats, EgoWarpBase, FineTokenRule, FineTokenSelection, LatentGrid, PlanarMotion,
    WorldModelConfig, warp_latent,
};
use burn::prelude::*;

use crate::data::Sequence;

/// How a window is cut and what it is turned into.
#[derive(Clone, Copy, Debug)]
pub struct WindowShape {
    pub context: usize,
    pub future: usize,
    pub grid: LatentGrid,
    /// What the future frames are diffused as the residual over.
    pub base: EgoWarpBase,
    /// For a model with fine tokens: its patch and which tokens get them.
    pub fine: Option<(usize, FineTokenRule)>,
}

/// A window on the host, standardised.
#[derive(Clone, Debug)]
pub struct WindowValues {
    /// `[context, C, H, W]`.
    pub context: Vec<f32>,
    /// `[future, C, H, W]`: the true future latents.
    pub future: Vec<f32>,
    /// `[future, C, H, W]`: the current latent warped into each future ego frame.
    pub warped: Vec<f32>,
    /// `[future]`: the warp's weight in each future frame's base (`EgoWarpBase::weight`).
    pub base_weights: Vec<f32>,
    /// `[context + future, 5]`, normalised.
    pub actions: Vec<f32>,
    /// The coarse tokens that get fine tokens (`fine_tokens::select_for_context`); empty
    /// without a fine stage.
    pub fine_tokens: Vec<usize>,
}

impl WindowShape {
    /// The model's own windows: its condition and future frames, its grid and target.
    pub fn of(config: &WorldModelConfig) -> Self {
        Self {
            context: config.context_frames,
            future: config.future_frames,
            grid: config.latent_grid(),
            base: config.ego_warp_base(),
            fine: Self::fine_of(config),
        }
    }

    /// A model's fine-token patch and rule, if it has a fine stage.
    pub fn fine_of(config: &WorldModelConfig) -> Option<(usize, FineTokenRule)> {
        config
            .fine_tokens
            .as_ref()
            .map(|fine| (config.patch, fine.select))
    }
}

impl WindowValues {
    /// Cuts frames `start .. start + context + future` of `sequence`; `start ≥ 1`.
    pub fn cut(
        sequence: &Sequence,
        start: usize,
        shape: &WindowShape,
        stats: &ActionStats,
    ) -> Self {
        let frames = shape.context + shape.future;
        let current = &sequence.frames[start + shape.context - 1];
        let mut context = Vec::with_capacity(shape.context * shape.grid.len());
        for frame in &sequence.frames[start..start + shape.context] {
            context.extend_from_slice(&frame.latent);
        }
        let mut future = Vec::with_capacity(shape.future * shape.grid.len());
        let mut warped = Vec::with_capacity(shape.future * shape.grid.len());
        let mut base_weights = Vec::with_capacity(shape.future);
        for frame in &sequence.frames[start + shape.context..start + frames] {
            future.extend_from_slice(&frame.latent);
            let horizon_s = (frame.time_us - current.time_us) as f64 * 1e-6;
            base_weights.push(shape.base.weight(horizon_s));
            let current_from_future =
                PlanarMotion::between(&current.global_from_ego, &frame.global_from_ego);
            warped.extend(warp_latent(
                &current.latent,
                &shape.grid,
                &current_from_future,
                0.0,
            ));
        }
        let fine_tokens = match &shape.fine {
            Some((patch, rule)) => {
                let condition = &sequence.frames[start..start + shape.context];
                let previous_from_frame: Vec<PlanarMotion> = condition
                    .windows(2)
                    .map(|pair| {
                        PlanarMotion::between(&pair[0].global_from_ego, &pair[1].global_from_ego)
                    })
                    .collect();
                select_for_context(&context, &shape.grid, &previous_from_frame, *patch, rule)
            }
            None => Vec::new(),
        };
        let actions = (start..start + frames)
            .flat_map(|k| {
                sequence
                    .action_into(k)
                    .map(|a| stats.normalise(&a))
                    .unwrap_or([0.0; 5])
            })
            .collect();
        Self {
            context,
            future,
            warped,
            base_weights,
            actions,
            fine_tokens,
        }
    }

    /// What a residual model adds its sample to: each future frame's warp times its weight.
    pub fn base(&self) -> Vec<f32> {
        let frame = self.warped.len() / self.base_weights.len().max(1);
        self.warped
            .chunks(frame.max(1))
            .zip(&self.base_weights)
            .flat_map(|(warped, &weight)| warped.iter().map(move |v| weight * v))
            .collect()
    }

    /// What the diffusion samples for the future frames: the latents less the base (the
    /// latents themselves where the base's weight is 0).
    pub fn diffused(&self) -> Vec<f32> {
        self.future
            .iter()
            .zip(self.base())
            .map(|(f, b)| f - b)
            .collect()
    }
}

/// Windows stacked into a batch on `device`.
pub struct WindowBatch {
    pub context: Tensor<5>,  // [B, context, C, H, W]
    pub diffused: Tensor<5>, // [B, future, C, H, W]
    /// What the sampled residual is added to (`WindowValues::base`).
    pub base: Tensor<5>, // [B, future, C, H, W]
    /// The current latent warped into each future frame (`ego_warp_input`).
    pub warped: Tensor<5>, // [B, future, C, H, W]
    pub actions: Tensor<3>,  // [B, context + future, 5]
    pub fine_tokens: FineTokenSelection,
}

impl WindowBatch {
    pub fn new(windows: &[&WindowValues], shape: &WindowShape, device: &Device) -> Self {
        let b = windows.len();
        let grid = shape.grid;
        let frames = |n: usize, values: Vec<f32>| {
            Tensor::<5>::from_data(
                TensorData::new(values, [b, n, grid.channels, grid.height, grid.width]),
                device,
            )
        };
        let gather = |f: &dyn Fn(&WindowValues) -> Vec<f32>| -> Vec<f32> {
            windows.iter().flat_map(|w| f(w)).collect()
        };
        Self {
            context: frames(shape.context, gather(&|w| w.context.clone())),
            diffused: frames(shape.future, gather(&|w| w.diffused())),
            base: frames(shape.future, gather(&|w| w.base())),
            warped: frames(shape.future, gather(&|w| w.warped.clone())),
            actions: Tensor::from_data(
                TensorData::new(
                    gather(&|w| w.actions.clone()),
                    [b, shape.context + shape.future, 5],
                ),
                device,
            ),
            fine_tokens: FineTokenSelection {
                tokens: windows.iter().map(|w| w.fine_tokens.clone()).collect(),
            },
        }
    }
}
