//! The synthetic sensor rig: six cameras and a roof LiDAR mounted like nuScenes' vehicle
//! (calibration of scene-0061's vehicle n015, rounded), so models see the same geometry on
//! synthetic and real data.

use bevworld_types::{CameraChannel, Intrinsics, Pose, pose_from_translation_quaternion};

pub struct CameraMount {
    pub channel: CameraChannel,
    pub translation: [f64; 3],
    /// [w, x, y, z]
    pub rotation: [f64; 4],
    /// fx, fy, cx, cy at 1600 x 900.
    pub intrinsics_1600: [f64; 4],
    /// Trigger time relative to the LiDAR's, microseconds (cameras fire as the LiDAR sweeps by).
    pub offset_us: i64,
}

/// One camera's mount, a line of the table below.
const fn mount(
    channel: CameraChannel,
    translation: [f64; 3],
    rotation: [f64; 4],
    intrinsics_1600: [f64; 4],
    offset_us: i64,
) -> CameraMount {
    CameraMount {
        channel,
        translation,
        rotation,
        intrinsics_1600,
        offset_us,
    }
}

#[rustfmt::skip] // a table: one camera a line
pub const CAMERAS: [CameraMount; 6] = [
    // channel, translation (m), rotation [w, x, y, z], fx fy cx cy at 1600 x 900, offset (µs)
    mount(CameraChannel::Front, [1.7008, 0.0159, 1.5110], [0.499802, -0.503032, 0.499780, -0.497371], [1266.42, 1266.42, 816.27, 491.51], -35_491),
    mount(CameraChannel::FrontRight, [1.5508, -0.4934, 1.4957], [0.206035, -0.202694, 0.682451, -0.671361], [1260.85, 1260.85, 807.97, 495.33], -27_612),
    mount(CameraChannel::BackRight, [1.0149, -0.4806, 1.5624], [0.122810, -0.132401, -0.700431, 0.690496], [1259.51, 1259.51, 807.25, 501.20], -20_058),
    mount(CameraChannel::Back, [0.0283, 0.0035, 1.5791], [0.503787, -0.497402, -0.494185, 0.504550], [809.22, 809.22, 829.22, 481.78], -10_426),
    mount(CameraChannel::BackLeft, [1.0357, 0.4848, 1.5910], [0.692419, -0.703162, -0.116483, 0.112033], [1256.74, 1256.74, 792.11, 492.78], -528),
    mount(CameraChannel::FrontLeft, [1.5239, 0.4946, 1.5093], [0.675727, -0.673627, 0.212140, -0.211228], [1272.60, 1272.60, 826.62, 479.75], -43_107),
];

pub const LIDAR_TRANSLATION: [f64; 3] = [0.943713, 0.0, 1.84023];
pub const LIDAR_ROTATION: [f64; 4] = [
    0.7077955119163518,
    -0.006492242056004365,
    0.010646214713995808,
    -0.7063073142877817,
];

impl CameraMount {
    pub fn ego_from_camera(&self) -> Pose {
        pose_from_translation_quaternion(self.translation, self.rotation).unwrap_or_default()
    }

    /// Intrinsics for an image of `width` x `height`, scaled from the 1600 x 900 calibration.
    pub fn intrinsics(&self, width: u32, height: u32) -> Intrinsics {
        let [fx, fy, cx, cy] = self.intrinsics_1600;
        Intrinsics {
            fx,
            fy,
            cx,
            cy,
            width: 1600,
            height: 900,
        }
        .scaled_to(width, height)
    }
}

pub fn ego_from_lidar() -> Pose {
    pose_from_translation_quaternion(LIDAR_TRANSLATION, LIDAR_ROTATION).unwrap_or_default()
}
