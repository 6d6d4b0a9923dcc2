//! The latent's compression and the RGB upsampler's shapes.

use bevworld_blocks::init::random_normal;
use bevworld_blocks::seeded_init;
use bevworld_tokenizer::decoder::RgbUpsamplerConfig;
use bevworld_tokenizer::latent::LatentCompressConfig;
use burn::prelude::*;

fn device() -> Device {
    Device::flex()
}

#[test]
fn compression_and_upsampling_shapes() {
    let compress = seeded_init(1, &device(), |d| LatentCompressConfig::new(32, 4).init(d));
    let latent = compress.forward(Tensor::zeros([1, 32, 12, 12], &device()));
    assert_eq!(latent.dims(), [1, 4, 12, 12]);

    let upsampler = seeded_init(2, &device(), |d| RgbUpsamplerConfig::new(16, 8, 3).init(d));
    let rgb = upsampler.forward(random_normal(3, [2, 16, 4, 6], 0.0, 1.0, &device()));
    assert_eq!(rgb.dims(), [2, 3, 32, 48]);
    let v = rgb.into_data().try_to_vec::<f32>().unwrap();
    assert!(v.iter().all(|&x| (0.0..=1.0).contains(&x)));
}
