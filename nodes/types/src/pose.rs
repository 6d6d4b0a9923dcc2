//! Rigid transforms in f64.

use glam::{DAffine3, DQuat, DVec3};

/// A rigid transform `a_from_b`, named at its use site.
pub type Pose = DAffine3;

/// Builds a pose from a translation and a unit quaternion given as [w, x, y, z] (the nuScenes
/// order). The quaternion is normalised, since JSON round-trips leave it a little off unit.
pub fn pose_from_translation_quaternion(translation: [f64; 3], wxyz: [f64; 4]) -> Option<Pose> {
    let [w, x, y, z] = wxyz;
    let rotation = DQuat::from_xyzw(x, y, z, w);
    let length = rotation.length();
    if !length.is_finite() || length < 1e-9 || translation.iter().any(|t| !t.is_finite()) {
        return None;
    }
    Some(DAffine3::from_rotation_translation(
        rotation / length,
        DVec3::from_array(translation),
    ))
}

/// Yaw (rotation about +z) of a pose, in radians.
pub fn yaw_of(pose: &Pose) -> f64 {
    let x_axis = pose.matrix3.x_axis;
    x_axis.y.atan2(x_axis.x)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quaternion_order_is_wxyz() {
        // 90 degrees about z: w = cos 45, z = sin 45.
        let half = std::f64::consts::FRAC_1_SQRT_2;
        let pose =
            pose_from_translation_quaternion([1.0, 2.0, 3.0], [half, 0.0, 0.0, half]).unwrap();
        let moved = pose.transform_point3(DVec3::X);
        assert!((moved - DVec3::new(1.0, 3.0, 3.0)).length() < 1e-12);
        assert!((yaw_of(&pose) - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
    }

    #[test]
    fn degenerate_quaternion_is_rejected() {
        assert!(pose_from_translation_quaternion([0.0; 3], [0.0; 4]).is_none());
        assert!(
            pose_from_translation_quaternion([f64::NAN, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0]).is_none()
        );
    }
}
