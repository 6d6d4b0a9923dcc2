//! A synchronised set of sensor data: what sources emit and models eat.

use std::sync::Arc;

use crate::action::EgoAction;
use crate::camera::{CameraChannel, CameraImage, ImageSet, NamedImage};
use crate::object_box::ObjectBox;
use crate::point_cloud::PointCloud;
use crate::pose::Pose;

#[derive(Clone, Debug)]
pub struct SensorFrame {
    /// The frame's time of validity (the LiDAR's, for keyframes).
    pub time_of_validity_us: i64,
    /// The dataset's identifier of the sample (nuScenes sample token, KITTI frame index).
    /// Sweeps between keyframes share their keyframe's sample token.
    pub sample_token: String,
    /// Unique per frame: the LiDAR sample_data token (nuScenes), `sequence/index` (KITTI).
    pub frame_token: String,
    pub scene_name: String,
    /// Position of the frame within its scene, from 0.
    pub index_in_scene: usize,
    /// The sample's own sweep (nuScenes `is_key_frame`), which its annotations and a
    /// detection submission describe; false for the sweeps between keyframes that share its
    /// sample token. Every frame of a dataset without keyframes (KITTI) is its own sample.
    pub keyframe: bool,
    /// The ego pose at the time of validity.
    pub global_from_ego: Pose,
    /// Cameras in `CameraChannel::ALL` order; empty for LiDAR-only datasets.
    pub cameras: Vec<CameraImage>,
    pub lidar: Arc<PointCloud>,
    /// The ego's motion from this frame to the next one in its scene, if there is one.
    pub action: Option<EgoAction>,
    /// The objects the dataset annotates at this frame, in the global frame: the keyframes of
    /// an annotated dataset (nuScenes, the synthetic world); empty otherwise.
    pub boxes: Vec<ObjectBox>,
}

impl SensorFrame {
    pub fn camera(&self, channel: CameraChannel) -> Option<&CameraImage> {
        self.cameras.iter().find(|camera| camera.channel == channel)
    }

    /// The cameras as named images, sharing the pixels.
    pub fn image_set(&self) -> ImageSet {
        ImageSet {
            images: self
                .cameras
                .iter()
                .map(|camera| NamedImage {
                    name: camera.channel.name().to_string(),
                    image: Arc::clone(&camera.image),
                })
                .collect(),
        }
    }
}
