//! The background head: the direction encoding by hand, and compositing by the ray's
//! remaining transmittance (an opaque ray keeps its feature, a transparent one sees the head).

use bevworld_blocks::seeded_init;
use bevworld_tokenizer::decoder::BackgroundConfig;
use bevworld_tokenizer::decoder::background::{encode_directions, encoded_width};
use burn::prelude::*;

fn device() -> Device {
    Device::flex()
}

fn values<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data().try_to_vec::<f32>().expect("f32")
}

#[test]
fn directions_are_encoded_with_sines_and_cosines_per_octave() {
    let d = [0.6f32, 0.0, 0.8];
    let encoded = values(encode_directions(Tensor::<2>::from_data(
        TensorData::new(d.to_vec(), [1, 3]),
        &device(),
    )));
    assert_eq!(encoded.len(), encoded_width());
    assert_eq!(&encoded[..3], &d);
    for k in 0..4 {
        let f = std::f32::consts::PI * (1 << k) as f32;
        for axis in 0..3 {
            let sin = encoded[3 + 6 * k + axis];
            let cos = encoded[3 + 6 * k + 3 + axis];
            assert!(
                (sin - (f * d[axis]).sin()).abs() < 1e-5,
                "sin, octave {k}, axis {axis}"
            );
            assert!(
                (cos - (f * d[axis]).cos()).abs() < 1e-5,
                "cos, octave {k}, axis {axis}"
            );
        }
    }
}

#[test]
fn opaque_rays_keep_their_feature_and_transparent_ones_see_the_background() {
    let head = seeded_init(1, &device(), |d| BackgroundConfig::new(8, 4).init(d));
    let features = Tensor::<2>::from_data(
        TensorData::new((0..12).map(|i| i as f32).collect::<Vec<_>>(), [3, 4]),
        &device(),
    );
    let directions = Tensor::<2>::from_data(
        TensorData::new(vec![0.0f32, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0, 0.6, 0.8], [3, 3]),
        &device(),
    );
    let opacity = Tensor::<1>::from_data(TensorData::new(vec![1.0f32, 0.0, 0.25], [3]), &device());
    let background = values(head.forward(directions.clone()));
    let out = values(head.composite(features.clone(), opacity, directions));
    let f = values(features);
    for c in 0..4 {
        assert_eq!(out[c], f[c], "an opaque ray keeps its feature");
        assert!((out[4 + c] - (f[4 + c] + background[4 + c])).abs() < 1e-6);
        assert!((out[8 + c] - (f[8 + c] + 0.75 * background[8 + c])).abs() < 1e-5);
    }
    // The head reads the direction: two directions, two backgrounds.
    assert_ne!(&background[0..4], &background[4..8]);
}
