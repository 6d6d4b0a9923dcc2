//! Bilinear sampling of feature maps at many points, with `grid_sample_2d`'s conventions
//! (coordinates in [-1, 1], `align_corners = false`, zero padding), as one row gather.
//!
//! Why not `grid_sample_2d` itself: under autodiff on flex it decomposes into generic
//! element-wise gathers, and its backward into a scatter over every element; those two were
//! a quarter of a tiny training step. Laying the maps out as `[N * h * w, C]` makes each corner
//! lookup a row `select`, whose backward is a row scatter, the same trick as
//! `render::sample_trilinear`.

use burn::prelude::*;

/// Samples channels-last `maps` `[N, h, w, C]` at `grid` `[N, P, 2]`, (x, y) in [-1, 1] where
/// −1 and 1 are the outer edges of the first and last pixels. Returns `[N, P, C]`: map `n`'s
/// features at each of its `P` points; a corner outside the map counts as zero.
pub fn sample_bilinear(maps: Tensor<4>, grid: Tensor<3>) -> Tensor<3> {
    let [maps_n, height, width, channels] = maps.dims();
    let [_, points, _] = grid.dims();
    let device = maps.device();
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
