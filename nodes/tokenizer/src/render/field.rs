//! The decoder's voxel field, kept as the lift's head writes it: a table of one row of `C_v`
//! features per voxel, which trilinear sampling reads by row.
//!
//! The head predicts, for each decoder cell, a block of `Z · r · r` voxels (`Z` heights, an
//! `r × r` patch of columns). Its output `[h_c, w_c, Z · r · r · C_v]` is this table as it is,
//! rows ordered by cell, then height, then the patch's row and column:
//!
//! `row(ix, iy, iz) = (((iy / r) · w_c + ix / r) · Z + iz) · r² + (iy mod r) · r + ix mod r`.
//!
//! Why not a `[C_v, Z, Y, X]` grid: sampling needs channels last, so the grid would be copied
//! into a table on every forward pass and every gradient copied back, and at the paper's size
//! the grid has 150 M values. `to_grid` gives the grid for inspection and tests.

use std::sync::{Arc, OnceLock};

use bevworld_blocks::host::inference_values;
use burn::prelude::*;

/// The layout of a voxel field.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FieldShape {
    /// Feature channels `C_v`.
    pub channels: usize,
    /// Height cells `Z`.
    pub height: usize,
    /// Decoder cells along y and x; each holds `split × split` voxel columns.
    pub cells_y: usize,
    pub cells_x: usize,
    pub split: usize,
}

impl FieldShape {
    /// Voxels along `[Z, Y, X]`.
    pub fn voxels(&self) -> [usize; 3] {
        [
            self.height,
            self.cells_y * self.split,
            self.cells_x * self.split,
        ]
    }

    /// Rows of the table: one per voxel.
    pub fn rows(&self) -> usize {
        let [z, y, x] = self.voxels();
        z * y * x
    }

    /// `row` as a sum of one term per axis, `row(ix, iy, iz) = x[ix] + y[iy] + z[iz]`:
    /// expanding the cell index gives
    /// `(iy / r) · w_c · Z · r² + (ix / r) · Z · r² + iz · r² + (iy mod r) · r + ix mod r`.
    /// Returned as `[x, y, z]`, indexed by voxel along that axis.
    pub fn row_terms(&self) -> [Vec<i64>; 3] {
        let r = self.split as i64;
        let z_block = self.height as i64 * r * r;
        let [depth, height, width] = self.voxels();
        let x = (0..width as i64)
            .map(|ix| (ix / r) * z_block + ix % r)
            .collect();
        let y = (0..height as i64)
            .map(|iy| (iy / r) * self.cells_x as i64 * z_block + (iy % r) * r)
            .collect();
        let z = (0..depth as i64).map(|iz| iz * r * r).collect();
        [x, y, z]
    }

    /// The table row of voxel `(ix, iy, iz)`.
    pub fn row(&self, ix: usize, iy: usize, iz: usize) -> usize {
        let r = self.split;
        let cell = (iy / r) * self.cells_x + ix / r;
        ((cell * self.height + iz) * r + iy % r) * r + ix % r
    }
}

/// A voxel field: `table` is `[rows, C_v]`, laid out as `shape` says. The table is fixed at
/// construction (read it with `table()`), so that its host copy, made once for CPU inference,
/// can never disagree with it.
#[derive(Clone)]
pub struct VoxelField {
    table: Tensor<2>,
    pub shape: FieldShape,
    /// The table's values on the host, read on first use by CPU inference and shared by the
    /// field's clones; `None` inside when the table is under autodiff or on another device.
    host: Arc<OnceLock<Option<Vec<f32>>>>,
}

impl std::fmt::Debug for VoxelField {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("VoxelField")
            .field("table", &self.table.dims())
            .field("shape", &self.shape)
            .finish_non_exhaustive()
    }
}

impl VoxelField {
    fn new(table: Tensor<2>, shape: FieldShape) -> Self {
        Self {
            table,
            shape,
            host: Arc::default(),
        }
    }

    /// The table, `[rows, C_v]`.
    pub fn table(&self) -> &Tensor<2> {
        &self.table
    }

    /// The table's values, row-major, when sampling may run on the host (CPU inference):
    /// copied from the device once per field.
    pub fn host_table(&self) -> Option<&[f32]> {
        self.host
            .get_or_init(|| inference_values(&self.table))
            .as_deref()
    }
    /// The field of the head's output `[1, h_c, w_c, Z · r · r · C_v]`, channels ordered
    /// (height, patch row, patch column, feature). No copy is made.
    pub fn from_head(head: Tensor<4>, channels: usize, height: usize, split: usize) -> Self {
        let [_, cells_y, cells_x, block] = head.dims();
        let shape = FieldShape {
            channels,
            height,
            cells_y,
            cells_x,
            split,
        };
        debug_assert_eq!(block, height * split * split * channels);
        Self::new(head.reshape([shape.rows(), channels]), shape)
    }

    /// A field of a `[1, C_v, Z, Y, X]` grid, one voxel column per cell (`split` 1): for
    /// scenes built by hand.
    pub fn from_grid(grid: Tensor<5>) -> Self {
        let [_, channels, height, y, x] = grid.dims();
        let shape = FieldShape {
            channels,
            height,
            cells_y: y,
            cells_x: x,
            split: 1,
        };
        Self::new(
            grid.reshape([channels, height, y, x])
                .permute([2, 3, 1, 0])
                .reshape([shape.rows(), channels]),
            shape,
        )
    }

    /// The field as a `[1, C_v, Z, Y, X]` grid.
    pub fn to_grid(&self) -> Tensor<5> {
        let s = self.shape;
        let [z, y, x] = s.voxels();
        self.table
            .clone()
            .reshape([s.cells_y, s.cells_x, s.height, s.split, s.split, s.channels])
            .permute([5, 2, 0, 3, 1, 4]) // [C_v, Z, h_c, r_y, w_c, r_x]
            .reshape([1, s.channels, z, y, x])
    }

    pub fn device(&self) -> Device {
        self.table.device()
    }

    /// The same field, detached from any autodiff graph.
    pub fn detach(&self) -> Self {
        Self::new(self.table.clone().detach(), self.shape)
    }
}
