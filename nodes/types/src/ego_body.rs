//! The ego vehicle's own body, as the roof LiDAR sees it.
//!
//! A roof LiDAR also hits the car it sits on: on the nuScenes keyframe a quarter of the
//! LIDAR_TOP sweep (8,526 of 34,688 returns) lies within 1 m of the sensor. Those returns are
//! not the scene. No BEV cell can render them, because every ray starts inside the cell that
//! holds them. The 4D-Occ evaluation (and Copilot4D, and BEVWorld after them) drops them before
//! computing Chamfer distances, so we drop them wherever a sweep is the scene's ground truth.

use crate::point_cloud::LidarPoint;

/// A box in the LiDAR's own frame that the ego vehicle fills, over any height.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EgoBody {
    pub x: [f32; 2],
    pub y: [f32; 2],
}

impl EgoBody {
    /// 4D-Occ's ego mask for nuScenes' LIDAR_TOP (x to the right, y forward):
    /// −0.8 ≤ x ≤ 0.8 m and −1.5 ≤ y ≤ 2.5 m. Our synthetic LiDAR returns nothing inside it,
    /// and KITTI's HDL-64 a handful of stray points per sweep (11 of 124,668).
    pub const FOUR_D_OCC: EgoBody = EgoBody {
        x: [-0.8, 0.8],
        y: [-1.5, 2.5],
    };

    /// Whether a return lies on the ego vehicle (bounds inclusive, as 4D-Occ's).
    pub fn contains(&self, point: &LidarPoint) -> bool {
        (self.x[0]..=self.x[1]).contains(&point.x) && (self.y[0]..=self.y[1]).contains(&point.y)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::point_cloud::PointCloud;

    fn at(x: f32, y: f32, z: f32) -> LidarPoint {
        LidarPoint {
            x,
            y,
            z,
            ..LidarPoint::default()
        }
    }

    #[test]
    fn the_box_is_inclusive_and_ignores_height() {
        let body = EgoBody::FOUR_D_OCC;
        for inside in [at(0.0, 0.0, 0.0), at(0.8, 2.5, 30.0), at(-0.8, -1.5, -9.0)] {
            assert!(body.contains(&inside), "{inside:?}");
        }
        for outside in [at(0.81, 0.0, 0.0), at(0.0, -1.51, 0.0), at(0.0, 2.51, 0.0)] {
            assert!(!body.contains(&outside), "{outside:?}");
        }
    }

    #[test]
    fn the_scene_is_what_lies_off_the_body_in_order() {
        let cloud = PointCloud {
            points: vec![at(5.0, 0.0, 0.0), at(0.1, 0.3, 0.0), at(0.0, -4.0, 1.0)],
            ..PointCloud::default()
        };
        assert_eq!(cloud.scene_indices(), vec![0, 2]);
        // ego_from_lidar is the identity here, so the ego points are the sensor's.
        assert_eq!(
            cloud.scene_ego_points(),
            vec![[5.0, 0.0, 0.0], [0.0, -4.0, 1.0]]
        );
    }
}
