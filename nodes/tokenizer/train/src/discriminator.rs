//! The patch discriminator of the GAN term: a small convolutional net that scores overlapping
//! patches of an image as real (input camera) or rendered, as in pix2pix's PatchGAN. It has
//! its own optimiser and enters training after the configured warm-up step.

use burn::nn::PaddingConfig2d;
use burn::nn::conv::{Conv2d, Conv2dConfig};
use burn::prelude::*;
use burn::tensor::activation::{leaky_relu, relu};

#[derive(Config, Debug)]
pub struct PatchDiscriminatorConfig {
    /// Channels of the first layer; the second has twice as many.
    pub channels: usize,
}

#[derive(Module, Debug)]
pub struct PatchDiscriminator {
    first: Conv2d,
    second: Conv2d,
    score: Conv2d,
}

fn conv(input: usize, output: usize, stride: usize, device: &Device) -> Conv2d {
    Conv2dConfig::new([input, output], [4, 4])
        .with_stride([stride, stride])
        .with_padding(PaddingConfig2d::Explicit(1, 1, 1, 1))
        .init(device)
}

impl PatchDiscriminatorConfig {
    pub fn init(&self, device: &Device) -> PatchDiscriminator {
        let c = self.channels;
        PatchDiscriminator {
            first: conv(3, c, 2, device),
            second: conv(c, 2 * c, 2, device),
            score: conv(2 * c, 1, 1, device),
        }
    }
}

impl PatchDiscriminator {
    /// One realness logit per patch.
    // [N, 3, H, W] in [0, 1] -> [N, 1, ~H/4, ~W/4]
    pub fn forward(&self, images: Tensor<4>) -> Tensor<4> {
        let x = images.mul_scalar(2.0).sub_scalar(1.0);
        let x = leaky_relu(self.first.forward(x), 0.2);
        let x = leaky_relu(self.second.forward(x), 0.2);
        self.score.forward(x)
    }
}

/// Hinge loss of the discriminator: `mean(relu(1 − D(real))) + mean(relu(1 + D(fake)))`.
pub fn discriminator_hinge(real: Tensor<4>, fake: Tensor<4>) -> Tensor<1> {
    relu(real.neg().add_scalar(1.0)).mean() + relu(fake.add_scalar(1.0)).mean()
}

/// The generator's adversarial loss: `−mean(D(fake))`.
pub fn generator_hinge(fake: Tensor<4>) -> Tensor<1> {
    fake.mean().neg()
}
