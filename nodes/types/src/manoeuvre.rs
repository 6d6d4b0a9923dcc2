//! The ego's future actions when the log has none: a manoeuvre from the current motion, each
//! defined once, here. A forecast conditioned on `left` and on `right` from one context must
//! differ, and these are what a user asks for. The world model's rollout turns them into
//! actions; the synthetic world drives them (`bevworld synth --branch-at`), so that a forecast
//! of each has its ground truth.

use serde::{Deserialize, Serialize};

use crate::action::{EgoAction, wrap_angle};

/// What the ego does over the forecast.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Manoeuvre {
    /// Constant speed and yaw rate.
    Keep,
    /// Yaw rate +`TURN_RATE_RPS` (counter-clockwise), speed kept.
    Left,
    /// Yaw rate −`TURN_RATE_RPS`, speed kept.
    Right,
    /// Accelerate at `ACCELERATION_MPS2`, straight.
    Faster,
    /// Brake at `DECELERATION_MPS2`, straight, never below 0.
    Slower,
    /// Brake at `STOP_DECELERATION_MPS2` to a standstill, straight.
    Stop,
}

/// ≈ 14°/s: a town turn of radius ≈ 32 m at 8 m/s.
pub const TURN_RATE_RPS: f64 = 0.25;
pub const ACCELERATION_MPS2: f64 = 1.5;
pub const DECELERATION_MPS2: f64 = 2.0;
pub const STOP_DECELERATION_MPS2: f64 = 4.0;

impl Manoeuvre {
    pub const ALL: [Manoeuvre; 6] = [
        Manoeuvre::Keep,
        Manoeuvre::Left,
        Manoeuvre::Right,
        Manoeuvre::Faster,
        Manoeuvre::Slower,
        Manoeuvre::Stop,
    ];

    /// The actions into `frames` future frames `dt_s` apart, from the ego's `current` action
    /// (its speed and yaw rate).
    pub fn actions(self, current: &EgoAction, frames: usize, dt_s: f64) -> Vec<EgoAction> {
        let mut speed = current.speed_mps.max(0.0);
        let yaw_rate = self.yaw_rate(current.yaw_rate_rps);
        let acceleration = self.acceleration();
        (0..frames)
            .map(|_| {
                let end_speed = (speed + acceleration * dt_s).max(0.0);
                let mean_speed = 0.5 * (speed + end_speed);
                speed = end_speed;
                constant_turn(mean_speed, yaw_rate, dt_s)
            })
            .collect()
    }

    pub fn parse(text: &str) -> Option<Self> {
        Self::ALL
            .into_iter()
            .find(|m| m.name().eq_ignore_ascii_case(text))
    }

    /// The name users write: `keep`, `left`, …
    pub fn name(self) -> &'static str {
        match self {
            Manoeuvre::Keep => "keep",
            Manoeuvre::Left => "left",
            Manoeuvre::Right => "right",
            Manoeuvre::Faster => "faster",
            Manoeuvre::Slower => "slower",
            Manoeuvre::Stop => "stop",
        }
    }

    /// Its yaw rate, for a driven ego whose current yaw rate is `current`.
    pub fn yaw_rate(self, current: f64) -> f64 {
        match self {
            Manoeuvre::Keep => current,
            Manoeuvre::Left => TURN_RATE_RPS,
            Manoeuvre::Right => -TURN_RATE_RPS,
            Manoeuvre::Faster | Manoeuvre::Slower | Manoeuvre::Stop => 0.0,
        }
    }

    /// Its longitudinal acceleration, m/s² (speed never goes below 0).
    pub fn acceleration(self) -> f64 {
        match self {
            Manoeuvre::Faster => ACCELERATION_MPS2,
            Manoeuvre::Slower => -DECELERATION_MPS2,
            Manoeuvre::Stop => -STOP_DECELERATION_MPS2,
            Manoeuvre::Keep | Manoeuvre::Left | Manoeuvre::Right => 0.0,
        }
    }
}

/// The ego's motion now, at the end of the last of `into_frames` (the actions into the last
/// frames, oldest first). An action's speed and yaw rate are means over its interval, half an
/// interval behind the frame it ends at: each is carried that half interval further along its
/// change since the action before, so that an ego that was speeding up is not taken for one
/// holding its speed. With one action, its rates are the estimate.
pub fn current_motion(into_frames: &[EgoAction]) -> EgoAction {
    match into_frames {
        [] => EgoAction::default(),
        [only] => *only,
        [.., before, last] => EgoAction {
            speed_mps: (last.speed_mps + 0.5 * (last.speed_mps - before.speed_mps)).max(0.0),
            yaw_rate_rps: last.yaw_rate_rps + 0.5 * (last.yaw_rate_rps - before.yaw_rate_rps),
            ..*last
        },
    }
}

/// The action of driving at `speed` with `yaw_rate` for `dt_s`: an arc, exactly.
pub fn constant_turn(speed: f64, yaw_rate: f64, dt_s: f64) -> EgoAction {
    let dyaw = yaw_rate * dt_s;
    let distance = speed * dt_s;
    // The chord of the arc, at half the heading change (→ a straight line as dyaw → 0).
    let chord = if dyaw.abs() < 1e-9 {
        distance
    } else {
        2.0 * distance / dyaw * (0.5 * dyaw).sin()
    };
    EgoAction {
        // The ego-frame speed, as `EgoAction::between` measures it from two poses: dx / dt.
        speed_mps: chord * (0.5 * dyaw).cos() / dt_s,
        yaw_rate_rps: yaw_rate,
        dx: chord * (0.5 * dyaw).cos(),
        dy: chord * (0.5 * dyaw).sin(),
        dyaw: wrap_angle(dyaw),
        dt_s,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Pose;
    use glam::{DQuat, DVec3};

    #[test]
    fn an_arc_matches_the_poses_it_joins() {
        // Quarter circle of radius 10 m: from the origin heading +x to (10, 10) heading +y.
        let speed = 10.0 * std::f64::consts::FRAC_PI_2;
        let action = constant_turn(speed, std::f64::consts::FRAC_PI_2, 1.0);
        let end = Pose::from_rotation_translation(
            DQuat::from_rotation_z(std::f64::consts::FRAC_PI_2),
            DVec3::new(10.0, 10.0, 0.0),
        );
        let measured = EgoAction::between(&Pose::IDENTITY, 0, &end, 1_000_000).unwrap();
        for (a, b) in action.as_features().iter().zip(measured.as_features()) {
            assert!((a - b).abs() < 1e-5, "{action:?} vs {measured:?}");
        }
    }

    #[test]
    fn the_current_motion_is_carried_half_an_interval_past_the_last_mean() {
        // Speeding up at 2 m/s²: the means over two 0.5 s intervals are 4 and 5 m/s, so the
        // speed at the end of the second is 5.5 m/s.
        let actions = [constant_turn(4.0, 0.1, 0.5), constant_turn(5.0, 0.2, 0.5)];
        let now = current_motion(&actions);
        // (An action's speed is its forward displacement over time, a little less on an arc.)
        assert!((now.speed_mps - 5.5).abs() < 0.02, "{now:?}");
        assert!((now.yaw_rate_rps - 0.25).abs() < 1e-9);
        assert_eq!(current_motion(&actions[..1]), actions[0]);
        assert_eq!(current_motion(&[]), EgoAction::default());
        // Braking to a stop is not carried below standstill.
        let stopping = [constant_turn(3.0, 0.0, 0.5), constant_turn(0.5, 0.0, 0.5)];
        assert_eq!(current_motion(&stopping).speed_mps, 0.0);
    }

    #[test]
    fn manoeuvres_do_what_they_say() {
        let current = constant_turn(8.0, 0.05, 0.5);
        let keep = Manoeuvre::Keep.actions(&current, 6, 0.5);
        assert!(keep.iter().all(|a| (a.yaw_rate_rps - 0.05).abs() < 1e-12));
        let left = Manoeuvre::Left.actions(&current, 6, 0.5);
        let right = Manoeuvre::Right.actions(&current, 6, 0.5);
        assert!(left.iter().all(|a| a.dy > 0.0 && a.dyaw > 0.0));
        assert!(right.iter().all(|a| a.dy < 0.0 && a.dyaw < 0.0));
        let stop = Manoeuvre::Stop.actions(&current, 6, 0.5);
        assert!(stop[0].dx > 0.0);
        assert!(stop[5].dx.abs() < 1e-12, "stopped after 2 s at 4 m/s²");
        let faster = Manoeuvre::Faster.actions(&current, 6, 0.5);
        assert!(faster.windows(2).all(|w| w[1].dx > w[0].dx));
        assert_eq!(Manoeuvre::parse("LEFT"), Some(Manoeuvre::Left));
        assert_eq!(Manoeuvre::parse("sideways"), None);
    }
}
