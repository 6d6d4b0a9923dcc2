//! Trilinear sampling of a voxel field. Burn has no 3D grid sample: the 8 corners of every
//! point are rows of the field's table, read with one row gather (`select`) and summed with
//! their weights.
//!
//! Coordinates are in voxel units: the centre of voxel `(ix, iy, iz)` is at `(ix, iy, iz)`, so
//! sampling at a centre returns that voxel exactly. Corners outside the grid count as zero (zero
//! padding): a point more than one voxel outside the grid samples exactly 0.
//!
//! Sample points are data (fixed depths along fixed rays), not parameters, so the corners and
//! their weights are computed on the host and gradients flow to the voxels only. One gather
//! for all corners matters for the backward pass: the gradient of a gather is a zero table of
//! the field's size with the rows added in, and eight gathers would make eight such tables and
//! add them up (at the tiny size, 4 M values each, every step).

use bevworld_blocks::host::vectorized;
use burn::prelude::*;
use rayon::prelude::*;

use crate::render::field::{FieldShape, VoxelField};

/// Points per parallel task when computing corners: large enough that a task's cost dwarfs
/// rayon's hand-off, small enough that both cores get several.
const POINTS_PER_TASK: usize = 16 * 1024;

/// The 8 corner rows and weights of each point, corner-major: entry `k · N + n` is corner `k`
/// of point `n`. A corner outside the grid gets row 0 and weight 0.
///
/// Each corner's slice is written by its own tasks, over chunks of points, in parallel; a
/// point's values do not depend on how the work is split. Rows are sums of per-axis terms
/// (`FieldShape::row_terms`), so the loop has no integer division.
pub fn corners(shape: &FieldShape, points: &[[f32; 3]]) -> (Vec<i64>, Vec<f32>) {
    let n = points.len();
    let mut rows = vec![0i64; 8 * n];
    let mut weights = vec![0f32; 8 * n];
    if n == 0 {
        return (rows, weights);
    }
    let [depth, height, width] = shape.voxels();
    let sizes = [width as f32, height as f32, depth as f32];
    let terms = shape.row_terms();
    rows.par_chunks_mut(n)
        .zip(weights.par_chunks_mut(n))
        .enumerate()
        .for_each(|(corner, (rows, weights))| {
            let offset = [corner & 1, (corner >> 1) & 1, (corner >> 2) & 1];
            rows.par_chunks_mut(POINTS_PER_TASK)
                .zip(weights.par_chunks_mut(POINTS_PER_TASK))
                .zip(points.par_chunks(POINTS_PER_TASK))
                .for_each(|((rows, weights), points)| {
                    for ((row, weight), p) in rows.iter_mut().zip(weights.iter_mut()).zip(points) {
                        let mut w = 1.0f32;
                        let mut r = 0i64;
                        let mut inside = true;
                        for axis in 0..3 {
                            let base = floor(p[axis]);
                            let fraction = p[axis] - base;
                            let c = base + offset[axis] as f32;
                            inside &= c >= 0.0 && c < sizes[axis] && !p[axis].is_nan();
                            w *= if offset[axis] == 1 {
                                fraction
                            } else {
                                1.0 - fraction
                            };
                            if inside {
                                r += terms[axis][c as usize];
                            }
                        }
                        if inside && w != 0.0 {
                            *row = r;
                            *weight = w;
                        }
                    }
                });
        });
    (rows, weights)
}

/// `x.floor()` for `|x| < 2³¹`, by truncation and a correction: `f32::floor` is a libm call
/// on x86-64 without SSE4.1, which keeps the corner loop from vectorising. Beyond ±2³¹ the
/// conversion saturates, and such a point is outside the grid either way; NaN gives 0 and is
/// refused by the caller.
#[inline(always)]
fn floor(x: f32) -> f32 {
    let truncated = x as i32 as f32;
    if truncated > x {
        truncated - 1.0
    } else {
        truncated
    }
}

/// Samples `field` at `points`, (x, y, z) in voxel units. Returns `[N, C_v]`.
///
/// For CPU inference the gather, weighting and sum are one host loop (`sample_on_host`),
/// which never builds the `[8 · N, C_v]` gathered rows; under autodiff or on another device
/// they are burn ops, so that gradients flow to the table.
pub fn sample_trilinear(field: &VoxelField, points: &[[f32; 3]]) -> Tensor<2> {
    let n = points.len();
    let channels = field.shape.channels;
    let device = field.device();
    if n == 0 {
        return Tensor::zeros([0, channels], &device);
    }
    if let Some(table) = field.host_table() {
        let values = sample_on_host(&field.shape, table, points);
        return Tensor::from_data(TensorData::new(values, [n, channels]), &device);
    }
    let (rows, weights) = corners(&field.shape, points);
    let rows = Tensor::<1, Int>::from_data(TensorData::new(rows, [8 * n]), &device);
    let weights = Tensor::<3>::from_data(TensorData::new(weights, [8, n, 1]), &device);
    (field
        .table()
        .clone()
        .select(0, rows)
        .reshape([8, n, channels])
        * weights)
        .sum_dim(0)
        .reshape([n, channels])
}

/// Trilinear samples of a row-major `[rows, C_v]` table, point-major `[N, C_v]`: each point's
/// 8 corners, in the order and with the weights `corners` gives them, weighted and summed in
/// one pass, in parallel over chunks of points. Corners outside the grid are skipped (they
/// weigh 0).
pub fn sample_on_host(shape: &FieldShape, table: &[f32], points: &[[f32; 3]]) -> Vec<f32> {
    let channels = shape.channels;
    let mut out = vec![0f32; points.len() * channels];
    if channels == 0 {
        return out;
    }
    let [depth, height, width] = shape.voxels();
    let sizes = [width as f32, height as f32, depth as f32];
    let terms = shape.row_terms();
    out.par_chunks_mut(POINTS_PER_TASK * channels)
        .zip(points.par_chunks(POINTS_PER_TASK))
        .for_each(|(out, points)| {
            vectorized(TrilinearKernel {
                table,
                terms: &terms,
                sizes,
                channels,
                points,
                out,
            })
        });
    out
}

/// One chunk of points of `sample_on_host`, compiled for the CPU's vector width.
struct TrilinearKernel<'a> {
    table: &'a [f32],
    terms: &'a [Vec<i64>; 3],
    sizes: [f32; 3],
    channels: usize,
    points: &'a [[f32; 3]],
    out: &'a mut [f32],
}

impl macerator::WithSimd for TrilinearKernel<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: macerator::Simd>(self) {
        let (table, terms, sizes, channels) = (self.table, self.terms, self.sizes, self.channels);
        let (out, points) = (self.out, self.points);
        for (sample, p) in out.chunks_exact_mut(channels).zip(points) {
            sample_point(table, terms, sizes, channels, *p, sample);
        }
    }
}

/// Adds the trilinear sample of `table` at `p` (voxel units) to `sample` (`C_v` values): the
/// 8 corners in `corners`' order, those outside the grid skipped. `terms` are
/// `FieldShape::row_terms`, `sizes` the voxels along x, y, z. Inlined into every kernel that
/// samples, so that it is compiled for that kernel's vector width.
#[inline(always)]
pub(crate) fn sample_point(
    table: &[f32],
    terms: &[Vec<i64>; 3],
    sizes: [f32; 3],
    channels: usize,
    p: [f32; 3],
    sample: &mut [f32],
) {
    // Per axis: the two neighbours' row terms and weights, or none if outside.
    let mut axes = [[(0i64, 0f32); 2]; 3];
    let mut valid = [[false; 2]; 3];
    for axis in 0..3 {
        let base = floor(p[axis]);
        let fraction = p[axis] - base;
        for (side, weight) in [1.0 - fraction, fraction].into_iter().enumerate() {
            let c = base + side as f32;
            if c >= 0.0 && c < sizes[axis] && !p[axis].is_nan() {
                axes[axis][side] = (terms[axis][c as usize], weight);
                valid[axis][side] = true;
            }
        }
    }
    for corner in 0..8 {
        let [sx, sy, sz] = [corner & 1, (corner >> 1) & 1, (corner >> 2) & 1];
        if !(valid[0][sx] && valid[1][sy] && valid[2][sz]) {
            continue;
        }
        let weight = axes[0][sx].1 * axes[1][sy].1 * axes[2][sz].1;
        if weight == 0.0 {
            continue;
        }
        let row = (axes[0][sx].0 + axes[1][sy].0 + axes[2][sz].0) as usize;
        let values = &table[row * channels..(row + 1) * channels];
        for (acc, value) in sample.iter_mut().zip(values) {
            *acc += value * weight;
        }
    }
}
