//! Trilinear sampling of a voxel grid. Burn has no 3D grid sample, so each of the 8 corners is
//! a row gather (`select`) from the grid laid out as `[cells, channels]`, weighted and summed.
//!
//! Coordinates are in voxel units: the centre of voxel `(ix, iy, iz)` is at `(ix, iy, iz)`, so
//! sampling at a centre returns that voxel exactly. Corners outside the grid count as zero (zero
//! padding): a point more than one voxel outside the grid samples exactly 0. Gradients flow to
//! the voxels (through `select`) and to the points (through the corner weights).

use burn::prelude::*;

/// Samples `voxels` at `points`.
///
/// `voxels`: `[B, C, Z, Y, X]`; `points`: `[B, N, 3]` as (x, y, z) in voxel units.
/// Returns `[B, N, C]`.
pub fn sample_trilinear(voxels: Tensor<5>, points: Tensor<3>) -> Tensor<3> {
    let [batch, channels, depth, height, width] = voxels.dims();
    let [_, count, _] = points.dims();
    let device = voxels.device();
    let cells = depth * height * width;
    // [B * Z * Y * X, C]: one row per voxel, so a corner lookup is one row gather.
    let table = voxels
        .permute([0, 2, 3, 4, 1])
        .reshape([batch * cells, channels]);

    let axis = |i: usize| points.clone().narrow(2, i, 1).reshape([batch, count]); // [B, N]
    let (px, py, pz) = (axis(0), axis(1), axis(2));
    let (x0, y0, z0) = (px.clone().floor(), py.clone().floor(), pz.clone().floor());
    // Fractions carry the gradient with respect to the points.
    let (fx, fy, fz) = (px - x0.clone(), py - y0.clone(), pz - z0.clone());
    // First row of each batch item in `table`.
    let batch_offset = Tensor::<1, Int>::arange(0..batch as i64, &device)
        .mul_scalar(cells as i64)
        .reshape([batch, 1]); // [B, 1]

    let mut out: Option<Tensor<2>> = None; // [B * N, C]
    for corner in 0..8 {
        let (dx, dy, dz) = (corner & 1, (corner >> 1) & 1, (corner >> 2) & 1);
        let weight_along = |f: &Tensor<2>, d: usize| {
            if d == 1 {
                f.clone()
            } else {
                f.clone().neg().add_scalar(1.0)
            }
        };
        let cx = x0.clone().add_scalar(dx as f32);
        let cy = y0.clone().add_scalar(dy as f32);
        let cz = z0.clone().add_scalar(dz as f32);
        let inside = |c: &Tensor<2>, size: usize| {
            c.clone()
                .greater_equal_elem(0.0)
                .bool_and(c.clone().lower_elem(size as f32))
        };
        let valid = inside(&cx, width)
            .bool_and(inside(&cy, height))
            .bool_and(inside(&cz, depth))
            .float(); // [B, N]
        let weight = weight_along(&fx, dx) * weight_along(&fy, dy) * weight_along(&fz, dz) * valid;
        let index = cz
            .clamp(0.0, (depth - 1) as f32)
            .int()
            .mul_scalar((height * width) as i64)
            + cy.clamp(0.0, (height - 1) as f32)
                .int()
                .mul_scalar(width as i64)
            + cx.clamp(0.0, (width - 1) as f32).int()
            + batch_offset.clone(); // [B, N]
        let rows = table.clone().select(0, index.reshape([batch * count])); // [B * N, C]
        let term = rows * weight.reshape([batch * count, 1]);
        out = Some(match out {
            Some(sum) => sum + term,
            None => term,
        });
    }
    match out {
        Some(sum) => sum.reshape([batch, count, channels]),
        None => Tensor::zeros([batch, count, channels], &device),
    }
}
