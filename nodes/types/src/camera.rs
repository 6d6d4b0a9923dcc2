//! Cameras: channels, pinhole intrinsics, and calibrated images.

use std::sync::Arc;

use glam::{DMat3, DVec2, DVec3};
use image::RgbImage;
use serde::{Deserialize, Serialize};

use crate::pose::Pose;

/// The six surround cameras of a nuScenes-like rig, in the order models see them.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub enum CameraChannel {
    #[serde(rename = "CAM_FRONT")]
    Front,
    #[serde(rename = "CAM_FRONT_RIGHT")]
    FrontRight,
    #[serde(rename = "CAM_BACK_RIGHT")]
    BackRight,
    #[serde(rename = "CAM_BACK")]
    Back,
    #[serde(rename = "CAM_BACK_LEFT")]
    BackLeft,
    #[serde(rename = "CAM_FRONT_LEFT")]
    FrontLeft,
}

impl CameraChannel {
    pub const ALL: [CameraChannel; 6] = [
        CameraChannel::Front,
        CameraChannel::FrontRight,
        CameraChannel::BackRight,
        CameraChannel::Back,
        CameraChannel::BackLeft,
        CameraChannel::FrontLeft,
    ];

    pub fn name(self) -> &'static str {
        match self {
            CameraChannel::Front => "CAM_FRONT",
            CameraChannel::FrontRight => "CAM_FRONT_RIGHT",
            CameraChannel::BackRight => "CAM_BACK_RIGHT",
            CameraChannel::Back => "CAM_BACK",
            CameraChannel::BackLeft => "CAM_BACK_LEFT",
            CameraChannel::FrontLeft => "CAM_FRONT_LEFT",
        }
    }

    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|channel| channel.name() == name)
    }

    pub fn index(self) -> usize {
        Self::ALL.iter().position(|c| *c == self).unwrap_or(0)
    }
}

/// Pinhole intrinsics in pixels, for an image of the stated size.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Intrinsics {
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    pub width: u32,
    pub height: u32,
}

impl Intrinsics {
    /// From a row-major 3x3 matrix as nuScenes writes `camera_intrinsic`.
    pub fn from_rows(rows: [[f64; 3]; 3], width: u32, height: u32) -> Self {
        Self {
            fx: rows[0][0],
            fy: rows[1][1],
            cx: rows[0][2],
            cy: rows[1][2],
            width,
            height,
        }
    }

    pub fn matrix(&self) -> DMat3 {
        DMat3::from_cols(
            DVec3::new(self.fx, 0.0, 0.0),
            DVec3::new(0.0, self.fy, 0.0),
            DVec3::new(self.cx, self.cy, 1.0),
        )
    }

    /// Projects a camera-frame point (z forward) to pixels; `None` behind the camera.
    pub fn project(&self, camera_point: DVec3) -> Option<DVec2> {
        if camera_point.z <= 0.0 {
            return None;
        }
        Some(DVec2::new(
            self.fx * camera_point.x / camera_point.z + self.cx,
            self.fy * camera_point.y / camera_point.z + self.cy,
        ))
    }

    /// The same camera for an image resized to `width` x `height`.
    pub fn scaled_to(&self, width: u32, height: u32) -> Self {
        let sx = f64::from(width) / f64::from(self.width);
        let sy = f64::from(height) / f64::from(self.height);
        Self {
            fx: self.fx * sx,
            fy: self.fy * sy,
            cx: self.cx * sx,
            cy: self.cy * sy,
            width,
            height,
        }
    }
}

/// One camera's image with everything needed to project into it.
#[derive(Clone, Debug)]
pub struct CameraImage {
    pub channel: CameraChannel,
    pub image: Arc<RgbImage>,
    pub intrinsics: Intrinsics,
    pub ego_from_camera: Pose,
    /// The camera's own capture time.
    pub timestamp_us: i64,
    /// The ego pose at the camera's timestamp.
    pub global_from_ego: Pose,
    /// The file it came from, relative to the dataset root.
    pub source_file: String,
}

/// A named image, for sinks that write images of any origin (inputs, renders, depth maps).
#[derive(Clone, Debug)]
pub struct NamedImage {
    pub name: String,
    pub image: Arc<RgbImage>,
}

/// A set of named images belonging to one time step.
#[derive(Clone, Debug, Default)]
pub struct ImageSet {
    pub images: Vec<NamedImage>,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn channel_names_round_trip() {
        for channel in CameraChannel::ALL {
            assert_eq!(CameraChannel::from_name(channel.name()), Some(channel));
        }
        assert_eq!(CameraChannel::from_name("CAM_TOP"), None);
    }

    #[test]
    fn projection_and_scaling() {
        let k = Intrinsics {
            fx: 1000.0,
            fy: 1000.0,
            cx: 800.0,
            cy: 450.0,
            width: 1600,
            height: 900,
        };
        assert_eq!(
            k.project(DVec3::new(1.0, -0.5, 10.0)),
            Some(DVec2::new(900.0, 400.0))
        );
        assert_eq!(k.project(DVec3::new(1.0, 0.0, -1.0)), None);
        let half = k.scaled_to(800, 450);
        assert_eq!(
            half.project(DVec3::new(1.0, -0.5, 10.0)),
            Some(DVec2::new(450.0, 200.0))
        );
    }
}
