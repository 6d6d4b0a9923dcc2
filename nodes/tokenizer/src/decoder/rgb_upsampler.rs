//! The CNN that turns rendered camera features, cast on a grid 8 times coarser than the image,
//! into RGB at full resolution: a 3x3 convolution, then per 2x step a nearest upsampling and a
//! 3x3 convolution with ReLU, then a 3x3 convolution to RGB through a sigmoid.

use burn::nn::PaddingConfig2d;
use burn::nn::conv::{Conv2d, Conv2dConfig};
use burn::prelude::*;
use burn::tensor::activation::{relu, sigmoid};
use burn::tensor::module::interpolate;
use burn::tensor::ops::{InterpolateMode, InterpolateOptions};

#[derive(Config, Debug, PartialEq)]
pub struct RgbUpsamplerConfig {
    /// Channels of the rendered features (C_v).
    pub in_channels: usize,
    /// Hidden width of the convolutions.
    pub hidden: usize,
    /// Number of 2x steps: 3 for the paper's 1/8-resolution rays.
    pub doublings: usize,
}

#[derive(Module, Debug)]
pub struct RgbUpsampler {
    input: Conv2d,
    steps: Vec<Conv2d>,
    to_rgb: Conv2d,
}

fn conv3x3(input: usize, output: usize, device: &Device) -> Conv2d {
    Conv2dConfig::new([input, output], [3, 3])
        .with_padding(PaddingConfig2d::Explicit(1, 1, 1, 1))
        .init(device)
}

impl RgbUpsamplerConfig {
    pub fn init(&self, device: &Device) -> RgbUpsampler {
        RgbUpsampler {
            input: conv3x3(self.in_channels, self.hidden, device),
            steps: (0..self.doublings)
                .map(|_| conv3x3(self.hidden, self.hidden, device))
                .collect(),
            to_rgb: conv3x3(self.hidden, 3, device),
        }
    }
}

impl RgbUpsampler {
    /// RGB in [0, 1].
    // [N, C_v, h, w] -> [N, 3, h * 2^d, w * 2^d]
    pub fn forward(&self, features: Tensor<4>) -> Tensor<4> {
        let mut x = relu(self.input.forward(features));
        for step in &self.steps {
            let [_, _, h, w] = x.dims();
            x = interpolate(
                x,
                InterpolateOptions::new(InterpolateMode::Nearest).with_output_size([2 * h, 2 * w]),
            );
            x = relu(step.forward(x));
        }
        sigmoid(self.to_rgb.forward(x))
    }
}
