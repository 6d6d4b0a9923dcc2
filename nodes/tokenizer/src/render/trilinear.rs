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

use burn::prelude::*;

use crate::render::field::{FieldShape, VoxelField};

/// The 8 corner rows and weights of each point, corner-major: entry `k · N + n` is corner `k`
/// of point `n`. A corner outside the grid gets row 0 and weight 0.
pub fn corners(shape: &FieldShape, points: &[[f32; 3]]) -> (Vec<i64>, Vec<f32>) {
    let n = points.len();
    let [depth, height, width] = shape.voxels();
    let mut rows = vec![0i64; 8 * n];
    let mut weights = vec![0f32; 8 * n];
    for (i, p) in points.iter().enumerate() {
        let base = [p[0].floor(), p[1].floor(), p[2].floor()];
        let fraction = [p[0] - base[0], p[1] - base[1], p[2] - base[2]];
        for corner in 0..8 {
            let d = [corner & 1, (corner >> 1) & 1, (corner >> 2) & 1];
            let mut weight = 1.0f32;
            let mut index = [0usize; 3];
            let mut inside = true;
            for axis in 0..3 {
                let c = base[axis] + d[axis] as f32;
                let size = [width, height, depth][axis] as f32;
                inside &= c >= 0.0 && c < size;
                weight *= if d[axis] == 1 {
                    fraction[axis]
                } else {
                    1.0 - fraction[axis]
                };
                index[axis] = c.max(0.0) as usize;
            }
            if inside && weight != 0.0 {
                rows[corner * n + i] = shape.row(index[0], index[1], index[2]) as i64;
                weights[corner * n + i] = weight;
            }
        }
    }
    (rows, weights)
}

/// Samples `field` at `points`, (x, y, z) in voxel units. Returns `[N, C_v]`.
pub fn sample_trilinear(field: &VoxelField, points: &[[f32; 3]]) -> Tensor<2> {
    let n = points.len();
    let channels = field.shape.channels;
    let device = field.device();
    if n == 0 {
        return Tensor::zeros([0, channels], &device);
    }
    let (rows, weights) = corners(&field.shape, points);
    let rows = Tensor::<1, Int>::from_data(TensorData::new(rows, [8 * n]), &device);
    let weights = Tensor::<3>::from_data(TensorData::new(weights, [8, n, 1]), &device);
    (field
        .table
        .clone()
        .select(0, rows)
        .reshape([8, n, channels])
        * weights)
        .sum_dim(0)
        .reshape([n, channels])
}
