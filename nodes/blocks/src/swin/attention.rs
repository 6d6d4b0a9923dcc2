//! Multi-head self-attention inside a window, with a learned relative position bias.

use burn::module::Param;
use burn::nn::{Initializer, Linear, LinearConfig};
use burn::prelude::*;

use super::host_attention::{WindowGeometry, window_attention_on_host};
use super::window::relative_position_index;
use crate::attention::{attend, attention_logits, merge_heads, split_heads};
use crate::cache::TensorCache;
use crate::host::{inference_values, into_inference_values, runs_on_host};
use crate::linear_on_host::linear;

#[derive(Config, Debug)]
pub struct WindowAttentionConfig {
    pub dim: usize,
    pub heads: usize,
    /// Window side w; attention runs over w * w tokens.
    pub window: usize,
}

#[derive(Module, Debug)]
pub struct WindowAttention {
    qkv: Linear,
    proj: Linear,
    /// One bias per head for each of the (2w - 1)^2 relative offsets.
    bias_table: Param<Tensor<2>>,
    #[module(skip)]
    heads: usize,
    #[module(skip)]
    window: usize,
    /// The relative position index of the window side that runs, per device: built once,
    /// not on every forward pass.
    #[module(skip)]
    index: TensorCache<usize, 1, Int>,
}

impl WindowAttentionConfig {
    pub fn init(&self, device: &Device) -> WindowAttention {
        let span = 2 * self.window - 1;
        WindowAttention {
            qkv: LinearConfig::new(self.dim, 3 * self.dim).init(device),
            proj: LinearConfig::new(self.dim, self.dim).init(device),
            bias_table: Initializer::Normal {
                mean: 0.0,
                std: 0.02,
            }
            .init([span * span, self.heads], device),
            heads: self.heads,
            window: self.window,
            index: TensorCache::default(),
        }
    }
}

impl WindowAttention {
    /// `mask`, when given, is added to the logits of every window of its index:
    /// `[windows_per_image, N, N]`, with the batch's windows in `window_partition` order.
    // x: [B * windows, N, C] -> [B * windows, N, C], N = w * w
    pub fn forward(&self, x: Tensor<3>, mask: Option<Tensor<3>>) -> Tensor<3> {
        let [count, tokens, _] = x.dims();
        let device = x.device();
        let [q, k, v] = split_heads(&self.qkv, x, self.heads);
        // A map smaller than the configured window runs as one window of its own side; the
        // bias table is indexed with the offsets of the configured window.
        let index = self.index.get_or_build(tokens, &device, || {
            Tensor::<1, Int>::from_data(
                TensorData::new(self.offsets(tokens), [tokens * tokens]),
                &device,
            )
        });
        let bias = self
            .bias_table
            .val()
            .select(0, index) // [N * N, H]
            .reshape([tokens, tokens, self.heads])
            .permute([2, 0, 1])
            .reshape([1, self.heads, tokens, tokens]);
        let mut logits = attention_logits(q, k) + bias; // [B*, H, N, N]
        if let Some(mask) = mask {
            let [windows, _, _] = mask.dims();
            logits = (logits.reshape([count / windows, windows, self.heads, tokens, tokens])
                + mask.reshape([1, windows, 1, tokens, tokens]))
            .reshape([count, self.heads, tokens, tokens]);
        }
        merge_heads(&self.proj, attend(logits, v))
    }

    /// The whole attention sub-layer of a block on its normalised `[B, H, W, C]` map, windows
    /// of `window` tokens a side rolled by `shift`, for CPU inference: one host kernel
    /// (`host_attention`) between the `qkv` and output projections, with no pad, roll,
    /// partition or mask tensor. `None` when the map is under autodiff or on another device:
    /// the caller runs the tensor path.
    // [B, H, W, C] -> [B, H, W, C]
    pub fn forward_map_on_host(
        &self,
        map: &Tensor<4>,
        window: usize,
        shift: usize,
    ) -> Option<Tensor<4>> {
        if !runs_on_host(map) {
            return None;
        }
        let [batch, height, width, channels] = map.dims();
        let device = map.device();
        let tokens = window * window;
        let qkv = into_inference_values(linear(&self.qkv, map.clone())).ok()?;
        let qkv_bias = self
            .qkv
            .bias
            .as_ref()
            .and_then(|bias| inference_values(&bias.val()))
            .unwrap_or_else(|| vec![0.0; 3 * channels]);
        let table = inference_values(&self.bias_table.val()).unwrap_or_default();
        let heads = self.heads;
        let index = self.offsets(tokens);
        // [heads, N, N]
        let mut bias = vec![0f32; heads * tokens * tokens];
        for (pair, &row) in index.iter().enumerate() {
            for head in 0..heads {
                bias[head * tokens * tokens + pair] = table
                    .get(row as usize * heads + head)
                    .copied()
                    .unwrap_or(0.0);
            }
        }
        let out = window_attention_on_host(
            &qkv,
            &qkv_bias,
            &bias,
            WindowGeometry {
                batch,
                height,
                width,
                channels,
                heads,
                window,
                shift,
            },
        );
        let out = Tensor::<4>::from_data(
            TensorData::new(out, [batch, height, width, channels]),
            &device,
        );
        Some(linear(&self.proj, out))
    }

    /// The bias table rows of every token pair of a window of `tokens` tokens.
    fn offsets(&self, tokens: usize) -> Vec<i64> {
        let side = (tokens as f64).sqrt().round() as usize;
        if side == self.window {
            return relative_position_index(self.window);
        }
        // A smaller window: its offsets, placed in the configured window's table.
        let span = 2 * self.window as i64 - 1;
        let mut index = Vec::with_capacity(tokens * tokens);
        for i in 0..tokens {
            let (yi, xi) = ((i / side) as i64, (i % side) as i64);
            for j in 0..tokens {
                let (yj, xj) = ((j / side) as i64, (j % side) as i64);
                let (dy, dx) = (
                    yi - yj + self.window as i64 - 1,
                    xi - xj + self.window as i64 - 1,
                );
                index.push(dy * span + dx);
            }
        }
        index
    }
}
