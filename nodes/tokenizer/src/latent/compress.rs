//! Compression of the fused BEV feature to the C' = 4 latent channels, a 1x1 convolution.

use burn::nn::conv::{Conv2d, Conv2dConfig};
use burn::prelude::*;

#[derive(Config, Debug, PartialEq)]
pub struct LatentCompressConfig {
    /// Channels of the fused BEV feature (256 in the paper).
    pub in_channels: usize,
    /// Latent channels C' (4).
    pub latent_channels: usize,
}

#[derive(Module, Debug)]
pub struct LatentCompress {
    proj: Conv2d,
}

impl LatentCompressConfig {
    pub fn init(&self, device: &Device) -> LatentCompress {
        LatentCompress {
            proj: Conv2dConfig::new([self.in_channels, self.latent_channels], [1, 1]).init(device),
        }
    }
}

impl LatentCompress {
    // [B, C, H, W] -> [B, C', H, W]
    pub fn forward(&self, bev: Tensor<4>) -> Tensor<4> {
        self.proj.forward(bev)
    }
}
