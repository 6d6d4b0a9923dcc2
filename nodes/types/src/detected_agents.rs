//! A detector's output for one frame, as the graph passes it: each agent's box in the frame's
//! ego frame, its score and its predicted trajectories. `to_detection` gives the box in the
//! global frame, as the nuScenes submission format (`Detection`) wants it.

use glam::{DQuat, DVec3};

use crate::bev::FrameMeta;
use crate::detection::Detection;
use crate::pose::{Pose, yaw_of};

/// One predicted future of an agent.
#[derive(Clone, Debug, PartialEq)]
pub struct TrajectoryMode {
    /// The mode's probability among the agent's modes (they sum to 1).
    pub probability: f64,
    /// The agent's centre (x, y) at each future step, in the frame's ego frame.
    pub positions: Vec<[f64; 2]>,
}

/// One detected agent, in the frame's ego frame.
#[derive(Clone, Debug, PartialEq)]
pub struct DetectedAgent {
    /// One of the challenge's ten detection names.
    pub detection_name: String,
    /// In [0, 1].
    pub score: f64,
    pub centre: [f64; 3],
    /// Width, length, height, m.
    pub size: [f64; 3],
    /// Heading about +z, rad.
    pub yaw: f64,
    /// Planar velocity, m/s.
    pub velocity: [f64; 2],
    /// Its futures, most probable first.
    pub modes: Vec<TrajectoryMode>,
}

/// Speed below which an agent is said to stand (the attribute a detection carries).
pub const STANDING_SPEED_MPS: f64 = 0.5;

impl DetectedAgent {
    /// The attribute the devkit scores, from the class and the speed: moving or parked for
    /// vehicles, moving or standing for pedestrians, with a rider for cycles.
    pub fn attribute_name(&self) -> &'static str {
        let moving = self.velocity[0].hypot(self.velocity[1]) > STANDING_SPEED_MPS;
        match self.detection_name.as_str() {
            "car" | "truck" | "bus" | "trailer" | "construction_vehicle" => {
                if moving {
                    "vehicle.moving"
                } else {
                    "vehicle.parked"
                }
            }
            "pedestrian" => {
                if moving {
                    "pedestrian.moving"
                } else {
                    "pedestrian.standing"
                }
            }
            "bicycle" | "motorcycle" => "cycle.with_rider",
            _ => "",
        }
    }

    /// The box in the global frame, for `sample_token`.
    pub fn to_detection(&self, sample_token: &str, global_from_ego: &Pose) -> Detection {
        let translation = global_from_ego.transform_point3(DVec3::from_array(self.centre));
        let yaw = self.yaw + yaw_of(global_from_ego);
        let rotation = DQuat::from_rotation_z(yaw);
        let velocity =
            global_from_ego.transform_vector3(DVec3::new(self.velocity[0], self.velocity[1], 0.0));
        Detection {
            sample_token: sample_token.to_string(),
            translation: translation.to_array(),
            size: self.size,
            rotation: [rotation.w, rotation.x, rotation.y, rotation.z],
            velocity: [velocity.x, velocity.y],
            detection_name: self.detection_name.clone(),
            detection_score: self.score.clamp(0.0, 1.0),
            attribute_name: self.attribute_name().to_string(),
        }
    }
}

/// A detector's output for one frame.
#[derive(Clone, Debug)]
pub struct FrameDetections {
    pub meta: FrameMeta,
    pub agents: Vec<DetectedAgent>,
    /// Seconds between the trajectories' steps.
    pub interval_s: f64,
    /// The detector's name and the digest of its weights.
    pub model: String,
    pub weights_hash: String,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_detection_is_moved_into_the_global_frame() {
        // The ego at (100, 50, 2), turned 90° left: its +x is global +y.
        let global_from_ego = Pose::from_rotation_translation(
            DQuat::from_rotation_z(std::f64::consts::FRAC_PI_2),
            DVec3::new(100.0, 50.0, 2.0),
        );
        let agent = DetectedAgent {
            detection_name: "car".into(),
            score: 0.7,
            centre: [10.0, 0.0, 1.0],
            size: [1.9, 4.5, 1.6],
            yaw: 0.0,
            velocity: [3.0, 0.0],
            modes: Vec::new(),
        };
        let detection = agent.to_detection("s", &global_from_ego);
        let [x, y, z] = detection.translation;
        assert!((x - 100.0).abs() < 1e-9 && (y - 60.0).abs() < 1e-9 && (z - 3.0).abs() < 1e-9);
        assert!((detection.yaw() - std::f64::consts::FRAC_PI_2).abs() < 1e-9);
        assert!(detection.velocity[0].abs() < 1e-9 && (detection.velocity[1] - 3.0).abs() < 1e-9);
        assert_eq!(detection.attribute_name, "vehicle.moving");
        assert_eq!(detection.problem(), None, "a box the devkit accepts");
        let standing = DetectedAgent {
            detection_name: "pedestrian".into(),
            velocity: [0.1, 0.0],
            ..agent
        };
        assert_eq!(standing.attribute_name(), "pedestrian.standing");
    }
}
