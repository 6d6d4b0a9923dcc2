//! The sparse pillarizer. Work and memory follow the occupied pillars, not the grid: a
//! cell-to-pillar map is allocated once per node and only the cells a sweep touched are reset.
//!
//! Deterministic rules when a limit is hit:
//! - a pillar keeps its first `max_points_per_pillar` points in input order;
//! - with more than `max_pillars` pillars, those whose centres are nearest the ego origin are
//!   kept (ties by cell index), since near space matters most for driving.
//! Output pillars are in row-major cell order (by iy, then ix).

use bevworld_types::{PILLAR_FEATURES, PillarGrid, PillarStats, Pillars};

use crate::Limits;

const EMPTY: u32 = u32::MAX;

pub struct Pillarizer {
    grid: PillarGrid,
    limits: Limits,
    nx: usize,
    ny: usize,
    cell_to_pillar: Vec<u32>,
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
            cell_to_pillar: vec![EMPTY; nx * ny],
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

        // Pass 1: pillars in order of first appearance; count and sum the kept points.
        let mut pillar_cells: Vec<u32> = Vec::new();
        let mut counts: Vec<u32> = Vec::new();
        let mut sums: Vec<[f32; 3]> = Vec::new();
        let mut point_pillar: Vec<u32> = Vec::with_capacity(points.len());
        for p in points {
            if !(p[0].is_finite() && p[1].is_finite() && p[2].is_finite() && p[3].is_finite()) {
                stats.non_finite += 1;
                point_pillar.push(EMPTY);
                continue;
            }
            let Some(cell) = cell_of(&self.grid, self.nx, self.ny, inv, p) else {
                stats.outside_range += 1;
                point_pillar.push(EMPTY);
                continue;
            };
            let mut pillar = self.cell_to_pillar[cell];
            if pillar == EMPTY {
                pillar = counts.len() as u32;
                self.cell_to_pillar[cell] = pillar;
                pillar_cells.push(cell as u32);
                counts.push(0);
                sums.push([0.0; 3]);
            }
            let index = pillar as usize;
            if (counts[index] as usize) < max_points {
                counts[index] += 1;
                for axis in 0..3 {
                    sums[index][axis] += p[axis];
                }
                point_pillar.push(pillar);
            } else {
                stats.dropped_by_pillar_limit += 1;
                point_pillar.push(EMPTY);
            }
        }
        // Reset only what this sweep touched.
        for &cell in &pillar_cells {
            self.cell_to_pillar[cell as usize] = EMPTY;
        }

        // Choose the pillars to keep and their output order (row-major cells).
        let mut kept: Vec<u32> = (0..counts.len() as u32).collect();
        if kept.len() > self.limits.max_pillars {
            let distance = |pillar: u32| {
                let cell = pillar_cells[pillar as usize] as usize;
                let (cx, cy) = self.grid.cell_center(cell % self.nx, cell / self.nx);
                (cx * cx + cy * cy, cell)
            };
            kept.select_nth_unstable_by(self.limits.max_pillars, |a, b| {
                let (da, ca) = distance(*a);
                let (db, cb) = distance(*b);
                da.total_cmp(&db).then(ca.cmp(&cb))
            });
            for &dropped in &kept[self.limits.max_pillars..] {
                stats.dropped_pillars += 1;
                stats.points_in_dropped_pillars += counts[dropped as usize] as usize;
            }
            kept.truncate(self.limits.max_pillars);
        }
        kept.sort_unstable_by_key(|&pillar| pillar_cells[pillar as usize]);
        let mut slot_of = vec![EMPTY; counts.len()];
        for (slot, &pillar) in kept.iter().enumerate() {
            slot_of[pillar as usize] = slot as u32;
        }

        // Pass 2: group each kept pillar's points (a counting sort, input order kept), then
        // write features and padding in one sequential sweep: every float is written once.
        let pillar_count = kept.len();
        let mut starts = vec![0u32; pillar_count + 1];
        for (slot, &pillar) in kept.iter().enumerate() {
            starts[slot + 1] = starts[slot] + counts[pillar as usize];
        }
        let mut cursor = starts.clone();
        let mut order = vec![0u32; starts[pillar_count] as usize];
        for (index, &pillar) in point_pillar.iter().enumerate() {
            if pillar == EMPTY {
                continue;
            }
            let slot = slot_of[pillar as usize];
            if slot != EMPTY {
                order[cursor[slot as usize] as usize] = index as u32;
                cursor[slot as usize] += 1;
            }
        }
        let mut features = Vec::with_capacity(pillar_count * max_points * PILLAR_FEATURES);
        let mut point_counts = Vec::with_capacity(pillar_count);
        for (slot, &pillar) in kept.iter().enumerate() {
            let (sum, n) = (sums[pillar as usize], counts[pillar as usize]);
            let mean = [sum[0] / n as f32, sum[1] / n as f32, sum[2] / n as f32];
            let cell = pillar_cells[pillar as usize] as usize;
            let (cx, cy) = self.grid.cell_center(cell % self.nx, cell / self.nx);
            for &index in &order[starts[slot] as usize..starts[slot + 1] as usize] {
                let p = points[index as usize];
                features.extend_from_slice(&point_features(&p, &mean, (cx, cy)));
            }
            features.resize(
                features.len() + (max_points - n as usize) * PILLAR_FEATURES,
                0.0,
            );
            point_counts.push(n);
        }
        stats.points_kept = order.len();
        let mut coords = Vec::with_capacity(pillar_count * 2);
        for &pillar in &kept {
            let cell = pillar_cells[pillar as usize] as usize;
            coords.push((cell / self.nx) as u32);
            coords.push((cell % self.nx) as u32);
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
