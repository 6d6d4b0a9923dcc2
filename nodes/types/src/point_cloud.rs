//! LiDAR sweeps.

use serde::{Deserialize, Serialize};

use crate::ego_body::EgoBody;
use crate::pose::Pose;

/// One return, in the sensor frame.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[repr(C)]
pub struct LidarPoint {
    pub x: f32,
    pub y: f32,
    pub z: f32,
    pub intensity: f32,
    /// Laser (beam) index; 0 where the format has none.
    pub ring: u16,
}

/// A sweep with its calibration and timing.
#[derive(Clone, Debug, Default)]
pub struct PointCloud {
    /// Points in the LiDAR frame.
    pub points: Vec<LidarPoint>,
    pub ego_from_lidar: Pose,
    pub timestamp_us: i64,
    /// The ego pose at the LiDAR's timestamp.
    pub global_from_ego: Pose,
    /// Points dropped on reading because a coordinate was NaN or infinite.
    pub dropped_non_finite: usize,
    /// The file it came from, relative to the dataset root.
    pub source_file: String,
}

impl PointCloud {
    pub fn len(&self) -> usize {
        self.points.len()
    }

    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// Indices of the returns off the ego vehicle's body (`EgoBody::FOUR_D_OCC`): the scene.
    pub fn scene_indices(&self) -> Vec<usize> {
        (0..self.points.len())
            .filter(|&i| !EgoBody::FOUR_D_OCC.contains(&self.points[i]))
            .collect()
    }

    /// The scene's points (`scene_indices`) in the ego frame: the ground truth that Chamfer
    /// distances compare against.
    pub fn scene_ego_points(&self) -> Vec<[f32; 3]> {
        self.ego_points_of(self.scene_indices().into_iter().map(|i| &self.points[i]))
    }

    /// Points moved into the ego frame, as f32 [x, y, z].
    pub fn ego_points(&self) -> Vec<[f32; 3]> {
        self.ego_points_of(self.points.iter())
    }

    /// The scene's returns (`scene_indices`) moved into the ego frame, each with its
    /// intensity and ring: the logged sweep as a file of it should hold it.
    pub fn scene_ego_returns(&self) -> Vec<LidarPoint> {
        self.ego_returns_of(self.scene_indices().into_iter().map(|i| &self.points[i]))
    }

    /// Every return moved into the ego frame, with its intensity and ring.
    pub fn ego_returns(&self) -> Vec<LidarPoint> {
        self.ego_returns_of(self.points.iter())
    }

    fn ego_returns_of<'a>(&self, points: impl Iterator<Item = &'a LidarPoint>) -> Vec<LidarPoint> {
        let ego_from_lidar = self.ego_from_lidar;
        points
            .map(|p| {
                let q = ego_from_lidar.transform_point3(glam::DVec3::new(
                    f64::from(p.x),
                    f64::from(p.y),
                    f64::from(p.z),
                ));
                LidarPoint {
                    x: q.x as f32,
                    y: q.y as f32,
                    z: q.z as f32,
                    ..*p
                }
            })
            .collect()
    }

    fn ego_points_of<'a>(&self, points: impl Iterator<Item = &'a LidarPoint>) -> Vec<[f32; 3]> {
        self.ego_returns_of(points)
            .into_iter()
            .map(|p| [p.x, p.y, p.z])
            .collect()
    }
}
