//! Sparse LiDAR pillars in the PointPillars layout, ready to become a tensor without copying.

use serde::{Deserialize, Serialize};

use crate::bev::FrameMeta;

/// Why a pillar grid cannot be used.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum GridError {
    #[error("ranges and pillar_size must be finite")]
    NonFinite,
    #[error("pillar_size must be > 0, got {0}")]
    PillarSize(f32),
    #[error("{name} must be [min, max) with min < max, got {range:?}")]
    Range { name: &'static str, range: [f32; 2] },
    #[error("pillar_size {pillar_size} does not divide {name} {range:?} ({cells} cells)")]
    Indivisible {
        name: &'static str,
        range: [f32; 2],
        pillar_size: f32,
        cells: f32,
    },
    #[error("the grid has {nx} x {ny} cells (allowed: 1 to 4096 x 4096)")]
    Cells { nx: usize, ny: usize },
}

/// A BEV grid over the ego frame. Intervals are half-open: a point is inside when
/// `min <= coordinate < max` on every axis, and falls in cell `floor((x - x_min) / size)`, so a
/// point exactly on a border between cells belongs to the higher cell, and a point on the
/// grid's upper edge is outside.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PillarGrid {
    pub x_range: [f32; 2],
    pub y_range: [f32; 2],
    pub z_range: [f32; 2],
    /// Pillar edge length, m (square pillars).
    pub pillar_size: f32,
}

impl Default for PillarGrid {
    /// The paper's reconstruction range, x, y in [-80, 80) m and z in [-4.5, 4.5) m, in a
    /// 384 x 384 grid.
    fn default() -> Self {
        Self {
            x_range: [-80.0, 80.0],
            y_range: [-80.0, 80.0],
            z_range: [-4.5, 4.5],
            pillar_size: 160.0 / 384.0,
        }
    }
}

impl PillarGrid {
    /// Cells along x and y.
    pub fn size(&self) -> (usize, usize) {
        let nx = ((self.x_range[1] - self.x_range[0]) / self.pillar_size).round() as usize;
        let ny = ((self.y_range[1] - self.y_range[0]) / self.pillar_size).round() as usize;
        (nx, ny)
    }

    /// Checks the grid is usable: finite, ordered ranges that the pillar size divides.
    pub fn validate(&self) -> Result<(), GridError> {
        let finite = [self.x_range, self.y_range, self.z_range]
            .iter()
            .flatten()
            .all(|v| v.is_finite())
            && self.pillar_size.is_finite();
        if !finite {
            return Err(GridError::NonFinite);
        }
        if self.pillar_size <= 0.0 {
            return Err(GridError::PillarSize(self.pillar_size));
        }
        for (name, range) in [
            ("x_range", self.x_range),
            ("y_range", self.y_range),
            ("z_range", self.z_range),
        ] {
            if range[0] >= range[1] {
                return Err(GridError::Range { name, range });
            }
        }
        for (name, range) in [("x_range", self.x_range), ("y_range", self.y_range)] {
            let cells = (range[1] - range[0]) / self.pillar_size;
            if (cells - cells.round()).abs() > 1e-3 {
                return Err(GridError::Indivisible {
                    name,
                    range,
                    pillar_size: self.pillar_size,
                    cells,
                });
            }
        }
        let (nx, ny) = self.size();
        if nx == 0 || ny == 0 || nx * ny > 16_777_216 {
            return Err(GridError::Cells { nx, ny });
        }
        Ok(())
    }

    /// Centre of cell (ix, iy) in the ego frame.
    pub fn cell_center(&self, ix: usize, iy: usize) -> (f32, f32) {
        (
            self.x_range[0] + (ix as f32 + 0.5) * self.pillar_size,
            self.y_range[0] + (iy as f32 + 0.5) * self.pillar_size,
        )
    }
}

/// Features per point: x, y, z, intensity, offsets from the pillar's point mean (3) and from the
/// pillar centre (2).
pub const PILLAR_FEATURES: usize = 9;

/// The non-empty pillars of one sweep.
#[derive(Clone, Debug, Default)]
pub struct Pillars {
    /// The frame the sweep belongs to (empty outside a graph).
    pub meta: FrameMeta,
    pub grid: PillarGrid,
    pub max_points_per_pillar: usize,
    /// `[P, max_points_per_pillar, 9]`, zero-padded: points beyond a pillar's count are zeros.
    pub features: Vec<f32>,
    /// `[P]`: points kept in each pillar.
    pub point_counts: Vec<u32>,
    /// `[P, 2]`: (iy, ix) grid indices of each pillar.
    pub coords: Vec<u32>,
    pub stats: PillarStats,
}

impl Pillars {
    pub fn len(&self) -> usize {
        self.point_counts.len()
    }

    pub fn is_empty(&self) -> bool {
        self.point_counts.is_empty()
    }

    /// Feature `f` of point `k` in pillar `p`.
    pub fn feature(&self, p: usize, k: usize, f: usize) -> f32 {
        self.features[(p * self.max_points_per_pillar + k) * PILLAR_FEATURES + f]
    }
}

/// What happened to the sweep's points.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct PillarStats {
    pub points_in: usize,
    pub points_kept: usize,
    pub outside_range: usize,
    pub non_finite: usize,
    /// Points beyond `max_points_per_pillar` in their pillar.
    pub dropped_by_pillar_limit: usize,
    /// Pillars (and their points) beyond `max_pillars`.
    pub dropped_pillars: usize,
    pub points_in_dropped_pillars: usize,
}

impl PillarStats {
    /// Points with a known fate: kept, or dropped for one of the counted reasons. Equals
    /// `points_in` when nothing was lost without being counted.
    pub fn accounted(&self) -> usize {
        self.points_kept
            + self.outside_range
            + self.non_finite
            + self.dropped_by_pillar_limit
            + self.points_in_dropped_pillars
    }
}
