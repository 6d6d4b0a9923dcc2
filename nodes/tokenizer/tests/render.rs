//! Trilinear sampling and volume rendering weights against hand-computed values, at the grid's
//! border, and against finite differences (sample points are data, so gradients flow to the
//! voxels). The numerical extremes are in `hard_cases.rs`.

use crate::common;
use common::weights_of;

use bevworld_tokenizer::render::{
    VoxelField, expected_depth, log_transmittance_after, render_weights, sample_trilinear,
};
use burn::prelude::*;

fn device() -> Device {
    Device::flex()
}

fn values<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data().try_to_vec::<f32>().expect("f32")
}

const C: usize = 2;
const Z: usize = 3;
const Y: usize = 4;
const X: usize = 5;

/// Voxel (c, z, y, x) of the test grid: distinct, non-linear values.
fn voxel(c: usize, z: usize, y: usize, x: usize) -> f32 {
    ((c * 7 + z * 31 + y * 17 + x * 5) % 23) as f32 * 0.25 - 2.0 + (x * y) as f32 * 0.1
}

fn grid(device: &Device) -> Tensor<5> {
    let mut data = Vec::new();
    for c in 0..C {
        for z in 0..Z {
            for y in 0..Y {
                for x in 0..X {
                    data.push(voxel(c, z, y, x));
                }
            }
        }
    }
    Tensor::from_data(TensorData::new(data, [1, C, Z, Y, X]), device)
}

/// Trilinear interpolation with zero padding, written out directly.
fn reference(c: usize, p: [f32; 3]) -> f32 {
    let (x0, y0, z0) = (p[0].floor(), p[1].floor(), p[2].floor());
    let (fx, fy, fz) = (p[0] - x0, p[1] - y0, p[2] - z0);
    let mut sum = 0.0;
    for dz in 0..2 {
        for dy in 0..2 {
            for dx in 0..2 {
                let (x, y, z) = (x0 as i64 + dx, y0 as i64 + dy, z0 as i64 + dz);
                if x < 0 || y < 0 || z < 0 || x >= X as i64 || y >= Y as i64 || z >= Z as i64 {
                    continue;
                }
                let w = (if dx == 1 { fx } else { 1.0 - fx })
                    * (if dy == 1 { fy } else { 1.0 - fy })
                    * (if dz == 1 { fz } else { 1.0 - fz });
                sum += w * voxel(c, z as usize, y as usize, x as usize);
            }
        }
    }
    sum
}

fn sample(points: &[[f32; 3]]) -> Vec<f32> {
    values(sample_trilinear(
        &VoxelField::from_grid(grid(&device())),
        points,
    ))
}

#[test]
fn trilinear_is_exact_at_voxel_centres() {
    let mut points = Vec::new();
    for z in 0..Z {
        for y in 0..Y {
            for x in 0..X {
                points.push([x as f32, y as f32, z as f32]);
            }
        }
    }
    let out = sample(&points);
    for (i, p) in points.iter().enumerate() {
        for c in 0..C {
            let expected = voxel(c, p[2] as usize, p[1] as usize, p[0] as usize);
            assert_eq!(out[i * C + c], expected, "{p:?} channel {c}");
        }
    }
}

#[test]
fn trilinear_is_linear_between_centres() {
    // Along x alone: a quarter of the way from (1, 2, 1) to (2, 2, 1).
    let out = sample(&[[1.25, 2.0, 1.0]]);
    let expected = 0.75 * voxel(0, 1, 2, 1) + 0.25 * voxel(0, 1, 2, 2);
    assert!((out[0] - expected).abs() < 1e-6);
    // Everywhere inside: the direct formula.
    let points = [
        [0.3, 0.7, 0.1],
        [3.9, 2.5, 1.5],
        [2.2, 0.0, 1.99],
        [1.5, 1.5, 0.5],
    ];
    let out = sample(&points);
    for (i, &p) in points.iter().enumerate() {
        for c in 0..C {
            assert!((out[i * C + c] - reference(c, p)).abs() < 1e-5, "{p:?}");
        }
    }
}

#[test]
fn trilinear_is_zero_outside_and_fades_at_the_border() {
    let points = [
        [-1.0, 1.0, 1.0],
        [X as f32, 1.0, 1.0],
        [2.0, -3.0, 1.0],
        [2.0, 1.0, Z as f32 + 0.5],
        [-50.0, 80.0, 1e6],
    ];
    assert!(sample(&points).iter().all(|&v| v == 0.0));
    // Half a voxel outside: half of the border voxel.
    let out = sample(&[[-0.5, 1.0, 1.0]]);
    assert!((out[0] - 0.5 * voxel(0, 1, 1, 0)).abs() < 1e-6);
}

#[test]
fn trilinear_gradients_match_finite_differences() {
    let device = Device::flex().autodiff();
    let points = [[1.3, 2.6, 0.4], [3.7, 0.2, 1.8], [-0.4, 1.1, 1.2]];
    // A fixed weighting of the outputs, so that the loss depends on every channel.
    let loss_of = |voxels: Tensor<5>| {
        let weights = Tensor::<2>::from_data(
            TensorData::new(vec![1.0f32, -0.5, 0.3, 2.0, -1.2, 0.7], [3, 2]),
            &voxels.device(),
        );
        (sample_trilinear(&VoxelField::from_grid(voxels), &points) * weights).sum()
    };
    let voxels = grid(&device).require_grad();
    let grads = loss_of(voxels.clone()).backward();
    let grad_v = values(voxels.grad(&grads).expect("voxel gradient"));

    let plain = Device::flex();
    let eval = |bump: Option<(usize, f32)>| -> f64 {
        let mut v = values(grid(&plain));
        if let Some((i, h)) = bump {
            v[i] += h;
        }
        let voxels = Tensor::<5>::from_data(TensorData::new(v, [1, C, Z, Y, X]), &plain);
        values(loss_of(voxels))[0] as f64
    };
    // The loss is linear in the voxels, so any step gives the exact derivative; most voxels
    // are no corner of any point and get exactly 0.
    let mut touched = 0;
    for (i, &analytic) in grad_v.iter().enumerate() {
        let numeric = (eval(Some((i, 1.0))) - eval(None)) as f32;
        assert!(
            (numeric - analytic).abs() < 1e-3,
            "voxel {i}: {analytic} vs {numeric}"
        );
        touched += usize::from(analytic != 0.0);
    }
    // 8 corners each for the two points inside, 4 for the one half outside in x (no corner
    // shared), two channels each.
    assert_eq!(touched, 2 * 20);
}

#[test]
fn weights_match_hand_computation() {
    // α = 0.5, 0.5, 0.5: w = 0.5, 0.25, 0.125.
    let w = weights_of(vec![0.0; 3], 1);
    for (got, want) in w.iter().zip([0.5, 0.25, 0.125]) {
        assert!((got - want).abs() < 1e-6, "{w:?}");
    }
}

#[test]
fn a_single_opaque_voxel_gives_its_depth() {
    let samples = 64;
    let depths: Vec<f32> = (0..samples).map(|i| 1.0 + 0.5 * i as f32).collect();
    let mut logits = vec![-30.0f32; samples];
    logits[37] = 30.0;
    let weights = Tensor::<2>::from_data(
        TensorData::new(weights_of(logits, 1), [1, samples]),
        &device(),
    );
    let t = Tensor::<2>::from_data(TensorData::new(depths.clone(), [1, samples]), &device());
    let depth = values(expected_depth(weights, t))[0];
    assert!(
        (depth - depths[37]).abs() < 1e-3,
        "{depth} vs {}",
        depths[37]
    );
}

#[test]
fn weights_sum_to_the_ray_opacity_and_never_above_one() {
    let (rays, samples) = (16, 200);
    let mut state = 7u32;
    let logits: Vec<f32> = (0..rays * samples)
        .map(|_| {
            state = state.wrapping_mul(1664525).wrapping_add(1013904223);
            (state >> 8) as f32 / (1 << 24) as f32 * 40.0 - 20.0
        })
        .collect();
    let w = weights_of(logits.clone(), rays);
    let log_t = values(log_transmittance_after(Tensor::from_data(
        TensorData::new(logits, [rays, samples]),
        &device(),
    )));
    for r in 0..rays {
        let sum: f32 = w[r * samples..(r + 1) * samples].iter().sum();
        let opacity = 1.0 - log_t[r * samples + samples - 1].exp();
        assert!(sum <= 1.0 + 1e-5, "ray {r}: {sum}");
        assert!((sum - opacity).abs() < 1e-4, "ray {r}: {sum} vs {opacity}");
    }
}

/// A field whose voxel blocks are split (`r` = 3) keeps its rows in the head's order; the
/// per-axis row terms that sampling adds up must give exactly `FieldShape::row`.
#[test]
fn row_terms_add_up_to_the_row_of_every_voxel() {
    let shape = bevworld_tokenizer::render::FieldShape {
        channels: 2,
        height: 3,
        cells_y: 4,
        cells_x: 5,
        split: 3,
    };
    let [x_terms, y_terms, z_terms] = shape.row_terms();
    assert_eq!(
        [z_terms.len(), y_terms.len(), x_terms.len()],
        shape.voxels()
    );
    let mut seen = vec![false; shape.rows()];
    for (iz, z_term) in z_terms.iter().enumerate() {
        for (iy, y_term) in y_terms.iter().enumerate() {
            for (ix, x_term) in x_terms.iter().enumerate() {
                let row = shape.row(ix, iy, iz);
                assert_eq!((x_term + y_term + z_term) as usize, row);
                assert!(!seen[row], "row {row} given twice");
                seen[row] = true;
            }
        }
    }
    assert!(seen.iter().all(|&s| s), "every row is some voxel's");
}

/// Sampling a split field (the head's layout) equals sampling the same voxels as a plain grid,
/// at points inside, on the border and outside, many more than one parallel task holds.
#[test]
fn a_split_field_samples_like_its_grid() {
    let device = device();
    let (channels, height, cells, split) = (3, 4, 6, 2);
    let block = height * split * split * channels;
    let head: Vec<f32> = (0..cells * cells * block)
        .map(|i| ((i * 37) % 101) as f32 * 0.01 - 0.5)
        .collect();
    let head = Tensor::<4>::from_data(TensorData::new(head, [1, cells, cells, block]), &device);
    let split_field = VoxelField::from_head(head, channels, height, split);
    let grid_field = VoxelField::from_grid(split_field.to_grid());
    let points: Vec<[f32; 3]> = (0..40_000)
        .map(|i| {
            let t = i as f32;
            [
                (t * 0.137).sin() * 7.0 + 5.5,
                (t * 0.071).cos() * 7.0 + 5.5,
                (t * 0.029).sin() * 2.6 + 1.5,
            ]
        })
        .collect();
    let split_values = values(sample_trilinear(&split_field, &points));
    let grid_values = values(sample_trilinear(&grid_field, &points));
    assert_eq!(split_values, grid_values);
    assert!(split_values.iter().any(|&v| v != 0.0) && split_values.contains(&0.0));
}

/// Points no ray should produce (NaN, infinite, beyond the i32 range) read nothing: exactly 0,
/// never NaN and never a wrapped-around voxel.
#[test]
fn nan_infinite_and_huge_points_sample_zero() {
    let bad = [
        [f32::NAN, 1.0, 1.0],
        [1.0, f32::NAN, 1.0],
        [1.0, 1.0, f32::NAN],
        [f32::INFINITY, 1.0, 1.0],
        [f32::NEG_INFINITY, 1.0, 1.0],
        [3e9, 1.0, 1.0],
        [-3e9, 1.0, 1.0],
        [1.0, 1.0, 4.3e9],
    ];
    let got = sample(&bad);
    assert_eq!(got, vec![0.0; bad.len() * C], "{got:?}");
    // Negative coordinates floor down, not toward zero: -0.25 lies between voxel -1 (outside,
    // weight 0.25) and voxel 0 (weight 0.75).
    let edge = sample(&[[-0.25, 1.0, 1.0]]);
    for (c, value) in edge.iter().enumerate() {
        assert!(
            (value - 0.75 * voxel(c, 1, 1, 0)).abs() < 1e-6,
            "channel {c}: {value}"
        );
    }
}

/// CPU inference samples with one host loop, autodiff with burn's gather and sum: the two
/// must agree, point for point, inside, on the border and outside the grid.
#[test]
fn the_host_sampler_agrees_with_the_autodiff_path() {
    let points: Vec<[f32; 3]> = (0..5_000)
        .map(|i| {
            let t = i as f32;
            [
                (t * 0.37).sin() * 3.5 + 2.0,
                (t * 0.23).cos() * 2.8 + 1.5,
                (t * 0.11).sin() * 2.2 + 1.0,
            ]
        })
        .collect();
    let host = sample(&points);
    let autodiff = Device::flex().autodiff();
    let field = VoxelField::from_grid(grid(&autodiff));
    assert!(field.host_table().is_none(), "autodiff keeps burn's ops");
    let ops = values(sample_trilinear(&field, &points));
    assert_eq!(host.len(), ops.len());
    for (i, (a, b)) in host.iter().zip(&ops).enumerate() {
        assert!((a - b).abs() <= 1e-6, "value {i}: host {a}, ops {b}");
    }
    assert!(
        VoxelField::from_grid(grid(&device()))
            .host_table()
            .is_some()
    );
}

/// Render weights for CPU inference come from a host loop, under autodiff from burn ops: the
/// two agree on logits from very transparent to very opaque, and on long rays.
#[test]
fn host_render_weights_agree_with_the_autodiff_path() {
    let (rays, samples) = (300, 97);
    let logits: Vec<f32> = (0..rays * samples)
        .map(|i| ((i * 7919) % 2001) as f32 / 1000.0 * 30.0 - 30.0 + (i % samples) as f32 * 0.05)
        .collect();
    let on = |device: &Device| {
        values(render_weights(Tensor::<2>::from_data(
            TensorData::new(logits.clone(), [rays, samples]),
            device,
        )))
    };
    let host = on(&device());
    let ops = on(&device().autodiff());
    for (i, (a, b)) in host.iter().zip(&ops).enumerate() {
        assert!(
            (a - b).abs() <= 2e-6 * b.abs().max(1e-3),
            "weight {i}: host {a}, ops {b}"
        );
    }
    for ray in host.chunks(samples) {
        let opacity: f32 = ray.iter().sum();
        assert!(
            opacity <= 1.0 + 1e-5 && ray.iter().all(|w| *w >= 0.0),
            "opacity {opacity}"
        );
    }
}
