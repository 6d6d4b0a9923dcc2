//! (Shifted) window attention for CPU inference as one host kernel, reading the map as it is.
//!
//! The tensor path pads the normalised map, rolls it, partitions it into windows, splits the
//! heads, scales `q`, multiplies, adds the relative-position bias and the shift mask, takes
//! the softmax, multiplies by `v`, merges the heads, reverses the windows, rolls back and crops:
//! a dozen passes over `[windows, heads, N, N]` or the map, most of them copies, and at the
//! tiny size they cost more than the arithmetic. Here each window reads its tokens straight
//! from the `[B, H, W, 3C]` map of `q, k, v` at the positions the pad and roll would have
//! brought there, computes every head's attention in registers-sized buffers, and writes each
//! token's output back where the reverse roll and crop would have put it.
//!
//! The arithmetic is the tensor path's, in its order: `q` scaled first, then `q·k`, then the
//! bias, then the mask; softmax as `activation::softmax_row`; the weighted sum of `v` over keys in
//! order. A padding token (zero after the norm) projects to the `qkv` layer's bias, which is
//! what it reads as a key and value. The mask is not stored: two tokens of a shifted window
//! attend to each other when their regions of the rolled map (three per axis) agree, which is
//! what `window::shift_mask` writes.

use rayon::prelude::*;

use crate::activation::softmax_row;
use crate::attention::MASKED;
use crate::host::vectorized;

/// Where a window attention runs: the map, the window and the shift.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct WindowGeometry {
    pub batch: usize,
    pub height: usize,
    pub width: usize,
    /// Channels C of the output; the input map has 3C (`q`, `k`, `v`, heads inside each).
    pub channels: usize,
    pub heads: usize,
    pub window: usize,
    pub shift: usize,
}

impl WindowGeometry {
    fn padded(&self) -> (usize, usize) {
        (
            self.height.div_ceil(self.window) * self.window,
            self.width.div_ceil(self.window) * self.window,
        )
    }

    /// The region (0, 1 or 2) of a rolled coordinate along an axis of `n` padded cells.
    fn region(&self, i: usize, n: usize) -> usize {
        if i < n - self.window {
            0
        } else if i < n - self.shift {
            1
        } else {
            2
        }
    }
}

/// Attention of every window: `qkv` is the `[B, H, W, 3C]` map after the `qkv` layer,
/// `qkv_bias` that layer's bias `[3C]` (what a padding token projects to), `bias` the
/// relative-position bias `[heads, N, N]`. Returns the `[B, H, W, C]` map of attention outputs
/// before the output projection.
pub fn window_attention_on_host(
    qkv: &[f32],
    qkv_bias: &[f32],
    bias: &[f32],
    geometry: WindowGeometry,
) -> Vec<f32> {
    let g = geometry;
    let (ph, pw) = g.padded();
    let (rows, columns) = (ph / g.window, pw / g.window);
    let tokens = g.window * g.window;
    let c = g.channels;
    let mut out = vec![0f32; g.batch * g.height * g.width * c];
    if tokens == 0 || c == 0 {
        return out;
    }
    // Each window's outputs, then one pass that writes them into the map.
    let windows: Vec<(usize, Vec<f32>)> = (0..g.batch * rows * columns)
        .into_par_iter()
        .map(|index| {
            let kernel = WindowKernel {
                qkv,
                qkv_bias,
                bias,
                geometry: g,
                index,
            };
            (index, vectorized(kernel))
        })
        .collect();
    for (index, values) in windows {
        let (b, wy, wx) = (
            index / (rows * columns),
            (index / columns) % rows,
            index % columns,
        );
        for t in 0..tokens {
            if let Some(source) = source_token(&g, b, wy, wx, t) {
                out[source * c..(source + 1) * c].copy_from_slice(&values[t * c..(t + 1) * c]);
            }
        }
    }
    out
}

/// The map token that window `(wy, wx)`'s token `t` is, after padding and the roll by
/// `-shift`; `None` for a padding token.
#[inline(always)]
fn source_token(g: &WindowGeometry, b: usize, wy: usize, wx: usize, t: usize) -> Option<usize> {
    let (ph, pw) = g.padded();
    let y = (wy * g.window + t / g.window + g.shift) % ph;
    let x = (wx * g.window + t % g.window + g.shift) % pw;
    (y < g.height && x < g.width).then(|| (b * g.height + y) * g.width + x)
}

struct WindowKernel<'a> {
    qkv: &'a [f32],
    qkv_bias: &'a [f32],
    bias: &'a [f32],
    geometry: WindowGeometry,
    index: usize,
}

impl macerator::WithSimd for WindowKernel<'_> {
    type Output = Vec<f32>;

    #[inline(always)]
    fn with_simd<S: macerator::Simd>(self) -> Vec<f32> {
        let g = self.geometry;
        let (ph, pw) = g.padded();
        let (rows, columns) = (ph / g.window, pw / g.window);
        let (b, wy, wx) = (
            self.index / (rows * columns),
            (self.index / columns) % rows,
            self.index % columns,
        );
        let n = g.window * g.window;
        let c = g.channels;
        let d = c / g.heads.max(1);
        let scale = (d as f64).powf(-0.5) as f32;
        // Each token's q, k, v rows (3C values) and its region label in the rolled map.
        let rows_of: Vec<&[f32]> = (0..n)
            .map(|t| match source_token(&g, b, wy, wx, t) {
                Some(source) => &self.qkv[source * 3 * c..(source + 1) * 3 * c],
                None => self.qkv_bias,
            })
            .collect();
        let label: Vec<f32> = (0..n)
            .map(|t| {
                let (y, x) = (wy * g.window + t / g.window, wx * g.window + t % g.window);
                (g.region(y, ph) * 3 + g.region(x, pw)) as f32
            })
            .collect();
        let mut out = vec![0f32; n * c];
        // [d, N] each: one channel per row, so that the loops over keys run along rows.
        let mut keys = vec![0f32; d * n];
        let mut values = vec![0f32; d * n];
        let mut logits = vec![0f32; n];
        for head in 0..g.heads {
            let offset = head * d;
            for (j, row) in rows_of.iter().enumerate() {
                for k in 0..d {
                    keys[k * n + j] = row[c + offset + k];
                    values[k * n + j] = row[2 * c + offset + k];
                }
            }
            let head_bias = &self.bias[head * n * n..(head + 1) * n * n];
            for i in 0..n {
                logits.iter_mut().for_each(|l| *l = 0.0);
                let query = &rows_of[i][offset..offset + d];
                for (k, &q) in query.iter().enumerate() {
                    let q = q * scale;
                    for (l, &key) in logits.iter_mut().zip(&keys[k * n..(k + 1) * n]) {
                        *l += q * key;
                    }
                }
                for (l, &bias) in logits.iter_mut().zip(&head_bias[i * n..(i + 1) * n]) {
                    *l += bias;
                }
                if g.shift > 0 {
                    let own = label[i];
                    for (l, &other) in logits.iter_mut().zip(&label) {
                        *l += if other == own { 0.0 } else { MASKED };
                    }
                }
                softmax_row(&mut logits);
                let target = &mut out[i * c + offset..i * c + offset + d];
                for (o, channel) in target.iter_mut().zip(values.chunks_exact(n)) {
                    *o = dot(&logits, channel);
                }
            }
        }
        out
    }
}

/// `Σ a_j b_j` over `LANES` independent partial sums, so that it vectorises.
#[inline(always)]
fn dot(a: &[f32], b: &[f32]) -> f32 {
    const LANES: usize = 16;
    let mut sums = [0f32; LANES];
    let (blocks_a, blocks_b) = (a.chunks_exact(LANES), b.chunks_exact(LANES));
    let tail: f32 = blocks_a
        .remainder()
        .iter()
        .zip(blocks_b.remainder())
        .map(|(x, y)| x * y)
        .sum();
    for (block_a, block_b) in blocks_a.zip(blocks_b) {
        for ((s, x), y) in sums.iter_mut().zip(block_a).zip(block_b) {
            *s += x * y;
        }
    }
    sums.iter().sum::<f32>() + tail
}
