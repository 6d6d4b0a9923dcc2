//! One training or validation example: `context` condition frames and `future` frames of a
//! sequence, with the action into every frame, the current latent warped into each future ego
//! frame (the ego-warp baseline, and the base a residual model adds to), and the target the
//! network learns to sample: the future latents, or their residual over that warp.

use bevworld_world_model::{ActionStats, LatentGrid, PlanarMotion, WorldModelConfig, warp_latent};
use burn::prelude::*;

use crate::data::Sequence;

/// How a window is cut and what it is turned into.
#[derive(Clone, Copy, Debug)]
pub struct WindowShape {
    pub context: usize,
    pub future: usize,
    pub grid: LatentGrid,
    pub residual: bool,
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
    /// `[context + future, 5]`, normalised.
    pub actions: Vec<f32>,
}

impl WindowShape {
    /// The model's own windows: its condition and future frames, its grid and target.
    pub fn of(config: &WorldModelConfig) -> Self {
        Self {
            context: config.context_frames,
            future: config.future_frames,
            grid: config.latent_grid(),
            residual: config.residual_over_ego_warp,
        }
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
        for frame in &sequence.frames[start + shape.context..start + frames] {
            future.extend_from_slice(&frame.latent);
            let current_from_future =
                PlanarMotion::between(&current.global_from_ego, &frame.global_from_ego);
            warped.extend(warp_latent(
                &current.latent,
                &shape.grid,
                &current_from_future,
                0.0,
            ));
        }
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
            actions,
        }
    }

    /// What the diffusion samples for the future frames: the latents, or with `residual`
    /// their difference from the warp.
    pub fn diffused(&self, residual: bool) -> Vec<f32> {
        if residual {
            self.future
                .iter()
                .zip(&self.warped)
                .map(|(f, w)| f - w)
                .collect()
        } else {
            self.future.clone()
        }
    }
}

/// Windows stacked into a batch on `device`.
pub struct WindowBatch {
    pub context: Tensor<5>,  // [B, context, C, H, W]
    pub diffused: Tensor<5>, // [B, future, C, H, W]
    pub warped: Tensor<5>,   // [B, future, C, H, W]
    pub actions: Tensor<3>,  // [B, context + future, 5]
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
            diffused: frames(shape.future, gather(&|w| w.diffused(shape.residual))),
            warped: frames(shape.future, gather(&|w| w.warped.clone())),
            actions: Tensor::from_data(
                TensorData::new(
                    gather(&|w| w.actions.clone()),
                    [b, shape.context + shape.future, 5],
                ),
                device,
            ),
        }
    }
}
