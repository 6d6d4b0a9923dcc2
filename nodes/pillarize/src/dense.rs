//! The straightforward dense-grid pillarizer: a bucket per grid cell, then a scan of every cell.
//! Same rules and same output as `Pillarizer`; kept as the reference it is tested against and
//! the baseline it is benchmarked beside.

use bevworld_types::{PILLAR_FEATURES, PillarGrid, PillarStats, Pillars};

use crate::Limits;
use crate::sparse::{cell_of, point_features};

pub fn pillarize_dense(grid: &PillarGrid, limits: Limits, points: &[[f32; 4]]) -> Pillars {
    let (nx, ny) = grid.size();
    let max_points = limits.max_points_per_pillar.max(1);
    let inv = 1.0 / grid.pillar_size;
    let mut stats = PillarStats {
        points_in: points.len(),
        ..Default::default()
    };
    let mut buckets: Vec<Vec<usize>> = vec![Vec::new(); nx * ny];
    for (index, p) in points.iter().enumerate() {
        if !p.iter().all(|v| v.is_finite()) {
            stats.non_finite += 1;
            continue;
        }
        match cell_of(grid, nx, ny, inv, p) {
            Some(cell) if buckets[cell].len() < max_points => buckets[cell].push(index),
            Some(_) => stats.dropped_by_pillar_limit += 1,
            None => stats.outside_range += 1,
        }
    }
    let mut cells: Vec<usize> = (0..nx * ny).filter(|&c| !buckets[c].is_empty()).collect();
    if cells.len() > limits.max_pillars {
        cells.sort_by(|&a, &b| {
            let distance = |c: usize| {
                let (x, y) = grid.cell_center(c % nx, c / nx);
                x * x + y * y
            };
            distance(a).total_cmp(&distance(b)).then(a.cmp(&b))
        });
        for &dropped in &cells[limits.max_pillars..] {
            stats.dropped_pillars += 1;
            stats.points_in_dropped_pillars += buckets[dropped].len();
        }
        cells.truncate(limits.max_pillars);
        cells.sort_unstable();
    }
    let mut features = vec![0.0f32; cells.len() * max_points * PILLAR_FEATURES];
    let mut point_counts = Vec::with_capacity(cells.len());
    let mut coords = Vec::with_capacity(cells.len() * 2);
    for (slot, &cell) in cells.iter().enumerate() {
        let bucket = &buckets[cell];
        let n = bucket.len() as f32;
        let mut mean = [0.0f32; 3];
        for &i in bucket {
            for axis in 0..3 {
                mean[axis] += points[i][axis];
            }
        }
        let mean = [mean[0] / n, mean[1] / n, mean[2] / n];
        let (cx, cy) = grid.cell_center(cell % nx, cell / nx);
        for (k, &i) in bucket.iter().enumerate() {
            let p = points[i];
            let at = (slot * max_points + k) * PILLAR_FEATURES;
            features[at..at + PILLAR_FEATURES].copy_from_slice(&point_features(
                &p,
                &mean,
                (cx, cy),
            ));
        }
        stats.points_kept += bucket.len();
        point_counts.push(bucket.len() as u32);
        coords.push((cell / nx) as u32);
        coords.push((cell % nx) as u32);
    }
    Pillars {
        meta: Default::default(),
        grid: *grid,
        max_points_per_pillar: max_points,
        features,
        point_counts,
        coords,
        stats,
    }
}
