//! Bilinear sampling of feature maps at many points, with `grid_sample_2d`'s conventions
//! (coordinates in [-1, 1], `align_corners = false`, zero padding), as one row gather.
//!
//! Why not `grid_sample_2d` itself: under autodiff on flex it decomposes into generic
//! element-wise gathers, and its backward into a scatter over every element; those two were
//! a quarter of a tiny training step. Laying the maps out as `[N * h * w, C]` makes each corner
//! lookup a row `select`, whose backward is a row scatter, the same trick as
//! `render::sample_trilinear`.
//!
//! For CPU inference the whole gather-weight-sum is one host loop (`sample_on_host`): the
//! tensor version is some thirty small ops over `[N, P]` per call, a fifth of the encoder.

use bevworld_blocks::host::{inference_values, vectorized};
use burn::prelude::*;
use rayon::prelude::*;

/// Samples channels-last `maps` `[N, h, w, C]` at `grid` `[N, P, 2]`, (x, y) in [-1, 1] where
/// −1 and 1 are the outer edges of the first and last pixels. Returns `[N, P, C]`: map `n`'s
/// features at each of its `P` points; a corner outside the map counts as zero.
pub fn sample_bilinear(maps: Tensor<4>, grid: Tensor<3>) -> Tensor<3> {
    let [maps_n, height, width, channels] = maps.dims();
    let [_, points, _] = grid.dims();
    let device = maps.device();
    // Both are small (the maps at the feature size, two numbers per point): copied to the host.
    if let (Some(table), Some(grid)) = (inference_values(&maps), inference_values(&grid)) {
        let values = sample_on_host(&table, [maps_n, height, width, channels], &grid);
        return Tensor::from_data(TensorData::new(values, [maps_n, points, channels]), &device);
    }
    let cells = height * width;
    // [N * h * w, C]: one row per pixel.
    let table = maps.reshape([maps_n * cells, channels]);

    // Pixel coordinates: pixel i's centre is at i, the map spans [-0.5, size - 0.5].
    let axis = |i: usize, size: usize| {
        grid.clone()
            .narrow(2, i, 1)
            .reshape([maps_n, points])
            .add_scalar(1.0)
            .mul_scalar(size as f32 / 2.0)
            .sub_scalar(0.5)
    }; // [N, P]
    let (px, py) = (axis(0, width), axis(1, height));
    let (x0, y0) = (px.clone().floor(), py.clone().floor());
    // The fractions carry the gradient with respect to the points.
    let (fx, fy) = (px - x0.clone(), py - y0.clone());
    let map_offset = Tensor::<1, Int>::arange(0..maps_n as i64, &device)
        .mul_scalar(cells as i64)
        .reshape([maps_n, 1]); // [N, 1]

    let mut indices = Vec::with_capacity(4);
    let mut weights = Vec::with_capacity(4);
    for corner in 0..4 {
        let (dx, dy) = (corner & 1, (corner >> 1) & 1);
        let along = |f: &Tensor<2>, d: usize| {
            if d == 1 {
                f.clone()
            } else {
                f.clone().neg().add_scalar(1.0)
            }
        };
        let cx = x0.clone().add_scalar(dx as f32);
        let cy = y0.clone().add_scalar(dy as f32);
        let inside = |c: &Tensor<2>, size: usize| {
            c.clone()
                .greater_equal_elem(0.0)
                .bool_and(c.clone().lower_elem(size as f32))
        };
        let valid = inside(&cx, width).bool_and(inside(&cy, height)).float(); // [N, P]
        let weight = along(&fx, dx) * along(&fy, dy) * valid;
        let index = cy
            .clamp(0.0, (height - 1) as f32)
            .int()
            .mul_scalar(width as i64)
            + cx.clamp(0.0, (width - 1) as f32).int()
            + map_offset.clone(); // [N, P]
        indices.push(index.reshape([maps_n * points]));
        weights.push(weight.reshape([maps_n * points, 1]));
    }
    let rows = table
        .select(0, Tensor::cat(indices, 0)) // [4 * N * P, C]
        .reshape([4, maps_n * points, channels]);
    let weights = Tensor::stack::<3>(weights, 0); // [4, N * P, 1]
    (rows * weights)
        .sum_dim(0)
        .reshape([maps_n, points, channels])
}

/// Points per parallel task on the host.
const POINTS_PER_TASK: usize = 2048;

/// `sample_bilinear` over host values: `table` is the maps `[N, h, w, C]` row-major, `grid`
/// `[N, P, 2]`; returns `[N, P, C]`. The same arithmetic as the tensor ops, corner by corner
/// in the same order, each point's corners outside the map skipped (they weigh 0).
pub fn sample_on_host(
    table: &[f32],
    [maps_n, height, width, channels]: [usize; 4],
    grid: &[f32],
) -> Vec<f32> {
    let points = grid.len() / (2 * maps_n.max(1));
    let mut out = vec![0f32; maps_n * points * channels];
    if channels == 0 || points == 0 {
        return out;
    }
    let cells = height * width;
    out.par_chunks_mut(points * channels)
        .zip(grid.par_chunks(points * 2))
        .enumerate()
        .for_each(|(map, (out, grid))| {
            let table = &table[map * cells * channels..(map + 1) * cells * channels];
            out.par_chunks_mut(POINTS_PER_TASK * channels)
                .zip(grid.par_chunks(POINTS_PER_TASK * 2))
                .for_each(|(out, grid)| {
                    vectorized(BilinearKernel {
                        table,
                        size: [height, width, channels],
                        grid,
                        out,
                    })
                });
        });
    out
}

/// One chunk of points of `sample_on_host`, compiled for the CPU's vector width (the corner
/// sums run along the channels).
struct BilinearKernel<'a> {
    table: &'a [f32],
    size: [usize; 3],
    grid: &'a [f32],
    out: &'a mut [f32],
}

impl macerator::WithSimd for BilinearKernel<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: macerator::Simd>(self) {
        let [height, width, channels] = self.size;
        for (sample, point) in self
            .out
            .chunks_exact_mut(channels)
            .zip(self.grid.chunks_exact(2))
        {
            let px = (point[0] + 1.0) * (width as f32 / 2.0) - 0.5;
            let py = (point[1] + 1.0) * (height as f32 / 2.0) - 0.5;
            let (x0, y0) = (px.floor(), py.floor());
            let (fx, fy) = (px - x0, py - y0);
            for corner in 0..4 {
                let (dx, dy) = (corner & 1, (corner >> 1) & 1);
                let (cx, cy) = (x0 + dx as f32, y0 + dy as f32);
                if !(cx >= 0.0 && cx < width as f32 && cy >= 0.0 && cy < height as f32) {
                    continue;
                }
                let wx = if dx == 1 { fx } else { 1.0 - fx };
                let wy = if dy == 1 { fy } else { 1.0 - fy };
                let weight = wx * wy;
                let row = cy as usize * width + cx as usize;
                let values = &self.table[row * channels..(row + 1) * channels];
                for (acc, value) in sample.iter_mut().zip(values) {
                    *acc += value * weight;
                }
            }
        }
    }
}
