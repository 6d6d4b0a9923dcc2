//! PointPillars pillarization: points in the ego frame to the non-empty pillars of a BEV grid.

pub mod bev_stats;
pub mod dense;
pub mod node;
pub mod sparse;

/// Registers this family's node kinds.
pub fn register(registry: &mut bevworld_graph::Registry) {
    node::register(registry);
    bev_stats::register(registry);
}
pub use sparse::Pillarizer;

/// Limits on what one sweep may produce. The defaults are mmdetection3d's for nuScenes
/// PointPillars (20 points per pillar) with room for the paper's 384 x 384 grid.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Limits {
    pub max_points_per_pillar: usize,
    pub max_pillars: usize,
}

impl Default for Limits {
    fn default() -> Self {
        Self {
            max_points_per_pillar: 20,
            max_pillars: 40_000,
        }
    }
}
