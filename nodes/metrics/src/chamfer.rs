//! Chamfer distance exactly as 4D-Occ and Copilot4D evaluate LiDAR forecasting:
//!
//! `CD = 1/2 * (mean over predicted p of min_g |p - g|^2 + mean over ground truth g of min_p |g - p|^2)`
//!
//! with squared nearest-neighbour distances found exactly by a k-d tree. The region of interest
//! is applied to each cloud on its own, with inclusive bounds. When either cloud is empty after
//! the ROI the distance is 0, as 4D-Occ's `compute_chamfer_distance_inner` returns.

use kiddo::{ImmutableKdTree, SquaredEuclidean};
use serde::{Deserialize, Serialize};

/// A box-shaped region of interest, inclusive on both ends of every axis.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Roi {
    pub min: [f64; 3],
    pub max: [f64; 3],
}

impl Roi {
    /// 4D-Occ / Copilot4D: |x| <= 70, |y| <= 70, |z| <= 4.5 m.
    pub const FOUR_D_OCC: Roi = Roi {
        min: [-70.0, -70.0, -4.5],
        max: [70.0, 70.0, 4.5],
    };
    /// ViDAR: [-51.2, 51.2] x [-51.2, 51.2] x [-5, 3] m.
    pub const VIDAR: Roi = Roi {
        min: [-51.2, -51.2, -5.0],
        max: [51.2, 51.2, 3.0],
    };

    /// A preset by name: `4docc` or `vidar`.
    pub fn preset(name: &str) -> Option<Roi> {
        match name {
            "4docc" => Some(Self::FOUR_D_OCC),
            "vidar" => Some(Self::VIDAR),
            _ => None,
        }
    }

    pub fn contains(&self, p: &[f64; 3]) -> bool {
        (0..3).all(|k| self.min[k] <= p[k] && p[k] <= self.max[k])
    }

    pub fn filter(&self, points: &[[f64; 3]]) -> Vec<[f64; 3]> {
        points
            .iter()
            .filter(|p| self.contains(p))
            .copied()
            .collect()
    }
}

/// A Chamfer distance with the point counts it was computed on.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ChamferResult {
    /// Square metres.
    pub chamfer: f64,
    pub pred_points: usize,
    pub gt_points: usize,
}

/// Mean squared distance from each query point to its exact nearest neighbour in `tree`.
fn mean_nearest_squared(tree: &ImmutableKdTree<f64, 3>, queries: &[[f64; 3]]) -> f64 {
    let total: f64 = queries
        .iter()
        .map(|q| {
            tree.query(q)
                .nearest_one::<SquaredEuclidean<f64>>()
                .execute()
                .distance
        })
        .sum();
    total / queries.len() as f64
}

/// The Chamfer distance between two clouds, without an ROI. 0 when either is empty.
pub fn chamfer(pred: &[[f64; 3]], gt: &[[f64; 3]]) -> f64 {
    if pred.is_empty() || gt.is_empty() {
        return 0.0;
    }
    let (Ok(pred_tree), Ok(gt_tree)) = (
        ImmutableKdTree::new_from_slice(pred),
        ImmutableKdTree::new_from_slice(gt),
    ) else {
        return f64::NAN;
    };
    0.5 * (mean_nearest_squared(&gt_tree, pred) + mean_nearest_squared(&pred_tree, gt))
}

/// The Chamfer distance after applying the ROI to each cloud on its own.
pub fn chamfer_in_roi(pred: &[[f64; 3]], gt: &[[f64; 3]], roi: &Roi) -> ChamferResult {
    let (pred, gt) = (roi.filter(pred), roi.filter(gt));
    ChamferResult {
        chamfer: chamfer(&pred, &gt),
        pred_points: pred.len(),
        gt_points: gt.len(),
    }
}
