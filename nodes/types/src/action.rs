//! Ego actions, derived from ego poses so that real and synthetic data share one definition.

use serde::{Deserialize, Serialize};

use crate::pose::{Pose, yaw_of};

/// The ego's motion from one frame to the next, in the first frame's ego coordinates.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct EgoAction {
    /// Forward speed along the ego x axis, m/s.
    pub speed_mps: f64,
    /// Yaw rate, rad/s (counter-clockwise positive).
    pub yaw_rate_rps: f64,
    /// Planar displacement in the first frame's ego coordinates, m.
    pub dx: f64,
    pub dy: f64,
    /// Heading change, rad, wrapped to (-pi, pi].
    pub dyaw: f64,
    /// Time between the frames, s.
    pub dt_s: f64,
}

impl EgoAction {
    /// The action that takes the ego from `global_from_ego_a` (at `t_a`) to `global_from_ego_b`.
    pub fn between(
        global_from_ego_a: &Pose,
        t_a_us: i64,
        global_from_ego_b: &Pose,
        t_b_us: i64,
    ) -> Option<Self> {
        let dt_s = (t_b_us - t_a_us) as f64 * 1e-6;
        if !(dt_s > 0.0) {
            return None;
        }
        let a_from_b = global_from_ego_a.inverse() * *global_from_ego_b;
        let translation = a_from_b.translation;
        let dyaw = wrap_angle(yaw_of(global_from_ego_b) - yaw_of(global_from_ego_a));
        Some(Self {
            speed_mps: translation.x / dt_s,
            yaw_rate_rps: dyaw / dt_s,
            dx: translation.x,
            dy: translation.y,
            dyaw,
            dt_s,
        })
    }

    /// The features a model conditions on, as f32.
    pub fn as_features(&self) -> [f32; 5] {
        [
            self.speed_mps as f32,
            self.yaw_rate_rps as f32,
            self.dx as f32,
            self.dy as f32,
            self.dyaw as f32,
        ]
    }
}

pub fn wrap_angle(angle: f64) -> f64 {
    let two_pi = std::f64::consts::TAU;
    let mut wrapped = angle.rem_euclid(two_pi);
    if wrapped > std::f64::consts::PI {
        wrapped -= two_pi;
    }
    wrapped
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::{DQuat, DVec3};

    #[test]
    fn straight_drive_in_a_rotated_world() {
        // Ego heading +y in the world, drives 5 m forward in 0.5 s.
        let yaw = std::f64::consts::FRAC_PI_2;
        let a = Pose::from_rotation_translation(
            DQuat::from_rotation_z(yaw),
            DVec3::new(10.0, 20.0, 0.0),
        );
        let b = Pose::from_rotation_translation(
            DQuat::from_rotation_z(yaw),
            DVec3::new(10.0, 25.0, 0.0),
        );
        let action = EgoAction::between(&a, 0, &b, 500_000).unwrap();
        assert!((action.dx - 5.0).abs() < 1e-12 && action.dy.abs() < 1e-12);
        assert!((action.speed_mps - 10.0).abs() < 1e-9);
        assert!(action.dyaw.abs() < 1e-12);
    }

    #[test]
    fn turning_wraps_across_pi() {
        let a = Pose::from_rotation_translation(DQuat::from_rotation_z(3.1), DVec3::ZERO);
        let b = Pose::from_rotation_translation(DQuat::from_rotation_z(-3.1), DVec3::ZERO);
        let action = EgoAction::between(&a, 0, &b, 1_000_000).unwrap();
        assert!((action.dyaw - (std::f64::consts::TAU - 6.2)).abs() < 1e-9);
        assert!(EgoAction::between(&a, 5, &b, 5).is_none());
    }
}
