//! Deformable fusion: masked projections contribute nothing, and an unseen query keeps only its
//! residual.

use bevworld_tokenizer::encoder::fusion::DeformableFusionConfig;
use burn::prelude::*;
use burn::tensor::Distribution;

fn device() -> Device {
    Device::flex()
}

fn values<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data().try_to_vec::<f32>().expect("f32")
}

const CAMERAS: usize = 2;
const K: usize = 4;
const H: usize = 3;
const W: usize = 4;

fn inputs(seed_shift: f64) -> (Tensor<4>, Tensor<4>, Tensor<4>) {
    let bev = Tensor::<4>::random([1, 8, H, W], Distribution::Normal(0.0, 1.0), &device());
    let images = Tensor::<4>::random(
        [CAMERAS, 6, 5, 7],
        Distribution::Normal(seed_shift, 1.0),
        &device(),
    );
    let reference = Tensor::<4>::random(
        [CAMERAS, H * W, K, 2],
        Distribution::Uniform(-0.9, 0.9),
        &device(),
    );
    (bev, images, reference)
}

#[test]
fn a_camera_that_sees_no_point_contributes_nothing() {
    let fusion = DeformableFusionConfig::new(8, 6, CAMERAS, K).init(&device());
    let (bev, images, reference) = inputs(0.0);
    // Camera 1 sees nothing; camera 0 sees everything.
    let mut valid = vec![1.0f32; H * W * K];
    valid.extend(vec![0.0f32; H * W * K]);
    let valid = Tensor::<3>::from_data(TensorData::new(valid, [CAMERAS, H * W, K]), &device());
    let out = values(fusion.forward(
        bev.clone(),
        images.clone(),
        reference.clone(),
        valid.clone(),
    ));

    // Replace camera 1's features with anything: the output must not move.
    let other = Tensor::<4>::random([1, 6, 5, 7], Distribution::Normal(5.0, 3.0), &device());
    let images2 = Tensor::cat(vec![images.clone().narrow(0, 0, 1), other], 0);
    let out2 = values(fusion.forward(bev.clone(), images2, reference.clone(), valid.clone()));
    for (a, b) in out.iter().zip(&out2) {
        assert!((a - b).abs() < 1e-5, "{a} vs {b}");
    }
    // Camera 0's features do matter.
    let other = Tensor::<4>::random([1, 6, 5, 7], Distribution::Normal(5.0, 3.0), &device());
    let images3 = Tensor::cat(vec![other, images.narrow(0, 1, 1)], 0);
    let out3 = values(fusion.forward(bev, images3, reference, valid));
    assert!(out.iter().zip(&out3).any(|(a, b)| (a - b).abs() > 1e-3));
}

#[test]
fn an_unseen_query_keeps_only_its_residual() {
    let fusion = DeformableFusionConfig::new(8, 6, CAMERAS, K).init(&device());
    let (bev, images, reference) = inputs(0.0);
    let nothing = Tensor::<3>::zeros([CAMERAS, H * W, K], &device());
    let out = values(fusion.forward(
        bev.clone(),
        images.clone(),
        reference.clone(),
        nothing.clone(),
    ));
    let (_, images2, _) = inputs(4.0);
    let out2 = values(fusion.forward(bev.clone(), images2, reference, nothing));
    assert_eq!(out, out2);
    assert!(out.iter().all(|v| v.is_finite()));
    assert_eq!(out.len(), 8 * H * W);
}
