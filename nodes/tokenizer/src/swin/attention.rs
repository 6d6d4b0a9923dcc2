//! Multi-head self-attention inside a window, with a learned relative position bias.

use burn::module::Param;
use burn::nn::{Initializer, Linear, LinearConfig};
use burn::prelude::*;
use burn::tensor::activation::softmax;

use super::window::relative_position_index;

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
        }
    }
}

impl WindowAttention {
    /// `mask`, when given, is added to the logits of every window of its index:
    /// `[windows_per_image, N, N]`, with the batch's windows in `window_partition` order.
    // x: [B * windows, N, C] -> [B * windows, N, C], N = w * w
    pub fn forward(&self, x: Tensor<3>, mask: Option<Tensor<3>>) -> Tensor<3> {
        let [count, tokens, dim] = x.dims();
        let head_dim = dim / self.heads;
        let device = x.device();
        let qkv = self
            .qkv
            .forward(x)
            .reshape([count, tokens, 3, self.heads, head_dim])
            .permute([2, 0, 3, 1, 4]); // [3, B*, H, N, d]
        let part = |i: usize| {
            qkv.clone()
                .narrow(0, i, 1)
                .reshape([count, self.heads, tokens, head_dim])
        };
        let (q, k, v) = (part(0), part(1), part(2));
        let scale = (head_dim as f64).powf(-0.5);
        let mut logits = q.mul_scalar(scale).matmul(k.swap_dims(2, 3)); // [B*, H, N, N]

        let index = Tensor::<1, Int>::from_data(
            TensorData::new(relative_position_index(self.window), [tokens * tokens]),
            &device,
        );
        let bias = self
            .bias_table
            .val()
            .select(0, index) // [N * N, H]
            .reshape([tokens, tokens, self.heads])
            .permute([2, 0, 1])
            .reshape([1, self.heads, tokens, tokens]);
        logits = logits + bias;
        if let Some(mask) = mask {
            let [windows, _, _] = mask.dims();
            logits = (logits.reshape([count / windows, windows, self.heads, tokens, tokens])
                + mask.reshape([1, windows, 1, tokens, tokens]))
            .reshape([count, self.heads, tokens, tokens]);
        }
        let attention = softmax(logits, 3);
        let out = attention
            .matmul(v) // [B*, H, N, d]
            .swap_dims(1, 2)
            .reshape([count, tokens, dim]);
        self.proj.forward(out)
    }
}
