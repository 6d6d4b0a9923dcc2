//! The tokenizer's hard cases, each against a known answer or an invariant:
//!
//! - transmittance underflow: 1000 opaque samples on one ray;
//! - empty space along a whole ray;
//! - rays that miss the grid: every sample outside it;
//! - points behind every camera: the fusion's projection masks them all;
//! - a sweep with no returns still encodes to a finite latent
//!   (`frame_input.rs::an_empty_sweep_still_encodes`, beside the frame's other inputs), and NaN,
//!   infinite and huge sample points sample zero (`render.rs`).

use crate::common;
use common::weights_of;

use bevworld_tokenizer::encoder::projection::{FusionCamera, project_points};
use bevworld_tokenizer::render::{VoxelField, log_transmittance_after, sample_trilinear};
use bevworld_types::{Intrinsics, Pose};
use burn::prelude::*;
use glam::DVec3;

fn device() -> Device {
    Device::flex()
}

fn values<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data().try_to_vec::<f32>().expect("f32")
}

#[test]
fn a_thousand_opaque_samples_neither_underflow_to_nan_nor_exceed_one() {
    let w = weights_of(vec![60.0; 1000], 1);
    assert!(w.iter().all(|v| v.is_finite() && *v >= 0.0));
    assert!((w[0] - 1.0).abs() < 1e-6);
    assert!(w[1..].iter().all(|&v| v < 1e-20));
    let log_t = values(log_transmittance_after(Tensor::from_data(
        TensorData::new(vec![60.0f32; 1000], [1, 1000]),
        &device(),
    )));
    assert!(log_t.iter().all(|v| v.is_finite()));
    // Each opaque sample adds log σ(−60) ≈ −60: the product of the transparencies is far
    // below f32's smallest number, its logarithm is not.
    assert!(log_t[999] < -1000.0);
}

#[test]
fn empty_space_renders_nothing() {
    let w = weights_of(vec![-40.0; 150], 1);
    assert!(w.iter().sum::<f32>() < 1e-6);
}

#[test]
fn a_ray_that_misses_the_grid_samples_nothing_on_its_whole_length() {
    // A 2-channel 4 × 6 × 8 field of ones: inside it every sample is 1.
    let field = VoxelField::from_grid(Tensor::ones([1, 2, 4, 6, 8], &device()));
    // A ray from just beside the grid (x = −2, more than one voxel out), going away from it,
    // 1000 samples out to 10,000 voxels; and one sample inside, as a control.
    let mut points: Vec<[f32; 3]> = (0..1000)
        .map(|i| [-2.0 - 10.0 * i as f32, 3.0, 1.5])
        .collect();
    points.push([4.0, 3.0, 1.5]);
    let sampled = values(sample_trilinear(&field, &points)); // [N, C]
    let (outside, inside) = sampled.split_at(2 * 1000);
    assert!(
        outside.iter().all(|v| *v == 0.0),
        "a missing ray sees nothing"
    );
    assert_eq!(inside, &[1.0, 1.0]);
    // Zero features everywhere give a finite ray: its logits are the head's bias, the same at
    // every sample, so its weights fall geometrically and sum below one.
    let w = weights_of(vec![0.0; 1000], 1);
    assert!(w.iter().all(|v| v.is_finite()));
    assert!(w.iter().sum::<f32>() <= 1.0 + 1e-6);
}

#[test]
fn points_behind_every_camera_are_masked_not_projected() {
    let intrinsics = Intrinsics {
        fx: 100.0,
        fy: 100.0,
        cx: 50.0,
        cy: 40.0,
        width: 100,
        height: 80,
    };
    // Six cameras around the car, each looking outward along its own axis (camera z).
    let cameras: Vec<FusionCamera> = (0..6)
        .map(|k| {
            let yaw = k as f64 * std::f64::consts::TAU / 6.0;
            // camera_from_ego: ego x forward; camera z = the ego direction at `yaw`.
            let forward = DVec3::new(yaw.cos(), yaw.sin(), 0.0);
            let right = DVec3::new(yaw.sin(), -yaw.cos(), 0.0);
            let down = DVec3::new(0.0, 0.0, -1.0);
            let rotation = glam::DMat3::from_cols(right, down, forward).transpose();
            FusionCamera {
                camera_from_bev_ego: Pose::from_mat3(rotation),
                intrinsics,
            }
        })
        .collect();
    // A point 5 m behind each camera, and one 5 m in front of it on its axis.
    for (k, camera) in cameras.iter().enumerate() {
        let yaw = k as f64 * std::f64::consts::TAU / 6.0;
        let axis = DVec3::new(yaw.cos(), yaw.sin(), 0.0);
        let hits = project_points(&[-5.0 * axis, 5.0 * axis], camera, 0.1);
        assert_eq!(hits.valid, vec![0.0, 1.0], "camera {k}");
        assert_eq!(
            hits.normalized[0],
            [0.0, 0.0],
            "a masked point samples nothing"
        );
        assert!(
            hits.normalized[1].iter().all(|v| v.abs() < 1e-9),
            "on the axis"
        );
    }
    // A point at the cameras' common centre is behind (at depth 0 of) every one of them.
    for camera in &cameras {
        let hits = project_points(&[DVec3::ZERO], camera, 0.1);
        assert_eq!(hits.valid, vec![0.0]);
        assert!(hits.normalized[0].iter().all(|v| v.is_finite()));
    }
}
