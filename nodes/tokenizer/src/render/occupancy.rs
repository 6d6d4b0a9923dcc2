//! Which samples empty-space skipping keeps: the options, the coarse occupancy grid built from
//! a fine one (dilated by a voxel, pooled into cells), and what a march reads of it. Building
//! the fine occupancy from a voxel field is the skipping renderer's (`skipping.rs`).

use serde::{Deserialize, Serialize};

#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SkipOptions {
    /// A voxel with α at or below this is empty.
    #[serde(default = "default_threshold")]
    pub alpha_threshold: f32,
    /// Coarse occupancy cells are `cell³` voxels.
    #[serde(default = "default_cell")]
    pub cell: usize,
    /// Widen the occupied voxels by one before pooling them into cells: a trilinear sample
    /// reads the 8 voxels around it, so a sample beside an occupied voxel may be dense.
    /// `false` keeps a sample only when its nearest voxel's cell is occupied: fewer samples
    /// near surfaces, at an error `bench/results/sparse-field.md` measures.
    #[serde(default = "default_dilate")]
    pub dilate: bool,
    /// A ray stops once its transmittance is below this.
    #[serde(default = "default_stop")]
    pub stop_transmittance: f32,
    /// Kept samples per ray per pass through the model.
    #[serde(default = "default_segment")]
    pub segment: usize,
}

fn default_threshold() -> f32 {
    1e-3
}
fn default_cell() -> usize {
    2
}
fn default_dilate() -> bool {
    true
}
fn default_stop() -> f32 {
    1e-4
}
fn default_segment() -> usize {
    12
}

impl Default for SkipOptions {
    fn default() -> Self {
        Self {
            alpha_threshold: default_threshold(),
            cell: default_cell(),
            dilate: default_dilate(),
            stop_transmittance: default_stop(),
            segment: default_segment(),
        }
    }
}

impl SkipOptions {
    pub fn problems(&self) -> Vec<String> {
        let mut problems = Vec::new();
        if !self.alpha_threshold.is_finite() || self.alpha_threshold >= 1.0 {
            problems.push(format!(
                "alpha_threshold: {} (accepted: a finite number below 1)",
                self.alpha_threshold
            ));
        }
        if self.cell == 0 {
            problems.push("cell: 0 (accepted: an integer >= 1)".into());
        }
        if !(0.0..1.0).contains(&self.stop_transmittance) {
            problems.push(format!(
                "stop_transmittance: {} (accepted: [0, 1))",
                self.stop_transmittance
            ));
        }
        if self.segment == 0 {
            problems.push("segment: 0 (accepted: an integer >= 1)".into());
        }
        problems
    }
}

/// Coarse occupancy of a voxel field.
#[derive(Clone, Debug)]
pub struct OccupancyGrid {
    /// Whether each fine voxel `[Z, Y, X]` (row-major) lies in an occupied coarse cell: the
    /// coarse cells spread back over their voxels, so that a lookup is one index, with no
    /// division by the cell size on the renderer's hottest path.
    kept: Vec<bool>,
    /// Fine voxels `[Z, Y, X]`.
    voxels: [usize; 3],
    /// Whether a sample outside the grid (zero feature) is dense enough to keep.
    outside_occupied: bool,
    /// Fraction of voxels with α above the threshold, before dilation.
    pub occupied_fraction: f64,
}

impl OccupancyGrid {
    /// The grid of a fine occupancy `[Z, Y, X]` (row-major, before dilation), dilated by a
    /// voxel when `dilate`, in coarse cells of `cell³` voxels; `outside_occupied` says whether
    /// a sample outside the grid (zero feature) is dense enough to keep.
    pub fn from_fine(
        fine: &[bool],
        [z, y, x]: [usize; 3],
        cell: usize,
        dilate: bool,
        outside_occupied: bool,
    ) -> Self {
        let count = fine.iter().filter(|&&occupied| occupied).count();
        // Dilate by one voxel (a trilinear sample reads the 8 voxels around it), one axis at a
        // time, then pool into coarse cells: O(voxels), where marking the 27 neighbours' cells
        // of every occupied voxel was 27 writes per voxel.
        let dilated = if dilate {
            dilate_by_one(fine, [z, y, x])
        } else {
            fine.to_vec()
        };
        let cell = cell.max(1);
        let coarse = [z.div_ceil(cell), y.div_ceil(cell), x.div_ceil(cell)];
        let mut occupied = vec![false; coarse[0] * coarse[1] * coarse[2]];
        for iz in 0..z {
            for iy in 0..y {
                let fine_row = &dilated[(iz * y + iy) * x..(iz * y + iy + 1) * x];
                let coarse_row = ((iz / cell) * coarse[1] + iy / cell) * coarse[2];
                for (ix, &voxel) in fine_row.iter().enumerate() {
                    if voxel {
                        occupied[coarse_row + ix / cell] = true;
                    }
                }
            }
        }
        let mut kept = Vec::with_capacity(z * y * x);
        for iz in 0..z {
            for iy in 0..y {
                let coarse_row = ((iz / cell) * coarse[1] + iy / cell) * coarse[2];
                kept.extend((0..x).map(|ix| occupied[coarse_row + ix / cell]));
            }
        }
        Self {
            kept,
            voxels: [z, y, x],
            outside_occupied,
            occupied_fraction: count as f64 / (z * y * x).max(1) as f64,
        }
    }

    /// Whether a sample at `p` (voxel units, x y z) may have α above the threshold.
    /// The nearest voxel is `⌊v + ½⌋` along each axis (`round` is a libm call on x86-64, and
    /// only ties at exactly half a voxel differ).
    #[inline(always)]
    pub fn keeps(&self, p: [f32; 3]) -> bool {
        let [z, y, x] = self.voxels;
        let nearest = |v: f32, n: usize| -> Option<usize> {
            let r = (v + 0.5).floor();
            (r >= 0.0 && r < n as f32).then_some(r as usize)
        };
        match (nearest(p[0], x), nearest(p[1], y), nearest(p[2], z)) {
            (Some(ix), Some(iy), Some(iz)) => self.kept[(iz * y + iy) * x + ix],
            _ => self.outside_occupied,
        }
    }
}

/// `grid` (`[Z, Y, X]`, row-major) with every voxel next to an occupied one (the 26
/// neighbours) occupied too: a maximum filter of width 3, separable into one pass per axis.
fn dilate_by_one(grid: &[bool], [z, y, x]: [usize; 3]) -> Vec<bool> {
    let mut current = grid.to_vec();
    // Along each axis in turn: a voxel is set when it or a neighbour along that axis is.
    // Lines along the axis are `len` voxels `stride` apart; `outer` blocks of `inner` lines.
    for (stride, len) in [(1, x), (x, y), (x * y, z)] {
        let source = current.clone();
        let block = stride * len;
        for start in (0..source.len()).step_by(block.max(1)) {
            for offset in 0..stride {
                let line = start + offset;
                for position in 0..len {
                    let i = line + position * stride;
                    current[i] = source[i]
                        || (position > 0 && source[i - stride])
                        || (position + 1 < len && source[i + stride]);
                }
            }
        }
    }
    current
}

/// What a march skips: nothing (dense), or samples in empty cells and samples after the ray's
/// transmittance fell below `exp(stop_log_transmittance)`. The march evaluates a ray's kept
/// samples `BLOCK` at a time and checks after each block; the tensor path checks after each of
/// its `segment`-sample passes, so the two stop within a few samples of each other, and each
/// drops at most `stop_transmittance` of the ray's weight.
#[derive(Clone, Copy)]
pub struct Skipping<'a> {
    pub grid: &'a OccupancyGrid,
    pub stop_log_transmittance: f32,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_occupied_voxel_keeps_its_dilated_coarse_cell_only() {
        // A 6³ grid with voxel (0, 0, 0) occupied: dilation reaches voxel 1 along each axis,
        // inside the first 2³ cell, so exactly that cell's 8 voxels are kept.
        let mut fine = vec![false; 6 * 6 * 6];
        fine[0] = true;
        let grid = OccupancyGrid::from_fine(&fine, [6, 6, 6], 2, true, false);
        assert_eq!(grid.kept.iter().filter(|&&k| k).count(), 8);
        assert!((grid.occupied_fraction - 1.0 / 216.0).abs() < 1e-12);
        assert!(grid.keeps([0.0, 0.0, 0.0]) && grid.keeps([1.4, 1.4, 1.4]));
        // 1.5 rounds to voxel 2, in the next cell.
        assert!(!grid.keeps([1.5, 0.0, 0.0]) && !grid.keeps([3.0, 3.0, 3.0]));
        // Outside the grid: as the zero feature says.
        assert!(!grid.keeps([-1.0, 0.0, 0.0]));
        assert!(OccupancyGrid::from_fine(&fine, [6, 6, 6], 2, true, true).keeps([-1.0, 0.0, 0.0]));
        // A voxel at a cell's edge spreads into the neighbouring cell: voxel (1, 0, 0) dilates
        // to x = 2, so the cells at x 0–1 and 2–3 are kept (16 voxels).
        let mut edge = vec![false; 6 * 6 * 6];
        edge[1] = true;
        let grid = OccupancyGrid::from_fine(&edge, [6, 6, 6], 2, true, false);
        assert_eq!(grid.kept.iter().filter(|&&k| k).count(), 16);
        // Undilated, the edge voxel stays in its own cell (8 voxels); with one-voxel cells
        // it is the only one kept, and a sample half a voxel beyond it is not.
        let grid = OccupancyGrid::from_fine(&edge, [6, 6, 6], 2, false, false);
        assert_eq!(grid.kept.iter().filter(|&&k| k).count(), 8);
        let grid = OccupancyGrid::from_fine(&edge, [6, 6, 6], 1, false, false);
        assert_eq!(grid.kept.iter().filter(|&&k| k).count(), 1);
        assert!(grid.keeps([1.4, 0.0, 0.0]) && !grid.keeps([1.5, 0.0, 0.0]));
        assert!(!grid.keeps([0.0, 0.0, 0.0]));
    }
}
