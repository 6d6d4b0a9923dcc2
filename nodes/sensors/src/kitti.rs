//! KITTI odometry: `velodyne/*.bin` (float32 x 4), `poses.txt` (camera-0 poses, 3x4 row-major
//! per line), `times.txt` (seconds) and `calib.txt` (`Tr`, velodyne to camera 0).
//!
//! The velodyne frame (x forward, y left, z up) serves as the ego frame, and frame 0's velodyne
//! frame as the global one: `global_from_ego_k = Tr^-1 * P_k * Tr`.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use bevworld_types::{EgoAction, PointCloud, Pose, SensorFrame};
use glam::{DMat3, DVec3};

use crate::error::{Result, SensorError};
use crate::lidar_file::{LidarLayout, NonFinitePolicy, decode_points};

pub struct Kitti {
    root: PathBuf,
    scans: Vec<PathBuf>,
    poses: Vec<Pose>,
    times_us: Vec<i64>,
    sequence: String,
    non_finite: NonFinitePolicy,
}

/// Parses 12 numbers as a 3x4 row-major rigid transform.
fn parse_3x4(values: &[f64]) -> Pose {
    let m = DMat3::from_cols(
        DVec3::new(values[0], values[4], values[8]),
        DVec3::new(values[1], values[5], values[9]),
        DVec3::new(values[2], values[6], values[10]),
    );
    Pose {
        matrix3: m,
        translation: DVec3::new(values[3], values[7], values[11]),
    }
}

fn numbers(text: &str, path: &Path, line: usize, field: &'static str) -> Result<Vec<f64>> {
    text.split_whitespace()
        .map(|token| {
            token
                .parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| {
                    SensorError::field(
                        path,
                        format!("line {line}"),
                        field,
                        format!("'{token}' is not a finite number"),
                    )
                })
        })
        .collect()
}

impl Kitti {
    /// True when `root` looks like a KITTI odometry sequence.
    pub fn recognise(root: &Path) -> bool {
        root.join("velodyne").is_dir() && root.join("poses.txt").is_file()
    }

    pub fn open(root: &Path, non_finite: NonFinitePolicy) -> Result<Self> {
        let calib_path = root.join("calib.txt");
        let calib =
            std::fs::read_to_string(&calib_path).map_err(|e| SensorError::io(&calib_path, e))?;
        let mut tr = None;
        for (number, line) in calib.lines().enumerate() {
            if let Some(rest) = line.strip_prefix("Tr:") {
                let values = numbers(rest, &calib_path, number + 1, "Tr")?;
                if values.len() != 12 {
                    return Err(SensorError::field(
                        &calib_path,
                        format!("line {}", number + 1),
                        "Tr",
                        format!("has {} numbers, needs 12 (3x4 row-major)", values.len()),
                    ));
                }
                tr = Some(parse_3x4(&values));
            }
        }
        let camera_from_velodyne = tr.ok_or_else(|| {
            SensorError::field(
                &calib_path,
                "file",
                "Tr",
                "missing (expected a line 'Tr: 12 numbers')",
            )
        })?;
        let velodyne_from_camera = camera_from_velodyne.inverse();

        let poses_path = root.join("poses.txt");
        let text =
            std::fs::read_to_string(&poses_path).map_err(|e| SensorError::io(&poses_path, e))?;
        let mut poses = Vec::new();
        for (number, line) in text
            .lines()
            .enumerate()
            .filter(|(_, l)| !l.trim().is_empty())
        {
            let values = numbers(line, &poses_path, number + 1, "pose")?;
            if values.len() != 12 {
                return Err(SensorError::field(
                    &poses_path,
                    format!("line {}", number + 1),
                    "pose",
                    format!("has {} numbers, needs 12 (3x4 row-major)", values.len()),
                ));
            }
            // Camera-0 pose in the world; as a velodyne pose in frame 0's velodyne coordinates.
            poses.push(velodyne_from_camera * parse_3x4(&values) * camera_from_velodyne);
        }

        let times_path = root.join("times.txt");
        let text =
            std::fs::read_to_string(&times_path).map_err(|e| SensorError::io(&times_path, e))?;
        let mut times_us: Vec<i64> = Vec::new();
        for (number, line) in text
            .lines()
            .enumerate()
            .filter(|(_, l)| !l.trim().is_empty())
        {
            let values = numbers(line, &times_path, number + 1, "time")?;
            if values.len() != 1 {
                return Err(SensorError::field(
                    &times_path,
                    format!("line {}", number + 1),
                    "time",
                    "needs exactly one number of seconds",
                ));
            }
            let us = (values[0] * 1e6).round() as i64;
            if let Some(&previous) = times_us.last()
                && us <= previous
            {
                return Err(SensorError::field(
                    &times_path,
                    format!("line {}", number + 1),
                    "time",
                    format!(
                        "non-monotonic timestamps: {} s is not after the previous {} s",
                        values[0],
                        previous as f64 * 1e-6
                    ),
                ));
            }
            times_us.push(us);
        }

        let velodyne = root.join("velodyne");
        let mut scans: Vec<PathBuf> = std::fs::read_dir(&velodyne)
            .map_err(|e| SensorError::io(&velodyne, e))?
            .filter_map(|entry| entry.ok().map(|e| e.path()))
            .filter(|path| path.extension().is_some_and(|e| e == "bin"))
            .collect();
        scans.sort();
        let count = scans.len().min(poses.len()).min(times_us.len());
        if count == 0 {
            return Err(SensorError::file(
                root,
                format!(
                    "no complete frames: {} scans, {} poses, {} times",
                    scans.len(),
                    poses.len(),
                    times_us.len()
                ),
            ));
        }
        if scans.len() > poses.len() {
            return Err(SensorError::file(
                &poses_path,
                format!(
                    "has {} poses for {} scans in velodyne/",
                    poses.len(),
                    scans.len()
                ),
            ));
        }
        scans.truncate(count);
        let sequence = root
            .file_name()
            .and_then(|n| n.to_str())
            .unwrap_or("kitti")
            .to_string();
        Ok(Self {
            root: root.to_path_buf(),
            scans,
            poses,
            times_us,
            sequence,
            non_finite,
        })
    }

    pub fn len(&self) -> usize {
        self.scans.len()
    }

    pub fn is_empty(&self) -> bool {
        self.scans.is_empty()
    }

    pub fn sequence(&self) -> &str {
        &self.sequence
    }

    pub fn pose(&self, index: usize) -> Option<&Pose> {
        self.poses.get(index)
    }

    pub fn fetch(&self, index: usize) -> Result<(usize, Vec<u8>)> {
        let path = self
            .scans
            .get(index)
            .ok_or_else(|| SensorError::Other(format!("frame {index} out of range")))?;
        Ok((
            index,
            std::fs::read(path).map_err(|e| SensorError::io(path, e))?,
        ))
    }

    pub fn decode(&self, (index, bytes): (usize, Vec<u8>)) -> Result<SensorFrame> {
        let path = &self.scans[index];
        let (points, dropped) = decode_points(&bytes, LidarLayout::Kitti, self.non_finite, path)?;
        let global_from_ego = self.poses[index];
        let time = self.times_us[index];
        let action = (index + 1 < self.len())
            .then(|| {
                EgoAction::between(
                    &global_from_ego,
                    time,
                    &self.poses[index + 1],
                    self.times_us[index + 1],
                )
            })
            .flatten();
        let relative = path
            .strip_prefix(&self.root)
            .unwrap_or(path)
            .display()
            .to_string();
        Ok(SensorFrame {
            time_of_validity_us: time,
            sample_token: format!("{}/{:06}", self.sequence, index),
            frame_token: format!("{}/{:06}", self.sequence, index),
            scene_name: self.sequence.clone(),
            index_in_scene: index,
            keyframe: true,
            global_from_ego,
            cameras: Vec::new(),
            lidar: Arc::new(PointCloud {
                points,
                ego_from_lidar: Pose::IDENTITY,
                timestamp_us: time,
                global_from_ego,
                dropped_non_finite: dropped,
                source_file: relative,
            }),
            action,
            // KITTI odometry has no object annotations.
            boxes: Vec::new(),
        })
    }
}
