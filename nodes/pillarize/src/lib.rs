//! PointPillars pillarization: points in the ego frame to the non-empty pillars of a BEV grid.

// Libraries return errors; a panic belongs to a broken invariant, said with `expect`.
#![cfg_attr(not(test), warn(clippy::unwrap_used))]

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

/// A sweep's points moved into the ego frame, with their intensity: what `Pillarizer::run`
/// takes. f32 is enough for metres near the ego. `out` is cleared and reused.
pub fn ego_points_into(cloud: &bevworld_types::PointCloud, out: &mut Vec<[f32; 4]>) {
    let ego_from_lidar = glam::Affine3A::from_mat3_translation(
        cloud.ego_from_lidar.matrix3.as_mat3(),
        cloud.ego_from_lidar.translation.as_vec3(),
    );
    out.clear();
    out.extend(cloud.points.iter().map(|p| {
        let q = ego_from_lidar.transform_point3(glam::Vec3::new(p.x, p.y, p.z));
        [q.x, q.y, q.z, p.intensity]
    }));
}
