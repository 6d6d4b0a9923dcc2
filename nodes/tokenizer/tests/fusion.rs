//! Deformable fusion: masked projections contribute nothing, and an unseen query keeps only its
//! residual.

use bevworld_blocks::init::{random_normal, random_tensor};
use bevworld_blocks::seeded_init;
use bevworld_tokenizer::encoder::fusion::DeformableFusionConfig;
use burn::prelude::*;

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
    let bev = random_normal(1, [1, 8, H, W], 0.0, 1.0, &device());
    let images = random_normal(2, [CAMERAS, 6, 5, 7], seed_shift, 1.0, &device());
    let reference = random_tensor(3, [CAMERAS, H * W, K, 2], -0.9, 0.9, &device());
    (bev, images, reference)
}

#[test]
fn a_camera_that_sees_no_point_contributes_nothing() {
    let fusion = seeded_init(1, &device(), |d| {
        DeformableFusionConfig::new(8, 6, CAMERAS, K).init(d)
    });
    let (bev, images, reference) = inputs(0.0);
    // Camera 1 sees nothing; camera 0 sees everything.
    let mut valid = vec![1.0f32; H * W * K];
    valid.extend(vec![0.0f32; H * W * K]);
    let valid = Tensor::<3>::from_data(TensorData::new(valid, [CAMERAS, H * W, K]), &device());
    let out = values(fusion.forward(
        bev.clone(),
        images.clone(),
        Vec::new(),
        reference.clone(),
        valid.clone(),
    ));

    // Replace camera 1's features with anything: the output must not move.
    let other = random_normal(4, [1, 6, 5, 7], 5.0, 3.0, &device());
    let images2 = Tensor::cat(vec![images.clone().narrow(0, 0, 1), other], 0);
    let out2 = values(fusion.forward(
        bev.clone(),
        images2,
        Vec::new(),
        reference.clone(),
        valid.clone(),
    ));
    for (a, b) in out.iter().zip(&out2) {
        assert!((a - b).abs() < 1e-5, "{a} vs {b}");
    }
    // Camera 0's features do matter.
    let other = random_normal(5, [1, 6, 5, 7], 5.0, 3.0, &device());
    let images3 = Tensor::cat(vec![other, images.narrow(0, 1, 1)], 0);
    let out3 = values(fusion.forward(bev, images3, Vec::new(), reference, valid));
    assert!(out.iter().zip(&out3).any(|(a, b)| (a - b).abs() > 1e-3));
}

#[test]
fn an_unseen_query_keeps_only_its_residual() {
    let fusion = seeded_init(1, &device(), |d| {
        DeformableFusionConfig::new(8, 6, CAMERAS, K).init(d)
    });
    let (bev, images, reference) = inputs(0.0);
    let nothing = Tensor::<3>::zeros([CAMERAS, H * W, K], &device());
    let out = values(fusion.forward(
        bev.clone(),
        images.clone(),
        Vec::new(),
        reference.clone(),
        nothing.clone(),
    ));
    let (_, images2, _) = inputs(4.0);
    let out2 = values(fusion.forward(bev.clone(), images2, Vec::new(), reference, nothing));
    assert_eq!(out, out2);
    assert!(out.iter().all(|v| v.is_finite()));
    assert_eq!(out.len(), 8 * H * W);
}

#[test]
fn a_finer_level_is_read_only_where_its_camera_sees_the_point() {
    // One finer level of 3 channels at twice the coarse map's size.
    let fusion = seeded_init(2, &device(), |d| {
        DeformableFusionConfig::new(8, 6, CAMERAS, K)
            .with_fine_channels(vec![3])
            .init(d)
    });
    let (bev, images, reference) = inputs(0.0);
    let fine =
        |mean: f64| random_normal(6 + mean as u64, [CAMERAS, 3, 10, 14], mean, 1.0, &device());
    let mut valid = vec![1.0f32; H * W * K];
    valid.extend(vec![0.0f32; H * W * K]);
    let valid = Tensor::<3>::from_data(TensorData::new(valid, [CAMERAS, H * W, K]), &device());
    let level = fine(0.0);
    let run = |level: Tensor<4>| {
        values(fusion.forward(
            bev.clone(),
            images.clone(),
            vec![level],
            reference.clone(),
            valid.clone(),
        ))
    };
    let out = run(level.clone());
    assert!(out.iter().all(|v| v.is_finite()));

    // Camera 1 sees nothing: its fine features cannot move the output.
    let changed = Tensor::cat(
        vec![level.clone().narrow(0, 0, 1), fine(5.0).narrow(0, 1, 1)],
        0,
    );
    for (a, b) in out.iter().zip(&run(changed)) {
        assert!((a - b).abs() < 1e-5, "{a} vs {b}");
    }
    // Camera 0 sees every point: its fine features do.
    let changed = Tensor::cat(vec![fine(5.0).narrow(0, 0, 1), level.narrow(0, 1, 1)], 0);
    assert!(
        out.iter()
            .zip(&run(changed))
            .any(|(a, b)| (a - b).abs() > 1e-3)
    );
}
