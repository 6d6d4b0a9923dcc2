//! `bevworld inspect` on the real nuScenes keyframe, against a projection computed here
//! independently from the raw JSON tables and sweep file (quaternion maths written out by hand,
//! following the devkit's map_pointcloud_to_image step by step).

use std::process::Command;

type M3 = [[f64; 3]; 3];

fn rotation(q: &[f64]) -> M3 {
    let (w, x, y, z) = (q[0], q[1], q[2], q[3]);
    let n = (w * w + x * x + y * y + z * z).sqrt();
    let (w, x, y, z) = (w / n, x / n, y / n, z / n);
    [
        [
            1.0 - 2.0 * (y * y + z * z),
            2.0 * (x * y - w * z),
            2.0 * (x * z + w * y),
        ],
        [
            2.0 * (x * y + w * z),
            1.0 - 2.0 * (x * x + z * z),
            2.0 * (y * z - w * x),
        ],
        [
            2.0 * (x * z - w * y),
            2.0 * (y * z + w * x),
            1.0 - 2.0 * (x * x + y * y),
        ],
    ]
}

fn apply(m: &M3, p: [f64; 3]) -> [f64; 3] {
    [0, 1, 2].map(|r| m[r][0] * p[0] + m[r][1] * p[1] + m[r][2] * p[2])
}

fn transpose(m: &M3) -> M3 {
    [0, 1, 2].map(|r| [0, 1, 2].map(|c| m[c][r]))
}

fn f64s(value: &serde_json::Value) -> Vec<f64> {
    value
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect()
}

#[test]
fn inspect_matches_an_independent_devkit_projection() {
    let Some(root) = bevworld_sensors::real_dataset("nuscenes-sample") else {
        return;
    };
    let out = tempfile::tempdir().unwrap();
    let status = Command::new(env!("CARGO_BIN_EXE_bevworld"))
        .args([
            "inspect",
            "--data",
            root.to_str().unwrap(),
            "--index",
            "0",
            "--out",
            out.path().to_str().unwrap(),
        ])
        .status()
        .unwrap();
    assert!(status.success());

    let table = |name: &str| -> Vec<serde_json::Value> {
        serde_json::from_slice(&std::fs::read(root.join(format!("v1.0-mini/{name}.json"))).unwrap())
            .unwrap()
    };
    let (data, calib, sensors, poses) = (
        table("sample_data"),
        table("calibrated_sensor"),
        table("sensor"),
        table("ego_pose"),
    );
    let by_channel = |channel: &str| {
        let sensor = sensors.iter().find(|s| s["channel"] == channel).unwrap();
        let cs = calib
            .iter()
            .find(|c| c["sensor_token"] == sensor["token"])
            .unwrap();
        let sd = data
            .iter()
            .find(|d| d["calibrated_sensor_token"] == cs["token"])
            .unwrap();
        let pose = poses
            .iter()
            .find(|p| p["token"] == sd["ego_pose_token"])
            .unwrap();
        (sd.clone(), cs.clone(), pose.clone())
    };
    let (lidar_sd, lidar_cs, lidar_pose) = by_channel("LIDAR_TOP");
    let (cam_sd, cam_cs, cam_pose) = by_channel("CAM_FRONT");
    let bytes = std::fs::read(root.join(lidar_sd["filename"].as_str().unwrap())).unwrap();

    let mut expected = Vec::new();
    for record in bytes.chunks_exact(20) {
        let f = |k: usize| {
            f64::from(f32::from_le_bytes(
                record[4 * k..4 * k + 4].try_into().unwrap(),
            ))
        };
        let mut p = [f(0), f(1), f(2)];
        // 1. lidar -> ego (lidar timestamp)
        let t = f64s(&lidar_cs["translation"]);
        p = apply(&rotation(&f64s(&lidar_cs["rotation"])), p);
        p = [p[0] + t[0], p[1] + t[1], p[2] + t[2]];
        // 2. ego -> global
        let t = f64s(&lidar_pose["translation"]);
        p = apply(&rotation(&f64s(&lidar_pose["rotation"])), p);
        p = [p[0] + t[0], p[1] + t[1], p[2] + t[2]];
        // 3. global -> ego (camera timestamp)
        let t = f64s(&cam_pose["translation"]);
        p = [p[0] - t[0], p[1] - t[1], p[2] - t[2]];
        p = apply(&transpose(&rotation(&f64s(&cam_pose["rotation"]))), p);
        // 4. ego -> camera
        let t = f64s(&cam_cs["translation"]);
        p = [p[0] - t[0], p[1] - t[1], p[2] - t[2]];
        p = apply(&transpose(&rotation(&f64s(&cam_cs["rotation"]))), p);
        let depth = p[2];
        let k: Vec<Vec<f64>> = cam_cs["camera_intrinsic"]
            .as_array()
            .unwrap()
            .iter()
            .map(f64s)
            .collect();
        let u = (k[0][0] * p[0] + k[0][1] * p[1] + k[0][2] * p[2]) / depth;
        let v = (k[1][0] * p[0] + k[1][1] * p[1] + k[1][2] * p[2]) / depth;
        let (w, h) = (
            cam_sd["width"].as_f64().unwrap(),
            cam_sd["height"].as_f64().unwrap(),
        );
        if depth > 1.0 && u > 1.0 && u < w - 1.0 && v > 1.0 && v < h - 1.0 {
            expected.push((u, v, depth));
        }
    }

    let csv = std::fs::read_to_string(out.path().join("CAM_FRONT.csv")).unwrap();
    let mut lines = csv.lines();
    assert_eq!(lines.next(), Some("u,v,depth"));
    let got: Vec<(f64, f64, f64)> = lines
        .map(|line| {
            let v: Vec<f64> = line.split(',').map(|x| x.parse().unwrap()).collect();
            (v[0], v[1], v[2])
        })
        .collect();
    assert!(
        expected.len() > 3000,
        "{} points in CAM_FRONT",
        expected.len()
    );
    assert_eq!(got.len(), expected.len());
    let worst = got
        .iter()
        .zip(&expected)
        .map(|(a, b)| {
            (a.0 - b.0)
                .abs()
                .max((a.1 - b.1).abs())
                .max((a.2 - b.2).abs())
        })
        .fold(0.0, f64::max);
    assert!(worst < 1e-5, "largest difference {worst} px/m");
    let png = image::open(out.path().join("CAM_FRONT.png")).unwrap();
    assert_eq!((png.width(), png.height()), (1600, 900));
}
