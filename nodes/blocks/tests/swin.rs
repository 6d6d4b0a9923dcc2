//! Swin parts against hand-computed layouts and the shifted-window mask's purpose: no attention
//! across the seams that the cyclic shift creates.

use bevworld_blocks::MASKED;
use bevworld_blocks::init::random_normal;
use bevworld_blocks::swin::patch::{depth_to_space, space_to_depth};
use bevworld_blocks::swin::window::{
    relative_position_index, shift_mask, window_partition, window_reverse,
};
use bevworld_blocks::swin::{SwinBlockConfig, SwinConfig};
use burn::prelude::*;

fn device() -> Device {
    Device::flex()
}

fn values<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data().try_to_vec::<f32>().expect("f32")
}

/// `[B, H, W, C]` filled with 0, 1, 2, ... in row-major order.
fn ramp(dims: [usize; 4]) -> Tensor<4> {
    let n: usize = dims.iter().product();
    Tensor::<1, Int>::arange(0..n as i64, &device())
        .float()
        .reshape(dims)
}

#[test]
fn windows_partition_and_reverse_exactly() {
    let x = ramp([2, 8, 12, 3]);
    let windows = window_partition(x.clone(), 4);
    assert_eq!(windows.dims(), [2 * 2 * 3, 16, 3]);
    // The second window of the first image starts at row 0, column 4: token (0, 4), channel 0.
    assert_eq!(values(windows.clone().narrow(0, 1, 1))[0], (4 * 3) as f32);
    assert_eq!(values(window_reverse(windows, 4, 8, 12)), values(x));
}

#[test]
fn relative_position_index_matches_hand_computation() {
    // Window 2: tokens (0,0), (0,1), (1,0), (1,1); offsets (dy + 1) * 3 + (dx + 1).
    let index = relative_position_index(2);
    assert_eq!(index.len(), 16);
    assert_eq!(index[0], 4); // same token
    assert_eq!(index[1], 3); // (0,0) vs (0,1): dx = -1
    assert_eq!(index[3], 0); // (0,0) vs (1,1): dy = dx = -1
    assert_eq!(index[3 * 4], 8); // (1,1) vs (0,0): dy = dx = +1
    assert!(index.iter().all(|&i| (0..9).contains(&i)));
}

#[test]
fn shift_mask_separates_the_regions_of_the_last_window() {
    // 8 x 8 map, window 4, shift 2: the first window has one region, the last has four.
    let mask = shift_mask(8, 8, 4, 2);
    assert_eq!(mask.len(), 4 * 16 * 16);
    assert!(mask[..256].iter().all(|&m| m == 0.0));
    let last = &mask[3 * 256..];
    let token = |y: usize, x: usize| y * 4 + x;
    assert_eq!(last[token(0, 0) * 16 + token(1, 1)], 0.0); // both in region (1, 1)
    assert_eq!(last[token(0, 0) * 16 + token(3, 3)], MASKED); // (1,1) vs (2,2)
    assert_eq!(last[token(2, 3) * 16 + token(3, 2)], 0.0); // both in region (2, 2)
    assert_eq!(last[token(0, 3) * 16 + token(3, 0)], MASKED); // (1,2) vs (2,1)
    // Each token sees itself.
    for w in 0..4 {
        for t in 0..16 {
            assert_eq!(mask[w * 256 + t * 16 + t], 0.0);
        }
    }
}

#[test]
fn shifted_block_never_attends_across_the_seam() {
    let block = SwinBlockConfig::new(8, 2, 4)
        .with_shifted(true)
        .init(&device());
    let base: Tensor<4> = random_normal(1, [1, 8, 8, 8], 0.0, 1.0, &device());
    // Perturb token (0, 0). After the roll by -2 it shares the last window with (7, 7), its
    // neighbour only through the wrap-around, and with (1, 1), its real neighbour.
    // Not constant over channels, which the block's layer norm would remove.
    let bump = Tensor::<4>::zeros([1, 8, 8, 8], &device()).slice_assign(
        [0..1, 0..1, 0..1, 0..8],
        Tensor::<1, Int>::arange(0..8, &device())
            .float()
            .mul_scalar(1.5)
            .reshape([1, 1, 1, 8]),
    );
    let out = values(block.forward(base.clone()));
    let bumped = values(block.forward(base + bump));
    let at = |v: &[f32], y: usize, x: usize| v[(y * 8 + x) * 8..(y * 8 + x + 1) * 8].to_vec();
    let change = |y, x| {
        at(&out, y, x)
            .iter()
            .zip(at(&bumped, y, x))
            .map(|(a, b)| (a - b).abs())
            .fold(0.0f32, f32::max)
    };
    assert!(change(7, 7) < 1e-5, "across the seam: {}", change(7, 7));
    assert!(
        change(7, 0) < 1e-5,
        "across the vertical seam: {}",
        change(7, 0)
    );
    assert!(
        change(1, 1) > 1e-3,
        "a real neighbour must see it: {}",
        change(1, 1)
    );
}

#[test]
fn merging_then_expanding_restores_the_layout() {
    let x = ramp([2, 6, 10, 3]);
    let merged = space_to_depth(x.clone());
    assert_eq!(merged.dims(), [2, 3, 5, 12]);
    // Swin's order inside a merged token: (y0,x0), (y1,x0), (y0,x1), (y1,x1).
    let first = values(
        merged
            .clone()
            .narrow(0, 0, 1)
            .narrow(1, 0, 1)
            .narrow(2, 0, 1),
    );
    let pixel = |y: usize, x: usize, c: usize| ((y * 10 + x) * 3 + c) as f32;
    let expected: Vec<f32> = [(0, 0), (1, 0), (0, 1), (1, 1)]
        .iter()
        .flat_map(|&(y, x)| (0..3).map(move |c| pixel(y, x, c)))
        .collect();
    assert_eq!(first, expected);
    assert_eq!(values(depth_to_space(merged)), values(x));
}

#[test]
fn blocks_keep_shape_on_maps_that_are_not_window_multiples() {
    for shifted in [false, true] {
        let block = SwinBlockConfig::new(8, 2, 4)
            .with_shifted(shifted)
            .init(&device());
        let x: Tensor<4> = random_normal(2, [1, 6, 10, 8], 0.0, 1.0, &device());
        let y = block.forward(x);
        assert_eq!(y.dims(), [1, 6, 10, 8]);
        assert!(values(y).iter().all(|v| v.is_finite()));
    }
}

#[test]
fn backbone_output_follows_its_stride_and_width() {
    let config = SwinConfig::new(3, 4, 16, vec![2, 2], vec![2, 4], 4);
    assert!(config.problems("image_backbone").is_empty());
    assert_eq!((config.out_channels(), config.stride()), (32, 8));
    let backbone = config.init(&device());
    let y = backbone.forward(Tensor::zeros([2, 3, 32, 64], &device()));
    assert_eq!(y.dims(), [2, 32, 4, 8]);

    let bad = SwinConfig::new(3, 4, 16, vec![2, 2], vec![3], 4);
    let problems = bad.problems("image_backbone");
    assert!(
        problems.iter().any(|p| p.field == "image_backbone.heads"),
        "{problems:?}"
    );
}

#[test]
fn backbone_levels_end_with_the_forward_output_and_keep_the_finer_stage() {
    let config = SwinConfig::new(3, 4, 16, vec![2, 2], vec![2, 4], 4);
    let backbone = config.init(&device());
    let x = random_normal(3, [2, 3, 32, 64], 0.0, 1.0, &device());
    let last = values(backbone.forward(x.clone()));

    let (coarse, none) = backbone.forward_levels(x.clone(), 0);
    assert!(none.is_empty());
    assert_eq!(values(coarse), last);

    let (coarse, fine) = backbone.forward_levels(x, 1);
    assert_eq!(values(coarse), last);
    assert_eq!(fine.len(), 1);
    // The first stage, before its merging: stride 4, the embedding width.
    assert_eq!(fine[0].dims(), [2, 16, 8, 16]);
}
