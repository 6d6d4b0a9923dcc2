//! One Swin Transformer block: (shifted) window attention and an MLP, each pre-normed and
//! residual. Maps whose sides are not multiples of the window are zero-padded on the bottom and
//! right, then cropped back, as Swin does.

use burn::nn::{LayerNorm, LayerNormConfig, Linear, LinearConfig};
use burn::prelude::*;

use super::attention::{WindowAttention, WindowAttentionConfig};
use super::window::{shift_mask, window_partition, window_reverse};
use crate::cache::TensorCache;
use crate::mlp::gelu_mlp;

#[derive(Config, Debug)]
pub struct SwinBlockConfig {
    pub dim: usize,
    pub heads: usize,
    pub window: usize,
    /// Shift the windows by half a window (every second block of a stage).
    #[config(default = false)]
    pub shifted: bool,
    #[config(default = 4.0)]
    pub mlp_ratio: f64,
}

#[derive(Module, Debug)]
pub struct SwinBlock {
    norm1: LayerNorm,
    attention: WindowAttention,
    norm2: LayerNorm,
    fc1: Linear,
    fc2: Linear,
    #[module(skip)]
    window: usize,
    #[module(skip)]
    shifted: bool,
    /// The shifted windows' mask per map size and device, built once.
    #[module(skip)]
    mask: TensorCache<(usize, usize, usize, usize), 3>,
}

impl SwinBlockConfig {
    pub fn init(&self, device: &Device) -> SwinBlock {
        let hidden = (self.dim as f64 * self.mlp_ratio) as usize;
        SwinBlock {
            norm1: LayerNormConfig::new(self.dim).init(device),
            attention: WindowAttentionConfig::new(self.dim, self.heads, self.window).init(device),
            norm2: LayerNormConfig::new(self.dim).init(device),
            fc1: LinearConfig::new(self.dim, hidden).init(device),
            fc2: LinearConfig::new(hidden, self.dim).init(device),
            window: self.window,
            shifted: self.shifted,
            mask: TensorCache::default(),
        }
    }
}

/// Window side and shift for an `H x W` map: a map no larger than the window is one window,
/// and then there is nothing to shift.
pub fn window_and_shift(
    height: usize,
    width: usize,
    window: usize,
    shifted: bool,
) -> (usize, usize) {
    let smallest = height.min(width);
    if smallest <= window {
        (smallest, 0)
    } else {
        (window, if shifted { window / 2 } else { 0 })
    }
}

impl SwinBlock {
    // [B, H, W, C] -> [B, H, W, C]
    pub fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        let [_, height, width, _] = x.dims();
        let (window, shift) = window_and_shift(height, width, self.window, self.shifted);
        let shortcut = x.clone();
        let normed = self.norm1.forward(x);
        let h = match self.attention.forward_map_on_host(&normed, window, shift) {
            Some(attended) => attended,
            None => self.attention_on_tensors(normed, window, shift),
        };
        let x = shortcut + h;
        let mlp = gelu_mlp(&self.fc1, &self.fc2, self.norm2.forward(x.clone()));
        x + mlp
    }
}

impl SwinBlock {
    /// The attention sub-layer with burn's ops (training, other devices): pad, roll, windows,
    /// attention with the shift mask, and back.
    // [B, H, W, C] (normalised) -> [B, H, W, C]
    fn attention_on_tensors(&self, mut h: Tensor<4>, window: usize, shift: usize) -> Tensor<4> {
        let [batch, height, width, channels] = h.dims();
        let device = h.device();
        let padded_h = height.div_ceil(window) * window;
        let padded_w = width.div_ceil(window) * window;
        if padded_h != height || padded_w != width {
            h = pad_bottom_right(h, padded_h, padded_w);
        }
        if shift > 0 {
            h = h.roll(&[-(shift as i64), -(shift as i64)], &[1, 2]);
        }
        let mask = (shift > 0).then(|| {
            self.mask
                .get_or_build((padded_h, padded_w, window, shift), &device, || {
                    let windows = (padded_h / window) * (padded_w / window);
                    let tokens = window * window;
                    Tensor::<3>::from_data(
                        TensorData::new(
                            shift_mask(padded_h, padded_w, window, shift),
                            [windows, tokens, tokens],
                        ),
                        &device,
                    )
                })
        });
        let windows = window_partition(h, window); // [B * nW, w*w, C]
        let attended = self.attention.forward(windows, mask);
        let mut h = window_reverse(attended, window, padded_h, padded_w);
        if shift > 0 {
            h = h.roll(&[shift as i64, shift as i64], &[1, 2]);
        }
        if padded_h != height || padded_w != width {
            h = h.slice([0..batch, 0..height, 0..width, 0..channels]);
        }
        h
    }
}

/// Zero-pads a `[B, H, W, C]` map to `[B, height, width, C]`.
fn pad_bottom_right(x: Tensor<4>, height: usize, width: usize) -> Tensor<4> {
    let [batch, h, w, channels] = x.dims();
    let device = x.device();
    let x = if width > w {
        Tensor::cat(
            vec![x, Tensor::zeros([batch, h, width - w, channels], &device)],
            2,
        )
    } else {
        x
    };
    if height > h {
        Tensor::cat(
            vec![
                x,
                Tensor::zeros([batch, height - h, width, channels], &device),
            ],
            1,
        )
    } else {
        x
    }
}
