//! The fusion's bilinear sampler against a hand-computed value and against burn's own
//! `grid_sample_2d` (align_corners = false, zero padding): values and both gradients, at points
//! inside, on the border and outside the maps.

use bevworld_tokenizer::encoder::bilinear::sample_bilinear;
use burn::prelude::*;
use burn::tensor::ops::GridSampleOptions;

fn values<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data().try_to_vec::<f32>().expect("f32")
}

const N: usize = 2;
const C: usize = 3;
const H: usize = 4;
const W: usize = 5;

/// Channels-first maps `[N, C, H, W]` with distinct, non-linear values.
fn maps(device: &Device) -> Tensor<4> {
    let data: Vec<f32> = (0..N * C * H * W)
        .map(|i| ((i * 37) % 29) as f32 * 0.2 - 2.5 + (i % 7) as f32 * 0.05)
        .collect();
    Tensor::from_data(TensorData::new(data, [N, C, H, W]), device)
}

/// Points in [-1, 1] and beyond: interior, on pixel centres, on the outer edges, half a pixel
/// outside, and far outside.
fn points() -> Vec<[f32; 2]> {
    vec![
        [0.13, -0.27],
        [-0.8, 0.75],
        [0.2, 0.25],
        [-1.0, -1.0],
        [1.0, 1.0],
        [1.1, -0.3],
        [-0.5, -1.2],
        [3.0, 0.0],
        [0.97, 0.93],
    ]
}

fn grid(device: &Device) -> Tensor<3> {
    let flat: Vec<f32> = (0..N)
        .flat_map(|n| {
            points()
                .into_iter()
                .map(move |[x, y]| [x * (1.0 - 0.1 * n as f32), y])
        })
        .flatten()
        .collect();
    Tensor::from_data(TensorData::new(flat, [N, points().len(), 2]), device)
}

/// burn's reference: `[N, C, H, W]` sampled at `[N, P, 1, 2]` gives `[N, C, P, 1]`, here
/// rearranged to `[N, P, C]`.
fn reference(maps: Tensor<4>, grid: Tensor<3>) -> Tensor<3> {
    let [n, p, _] = grid.dims();
    maps.grid_sample_2d(grid.reshape([n, p, 1, 2]), GridSampleOptions::default())
        .reshape([n, C, p])
        .swap_dims(1, 2)
}

fn ours(maps: Tensor<4>, grid: Tensor<3>) -> Tensor<3> {
    sample_bilinear(maps.permute([0, 2, 3, 1]), grid)
}

#[test]
fn a_point_between_four_pixels_mixes_them_by_area() {
    let device = Device::flex();
    // One 2 x 2 single-channel map; (x, y) = (0, 0) is the centre of the map, halfway between
    // the four pixel centres; (-0.25, -0.5) is a quarter of the way from pixel (0, 0) to (1, 0)
    // along x: pixel x = (−0.25 + 1) * 2 / 2 − 0.5 = 0.25, y = (−0.5 + 1) − 0.5 = 0 exactly.
    let map = Tensor::<4>::from_data(
        TensorData::new(vec![1.0f32, 2.0, 3.0, 4.0], [1, 2, 2, 1]),
        &device,
    );
    let at = Tensor::<3>::from_data(
        TensorData::new(vec![0.0f32, 0.0, -0.25, -0.5, -1.0, -0.5], [1, 3, 2]),
        &device,
    );
    let out = values(sample_bilinear(map, at));
    assert!((out[0] - 2.5).abs() < 1e-6, "centre: {}", out[0]);
    assert!((out[1] - 1.25).abs() < 1e-6, "quarter along x: {}", out[1]);
    // On the left edge, half a pixel outside the first centre: half of pixel (0, 0), half zero.
    assert!((out[2] - 0.5).abs() < 1e-6, "left edge: {}", out[2]);
}

#[test]
fn values_match_grid_sample_2d_inside_on_the_border_and_outside() {
    let device = Device::flex();
    let expected = values(reference(maps(&device), grid(&device)));
    let got = values(ours(maps(&device), grid(&device)));
    assert_eq!(expected.len(), got.len());
    for (i, (e, g)) in expected.iter().zip(&got).enumerate() {
        assert!(
            (e - g).abs() < 1e-5,
            "element {i}: grid_sample_2d {e}, ours {g}"
        );
    }
    // The far-outside point samples exactly zero.
    let p = points().len();
    assert!(got[7 * C..8 * C].iter().all(|&v| v == 0.0));
    assert!(got[(p + 7) * C..(p + 8) * C].iter().all(|&v| v == 0.0));
}

#[test]
fn gradients_match_grid_sample_2d() {
    let device = Device::flex().autodiff();
    let weights = |device: &Device| {
        let w: Vec<f32> = (0..N * points().len() * C)
            .map(|i| ((i * 13) % 11) as f32 * 0.3 - 1.4)
            .collect();
        Tensor::<3>::from_data(TensorData::new(w, [N, points().len(), C]), device)
    };
    let gradients = |sampler: fn(Tensor<4>, Tensor<3>) -> Tensor<3>| {
        let m = maps(&device).require_grad();
        let g = grid(&device).require_grad();
        let loss = (sampler(m.clone(), g.clone()) * weights(&device)).sum();
        let grads = loss.backward();
        (
            values(m.grad(&grads).expect("map gradient")),
            values(g.grad(&grads).expect("grid gradient")),
        )
    };
    let (map_ref, grid_ref) = gradients(reference);
    let (map_ours, grid_ours) = gradients(ours);
    for (i, (e, g)) in map_ref.iter().zip(&map_ours).enumerate() {
        assert!((e - g).abs() < 1e-4, "map gradient {i}: {e} vs {g}");
    }
    assert!(map_ours.iter().any(|&v| v != 0.0));
    // A coordinate exactly on a pixel centre sits on a kink of the interpolant, where the
    // one-sided derivatives differ; compare the grid gradient only along axes strictly between
    // centres.
    let flat = values(grid(&Device::flex()));
    let mut compared = 0;
    for (i, (e, g)) in grid_ref.iter().zip(&grid_ours).enumerate() {
        let size = if i % 2 == 0 { W } else { H } as f32;
        let pixel = (flat[i] + 1.0) * size / 2.0 - 0.5;
        if (pixel - pixel.round()).abs() > 1e-4 {
            assert!((e - g).abs() < 1e-3, "grid gradient {i}: {e} vs {g}");
            compared += 1;
        }
    }
    assert!(
        compared >= flat.len() / 2,
        "only {compared} coordinates off the kinks"
    );
    assert!(grid_ours.iter().any(|&v| v != 0.0));
}

#[test]
fn the_host_kernel_of_inference_equals_the_tensor_ops_of_training() {
    // On flex outside autodiff the sampler is one host loop; under autodiff it is burn's ops.
    let host = values(ours(maps(&Device::flex()), grid(&Device::flex())));
    let device = Device::flex().autodiff();
    let tensor_ops = values(ours(maps(&device), grid(&device)));
    assert_eq!(host.len(), tensor_ops.len());
    for (i, (a, b)) in host.iter().zip(&tensor_ops).enumerate() {
        assert!(
            (a - b).abs() <= 1e-6,
            "element {i}: host {a}, tensor ops {b}"
        );
    }
}
