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

/// What a road vehicle can do. An action past these is not unusual but impossible (a unit
/// error, a typo, a corrupt pose) and is refused wherever a forecast would be conditioned on
/// it; an action inside them but outside what a model was trained on is merely unusual, and is
/// forecast and counted.
pub mod limits {
    /// Forward speed, m/s (252 km/h).
    pub const MAX_FORWARD_SPEED_MPS: f64 = 70.0;
    /// Speed in reverse, m/s (36 km/h).
    pub const MAX_REVERSE_SPEED_MPS: f64 = 10.0;
    /// Yaw rate, rad/s (about 115 °/s: a tight turn at walking pace).
    pub const MAX_YAW_RATE_RPS: f64 = 2.0;
    /// Lateral acceleration `|speed · yaw rate|`, m/s² (1.5 g, past what tyres hold).
    pub const MAX_LATERAL_ACCELERATION_MPS2: f64 = 15.0;
}

impl EgoAction {
    /// Why no road vehicle could make this motion, if none could (`limits`).
    pub fn impossible(&self) -> Option<String> {
        use limits::*;
        let (speed, yaw_rate) = (self.speed_mps, self.yaw_rate_rps);
        if !(speed.is_finite() && yaw_rate.is_finite() && self.dt_s.is_finite()) {
            return Some(format!(
                "speed {speed} m/s, yaw rate {yaw_rate} rad/s over {} s: not finite",
                self.dt_s
            ));
        }
        if !(-MAX_REVERSE_SPEED_MPS..=MAX_FORWARD_SPEED_MPS).contains(&speed) {
            return Some(format!(
                "speed {speed} m/s: a road vehicle drives between {} m/s (reversing) and {MAX_FORWARD_SPEED_MPS} m/s",
                -MAX_REVERSE_SPEED_MPS
            ));
        }
        if yaw_rate.abs() > MAX_YAW_RATE_RPS {
            return Some(format!(
                "yaw rate {yaw_rate} rad/s: a road vehicle turns at most {MAX_YAW_RATE_RPS} rad/s"
            ));
        }
        let lateral = (speed * yaw_rate).abs();
        if lateral > MAX_LATERAL_ACCELERATION_MPS2 {
            return Some(format!(
                "speed {speed} m/s with yaw rate {yaw_rate} rad/s: a lateral acceleration of {lateral:.1} m/s², past the {MAX_LATERAL_ACCELERATION_MPS2} m/s² tyres hold"
            ));
        }
        None
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
    fn impossible_motions_are_named_and_unusual_ones_pass() {
        let at = |speed: f64, yaw_rate: f64| EgoAction {
            speed_mps: speed,
            yaw_rate_rps: yaw_rate,
            dt_s: 0.5,
            ..EgoAction::default()
        };
        for possible in [
            (0.0, 0.0),
            (12.0, 0.3),
            (-3.0, 0.5),
            (69.0, 0.1),
            (5.0, 2.0),
        ] {
            assert_eq!(
                at(possible.0, possible.1).impossible(),
                None,
                "{possible:?}"
            );
        }
        for (impossible, word) in [
            ((1e300, 0.0), "speed"),
            ((-30.0, 0.0), "reversing"),
            ((10.0, 1e6), "yaw rate"),
            ((f64::NAN, 0.0), "not finite"),
            // 20 m/s at 1 rad/s: 20 m/s², 2 g sideways.
            ((20.0, 1.0), "lateral"),
        ] {
            let reason = at(impossible.0, impossible.1)
                .impossible()
                .unwrap_or_default();
            assert!(reason.contains(word), "{impossible:?}: {reason}");
        }
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
