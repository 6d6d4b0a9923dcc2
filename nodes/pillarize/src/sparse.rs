//! The sparse pillarizer. Work and memory follow the points, not the grid: each point inside
//! the grid becomes a `cell << 32 | index` key, and a stable radix sort with 8-bit digits groups
//! the keys by cell. Its histograms fit in L1, where a per-cell map of the 384 x 384 grid would
//! not fit in L2. Each pillar is then one contiguous run of keys, and features and padding are
//! written once, in order.
//!
//! Deterministic rules when a limit is hit:
//! - a pillar keeps its first `max_points_per_pillar` points in input order;
//! - with more than `max_pillars` pillars, those whose centres are nearest the ego origin are
//!   kept (ties by cell index), since near space matters most for driving.
//!
//! Output pillars are in row-major cell order (by iy, then ix).

use bevworld_types::{PILLAR_FEATURES, PillarGrid, PillarStats, Pillars};

use crate::Limits;

pub struct Pillarizer {
    grid: PillarGrid,
    limits: Limits,
    nx: usize,
    ny: usize,
    /// Sort buffers, kept between sweeps.
    keys: Vec<u64>,
    scratch: Vec<u64>,
}

/// The 9 PointPillars features of a point: x, y, z, intensity, its offsets from the pillar's
/// point mean, and its offsets from the pillar centre.
#[inline]
pub(crate) fn point_features(
    p: &[f32; 4],
    mean: &[f32; 3],
    center: (f32, f32),
) -> [f32; PILLAR_FEATURES] {
    [
        p[0],
        p[1],
        p[2],
        p[3],
        p[0] - mean[0],
        p[1] - mean[1],
        p[2] - mean[2],
        p[0] - center.0,
        p[1] - center.1,
    ]
}

/// Cell of a point under the half-open rule, or None when outside.
#[inline]
pub(crate) fn cell_of(
    grid: &PillarGrid,
    nx: usize,
    ny: usize,
    inv: f32,
    p: &[f32; 4],
) -> Option<usize> {
    let [x, y, z, _] = *p;
    if !(x >= grid.x_range[0]
        && x < grid.x_range[1]
        && y >= grid.y_range[0]
        && y < grid.y_range[1]
        && z >= grid.z_range[0]
        && z < grid.z_range[1])
    {
        return None;
    }
    // `x < x_max` holds, but (x - x_min) * inv can still round up to nx: clamp into the grid.
    let ix = (((x - grid.x_range[0]) * inv) as usize).min(nx - 1);
    let iy = (((y - grid.y_range[0]) * inv) as usize).min(ny - 1);
    Some(iy * nx + ix)
}

impl Pillarizer {
    /// `grid` must pass `PillarGrid::validate`.
    pub fn new(grid: PillarGrid, limits: Limits) -> Self {
        let (nx, ny) = grid.size();
        Self {
            grid,
            limits,
            nx,
            ny,
            keys: Vec::new(),
            scratch: Vec::new(),
        }
    }

    pub fn grid(&self) -> &PillarGrid {
        &self.grid
    }

    /// Pillarizes points `[x, y, z, intensity]` given in the ego frame.
    pub fn run(&mut self, points: &[[f32; 4]]) -> Pillars {
        let max_points = self.limits.max_points_per_pillar.max(1);
        let inv = 1.0 / self.grid.pillar_size;
        let mut stats = PillarStats {
            points_in: points.len(),
            ..Default::default()
        };

        // Keys `cell << 32 | point index` for the points inside the grid.
        self.keys.clear();
        for (index, p) in points.iter().enumerate() {
            if !(p[0].is_finite() && p[1].is_finite() && p[2].is_finite() && p[3].is_finite()) {
                stats.non_finite += 1;
                continue;
            }
            match cell_of(&self.grid, self.nx, self.ny, inv, p) {
                Some(cell) => self.keys.push(((cell as u64) << 32) | index as u64),
                None => stats.outside_range += 1,
            }
        }
        // Stable LSD radix sort on the cell, 8 bits a pass: the histograms stay in L1 and the
        // work follows the points, not the grid. Pillars come out contiguous, in row-major
        // order, each with its points in input order.
        let cell_bits = usize::BITS - (self.nx * self.ny).leading_zeros();
        let mut shift = 32;
        while shift < 32 + cell_bits {
            let mut histogram = [0usize; 257];
            for key in &self.keys {
                histogram[((key >> shift) & 0xFF) as usize + 1] += 1;
            }
            for digit in 0..256 {
                histogram[digit + 1] += histogram[digit];
            }
            self.scratch.resize(self.keys.len(), 0);
            for &key in &self.keys {
                let digit = ((key >> shift) & 0xFF) as usize;
                self.scratch[histogram[digit]] = key;
                histogram[digit] += 1;
            }
            std::mem::swap(&mut self.keys, &mut self.scratch);
            shift += 8;
        }

        // Groups of equal cells: (cell, first key, points kept).
        let mut groups: Vec<(u32, u32, u32)> = Vec::new();
        let mut start = 0usize;
        while start < self.keys.len() {
            let cell = (self.keys[start] >> 32) as u32;
            let mut end = start + 1;
            while end < self.keys.len() && (self.keys[end] >> 32) as u32 == cell {
                end += 1;
            }
            let kept = (end - start).min(max_points);
            stats.dropped_by_pillar_limit += end - start - kept;
            groups.push((cell, start as u32, kept as u32));
            start = end;
        }

        // Beyond max_pillars, keep those nearest the ego origin (ties by cell index).
        if groups.len() > self.limits.max_pillars {
            let nx = self.nx;
            let grid = self.grid;
            let distance = |cell: u32| {
                let (cx, cy) = grid.cell_center(cell as usize % nx, cell as usize / nx);
                cx * cx + cy * cy
            };
            groups.select_nth_unstable_by(self.limits.max_pillars, |a, b| {
                distance(a.0).total_cmp(&distance(b.0)).then(a.0.cmp(&b.0))
            });
            for dropped in &groups[self.limits.max_pillars..] {
                stats.dropped_pillars += 1;
                stats.points_in_dropped_pillars += dropped.2 as usize;
            }
            groups.truncate(self.limits.max_pillars);
            groups.sort_unstable_by_key(|g| g.0);
        }

        // Features and padding, written once, in order.
        let pillar_count = groups.len();
        let mut features = Vec::with_capacity(pillar_count * max_points * PILLAR_FEATURES);
        let mut point_counts = Vec::with_capacity(pillar_count);
        let mut coords = Vec::with_capacity(pillar_count * 2);
        for &(cell, first, kept) in &groups {
            let members = &self.keys[first as usize..(first + kept) as usize];
            let mut sum = [0.0f32; 3];
            for key in members {
                let p = &points[(key & 0xFFFF_FFFF) as usize];
                sum[0] += p[0];
                sum[1] += p[1];
                sum[2] += p[2];
            }
            let n = kept as f32;
            let mean = [sum[0] / n, sum[1] / n, sum[2] / n];
            let (ix, iy) = (cell as usize % self.nx, cell as usize / self.nx);
            let center = self.grid.cell_center(ix, iy);
            for key in members {
                features.extend_from_slice(&point_features(
                    &points[(key & 0xFFFF_FFFF) as usize],
                    &mean,
                    center,
                ));
            }
            features.resize(
                features.len() + (max_points - kept as usize) * PILLAR_FEATURES,
                0.0,
            );
            point_counts.push(kept);
            coords.push(iy as u32);
            coords.push(ix as u32);
            stats.points_kept += kept as usize;
        }
        Pillars {
            meta: Default::default(),
            grid: self.grid,
            max_points_per_pillar: max_points,
            features,
            point_counts,
            coords,
            stats,
        }
    }
}
