//! Changing resolution in a Swin stack: the patch embedding at the input, patch merging
//! (2 x 2 tokens -> one, channels x 2) going down, and patch expanding (the reverse) going up.
//! Merging and expanding share one 2 x 2 rearrangement and its exact inverse.

use crate::linear_on_host::linear;
use burn::nn::conv::{Conv2d, Conv2dConfig};
use burn::nn::{LayerNorm, LayerNormConfig, Linear, LinearConfig};
use burn::prelude::*;

/// Gathers each 2 x 2 block of tokens into one token of 4C channels, in Swin's order
/// (top-left, bottom-left, top-right, bottom-right).
// [B, H, W, C] -> [B, H / 2, W / 2, 4C]
pub fn space_to_depth(x: Tensor<4>) -> Tensor<4> {
    let [batch, height, width, channels] = x.dims();
    x.reshape([batch, height / 2, 2, width / 2, 2, channels])
        .permute([0, 1, 3, 4, 2, 5]) // [B, H/2, W/2, dx, dy, C]
        .reshape([batch, height / 2, width / 2, 4 * channels])
}

/// The exact inverse of `space_to_depth`.
// [B, H, W, 4C] -> [B, 2H, 2W, C]
pub fn depth_to_space(x: Tensor<4>) -> Tensor<4> {
    let [batch, height, width, channels4] = x.dims();
    let channels = channels4 / 4;
    x.reshape([batch, height, width, 2, 2, channels]) // [B, H, W, dx, dy, C]
        .permute([0, 1, 4, 2, 3, 5]) // [B, H, dy, W, dx, C]
        .reshape([batch, 2 * height, 2 * width, channels])
}

#[derive(Config, Debug)]
pub struct PatchEmbedConfig {
    pub in_channels: usize,
    pub dim: usize,
    pub patch: usize,
}

/// Non-overlapping `patch x patch` patches to tokens.
#[derive(Module, Debug)]
pub struct PatchEmbed {
    proj: Conv2d,
    norm: LayerNorm,
}

impl PatchEmbedConfig {
    pub fn init(&self, device: &Device) -> PatchEmbed {
        PatchEmbed {
            proj: Conv2dConfig::new([self.in_channels, self.dim], [self.patch, self.patch])
                .with_stride([self.patch, self.patch])
                .init(device),
            norm: LayerNormConfig::new(self.dim).init(device),
        }
    }
}

impl PatchEmbed {
    // [B, C_in, H, W] -> [B, H / p, W / p, C]
    pub fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        self.norm
            .forward(self.proj.forward(x).permute([0, 2, 3, 1]))
    }
}

/// Halves the resolution and doubles the channels.
#[derive(Module, Debug)]
pub struct PatchMerging {
    norm: LayerNorm,
    reduction: Linear,
}

pub fn patch_merging(dim: usize, device: &Device) -> PatchMerging {
    PatchMerging {
        norm: LayerNormConfig::new(4 * dim).init(device),
        reduction: LinearConfig::new(4 * dim, 2 * dim)
            .with_bias(false)
            .init(device),
    }
}

impl PatchMerging {
    // [B, H, W, C] -> [B, H / 2, W / 2, 2C]
    pub fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        linear(&self.reduction, self.norm.forward(space_to_depth(x)))
    }
}

/// Doubles the resolution and halves the channels: the decoder's reverse of patch merging.
#[derive(Module, Debug)]
pub struct PatchExpanding {
    expand: Linear,
    norm: LayerNorm,
}

pub fn patch_expanding(dim: usize, device: &Device) -> PatchExpanding {
    PatchExpanding {
        expand: LinearConfig::new(dim, 2 * dim)
            .with_bias(false)
            .init(device),
        norm: LayerNormConfig::new(dim / 2).init(device),
    }
}

impl PatchExpanding {
    // [B, H, W, C] -> [B, 2H, 2W, C / 2]
    pub fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        self.norm.forward(depth_to_space(linear(&self.expand, x)))
    }
}
