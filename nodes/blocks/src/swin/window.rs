//! Window bookkeeping for Swin attention: partitioning a token map into windows and back, the
//! relative position index, and the mask that keeps shifted windows from attending across the
//! seams the cyclic shift creates.

use burn::prelude::*;

use crate::attention::MASKED;

/// Splits a token map into non-overlapping windows.
// [B, H, W, C] -> [B * (H / w) * (W / w), w * w, C]
pub fn window_partition(x: Tensor<4>, window: usize) -> Tensor<3> {
    let [batch, height, width, channels] = x.dims();
    x.reshape([
        batch,
        height / window,
        window,
        width / window,
        window,
        channels,
    ])
    .permute([0, 1, 3, 2, 4, 5])
    .reshape([
        batch * (height / window) * (width / window),
        window * window,
        channels,
    ])
}

/// The inverse of `window_partition`.
// [B * (H / w) * (W / w), w * w, C] -> [B, H, W, C]
pub fn window_reverse(windows: Tensor<3>, window: usize, height: usize, width: usize) -> Tensor<4> {
    let [count, _, channels] = windows.dims();
    let batch = count / ((height / window) * (width / window));
    windows
        .reshape([
            batch,
            height / window,
            width / window,
            window,
            window,
            channels,
        ])
        .permute([0, 1, 3, 2, 4, 5])
        .reshape([batch, height, width, channels])
}

/// For each pair of tokens (i, j) in a window, the row of their relative offset in a
/// `(2w - 1)^2` bias table. Row-major `[w*w * w*w]`.
pub fn relative_position_index(window: usize) -> Vec<i64> {
    let tokens = window * window;
    let span = 2 * window as i64 - 1;
    let mut index = Vec::with_capacity(tokens * tokens);
    for i in 0..tokens {
        let (yi, xi) = ((i / window) as i64, (i % window) as i64);
        for j in 0..tokens {
            let (yj, xj) = ((j / window) as i64, (j % window) as i64);
            let (dy, dx) = (yi - yj + window as i64 - 1, xi - xj + window as i64 - 1);
            index.push(dy * span + dx);
        }
    }
    index
}

/// The attention mask of shifted windows over an `H x W` map cyclically shifted by `shift`:
/// tokens that were not neighbours before the roll belong to different regions and get
/// `MASKED`. Row-major `[windows, w*w, w*w]`, windows in `window_partition` order.
pub fn shift_mask(height: usize, width: usize, window: usize, shift: usize) -> Vec<f32> {
    // Each axis has three regions after the roll: [0, n - w), [n - w, n - shift), [n - shift, n).
    let region = |i: usize, n: usize| -> usize {
        if i < n - window {
            0
        } else if i < n - shift {
            1
        } else {
            2
        }
    };
    let (rows, columns) = (height / window, width / window);
    let tokens = window * window;
    let mut mask = Vec::with_capacity(rows * columns * tokens * tokens);
    for wy in 0..rows {
        for wx in 0..columns {
            let label = |t: usize| {
                let (y, x) = (wy * window + t / window, wx * window + t % window);
                region(y, height) * 3 + region(x, width)
            };
            for i in 0..tokens {
                for j in 0..tokens {
                    mask.push(if label(i) == label(j) { 0.0 } else { MASKED });
                }
            }
        }
    }
    mask
}
