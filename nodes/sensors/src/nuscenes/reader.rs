//! Reads a nuScenes-layout dataset into `SensorFrame`s.
//!
//! Every token is resolved when the dataset is opened, so a dangling token or a missing table
//! is reported before the first frame, naming the table, the record and the field. Reading a
//! frame then only touches its seven sensor files.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use bevworld_types::{
    CameraChannel, CameraImage, EgoAction, Intrinsics, ObjectBox, PointCloud, Pose, SensorFrame,
    pose_from_translation_quaternion,
};
use rayon::prelude::*;

use super::tables::{CalibratedSensor, EgoPose, Sample, SampleData, Scene, Sensor, read_table};
use crate::error::{Result, SensorError};
use crate::lidar_file::{LidarLayout, NonFinitePolicy, decode_points};

#[derive(Clone, Debug, Default)]
pub struct NuScenesOptions {
    /// Table folder name, e.g. `v1.0-mini`; found automatically when there is only one.
    pub version: Option<String>,
    /// Scene names to read; empty = all, in table order.
    pub scenes: Vec<String>,
    /// Every LiDAR sweep (with the nearest camera images), not only keyframes.
    pub sweeps: bool,
    pub non_finite: NonFinitePolicy,
    /// Decode camera images; off for LiDAR-only pipelines.
    pub skip_images: bool,
}

/// One resolved sensor reading.
#[derive(Clone, Debug)]
struct Reading {
    /// The sample_data token.
    token: String,
    file: String,
    timestamp_us: i64,
    global_from_ego: Pose,
    ego_from_sensor: Pose,
    intrinsics: Option<Intrinsics>,
}

#[derive(Clone, Debug)]
struct FrameRef {
    sample_token: String,
    scene_name: String,
    index_in_scene: usize,
    lidar: Reading,
    cameras: Vec<(CameraChannel, Reading)>,
    action: Option<EgoAction>,
    /// The keyframe's annotated objects (none for a sweep between keyframes).
    boxes: Vec<ObjectBox>,
}

/// The bytes of one frame's files, read ahead of decoding.
pub struct FrameFiles {
    index: usize,
    lidar: Vec<u8>,
    cameras: Vec<Vec<u8>>,
}

pub struct NuScenes {
    root: PathBuf,
    version: String,
    frames: Vec<FrameRef>,
    options: NuScenesOptions,
    non_unit_quaternions: usize,
}

/// How far from unit a table's quaternion may be before it counts as non-unit: JSON's
/// decimal round trip leaves real ones within 1e-9.
const UNIT_QUATERNION_TOLERANCE: f64 = 1e-6;

fn is_non_unit(wxyz: &[f64; 4]) -> bool {
    let norm = wxyz.iter().map(|v| v * v).sum::<f64>().sqrt();
    (norm - 1.0).abs() > UNIT_QUATERNION_TOLERANCE
}

impl NuScenes {
    pub fn open(root: &Path, options: NuScenesOptions) -> Result<Self> {
        let version = match &options.version {
            Some(version) => version.clone(),
            None => detect_version(root)?,
        };
        let dir = root.join(&version);
        if !dir.is_dir() {
            return Err(SensorError::file(
                &dir,
                "no such table folder (expected the nuScenes layout: <root>/<version>/*.json)",
            ));
        }
        let (scene_path, scenes) = read_table::<Scene>(&dir, "scene")?;
        let (sample_path, samples) = read_table::<Sample>(&dir, "sample")?;
        let (data_path, sample_data) = read_table::<SampleData>(&dir, "sample_data")?;
        let (calib_path, calibrated) = read_table::<CalibratedSensor>(&dir, "calibrated_sensor")?;
        let (sensor_path, sensors) = read_table::<Sensor>(&dir, "sensor")?;
        let (pose_path, poses) = read_table::<EgoPose>(&dir, "ego_pose")?;
        let mut boxes = super::annotations::boxes_by_sample(&dir, &samples)?;

        let sensor_by_token: HashMap<&str, &Sensor> =
            sensors.iter().map(|s| (s.token.as_str(), s)).collect();
        let calib_by_token: HashMap<&str, &CalibratedSensor> =
            calibrated.iter().map(|c| (c.token.as_str(), c)).collect();
        let pose_by_token: HashMap<&str, &EgoPose> =
            poses.iter().map(|p| (p.token.as_str(), p)).collect();
        let sample_by_token: HashMap<&str, &Sample> =
            samples.iter().map(|s| (s.token.as_str(), s)).collect();
        for sensor in &sensors {
            if sensor.modality == "camera" && CameraChannel::from_name(&sensor.channel).is_none() {
                return Err(SensorError::field(
                    &sensor_path,
                    format!("sensor {}", sensor.token),
                    "channel",
                    format!(
                        "unknown camera channel '{}' (known: CAM_FRONT, CAM_FRONT_RIGHT, CAM_BACK_RIGHT, CAM_BACK, CAM_BACK_LEFT, CAM_FRONT_LEFT)",
                        sensor.channel
                    ),
                ));
            }
        }

        // Resolve every sample_data record into a reading with its channel.
        let mut readings: Vec<(String, &SampleData, Reading)> =
            Vec::with_capacity(sample_data.len());
        for record in &sample_data {
            let name = format!("sample_data {}", record.token);
            let calib = calib_by_token
                .get(record.calibrated_sensor_token.as_str())
                .ok_or_else(|| {
                    SensorError::field(
                        &data_path,
                        &name,
                        "calibrated_sensor_token",
                        format!(
                            "dangling token '{}' (not in {})",
                            record.calibrated_sensor_token,
                            calib_path.display()
                        ),
                    )
                })?;
            let sensor = sensor_by_token
                .get(calib.sensor_token.as_str())
                .ok_or_else(|| {
                    SensorError::field(
                        &calib_path,
                        format!("calibrated_sensor {}", calib.token),
                        "sensor_token",
                        format!(
                            "dangling token '{}' (not in {})",
                            calib.sensor_token,
                            sensor_path.display()
                        ),
                    )
                })?;
            let pose = pose_by_token
                .get(record.ego_pose_token.as_str())
                .ok_or_else(|| {
                    SensorError::field(
                        &data_path,
                        &name,
                        "ego_pose_token",
                        format!(
                            "dangling token '{}' (not in {})",
                            record.ego_pose_token,
                            pose_path.display()
                        ),
                    )
                })?;
            if !sample_by_token.contains_key(record.sample_token.as_str()) {
                return Err(SensorError::field(
                    &data_path,
                    &name,
                    "sample_token",
                    format!(
                        "dangling token '{}' (not in {})",
                        record.sample_token,
                        sample_path.display()
                    ),
                ));
            }
            let global_from_ego = pose_from_translation_quaternion(pose.translation, pose.rotation)
                .ok_or_else(|| {
                    SensorError::field(
                        &pose_path,
                        format!("ego_pose {}", pose.token),
                        "rotation",
                        "not a valid rotation quaternion or translation",
                    )
                })?;
            let ego_from_sensor =
                pose_from_translation_quaternion(calib.translation, calib.rotation).ok_or_else(
                    || {
                        SensorError::field(
                            &calib_path,
                            format!("calibrated_sensor {}", calib.token),
                            "rotation",
                            "not a valid rotation quaternion or translation",
                        )
                    },
                )?;
            let intrinsics = if sensor.modality == "camera" {
                let rows = &calib.camera_intrinsic;
                if rows.len() != 3
                    || rows
                        .iter()
                        .any(|row| row.len() != 3 || row.iter().any(|v| !v.is_finite()))
                {
                    return Err(SensorError::field(
                        &calib_path,
                        format!("calibrated_sensor {}", calib.token),
                        "camera_intrinsic",
                        "a camera needs a finite 3x3 matrix",
                    ));
                }
                let matrix = [
                    [rows[0][0], rows[0][1], rows[0][2]],
                    [rows[1][0], rows[1][1], rows[1][2]],
                    [rows[2][0], rows[2][1], rows[2][2]],
                ];
                // A focal length of 0 projects every point onto the principal point, and a
                // negative one mirrors the image: no real camera has either.
                let (fx, fy) = (matrix[0][0], matrix[1][1]);
                if !(fx > 0.0 && fy > 0.0) {
                    return Err(SensorError::field(
                        &calib_path,
                        format!("calibrated_sensor {}", calib.token),
                        "camera_intrinsic",
                        format!("focal lengths fx = {fx}, fy = {fy}: a camera needs both > 0"),
                    ));
                }
                Some(Intrinsics::from_rows(matrix, record.width, record.height))
            } else {
                None
            };
            readings.push((
                sensor.channel.clone(),
                record,
                Reading {
                    token: record.token.clone(),
                    file: record.filename.clone(),
                    timestamp_us: record.timestamp,
                    global_from_ego,
                    ego_from_sensor,
                    intrinsics,
                },
            ));
        }

        // Scenes in table order, filtered by name.
        let mut selected: Vec<&Scene> = Vec::new();
        for wanted in &options.scenes {
            if !scenes.iter().any(|s| &s.name == wanted) {
                let known: Vec<&str> = scenes.iter().map(|s| s.name.as_str()).collect();
                return Err(SensorError::file(
                    &scene_path,
                    format!("no scene named '{wanted}' (scenes: {})", known.join(", ")),
                ));
            }
        }
        for scene in &scenes {
            if options.scenes.is_empty() || options.scenes.contains(&scene.name) {
                selected.push(scene);
            }
        }

        let mut frames = Vec::new();
        for scene in selected {
            let keyframes = ordered_samples(scene, &samples, &sample_by_token, &sample_path)?;
            let scene_samples: std::collections::HashSet<&str> =
                keyframes.iter().map(|s| s.token.as_str()).collect();
            // LiDAR readings that define frames, in time order.
            let mut lidar_readings: Vec<&(String, &SampleData, Reading)> = readings
                .iter()
                .filter(|(channel, record, _)| {
                    channel == "LIDAR_TOP"
                        && scene_samples.contains(record.sample_token.as_str())
                        && (options.sweeps || record.is_key_frame)
                })
                .collect();
            lidar_readings.sort_by_key(|(_, record, _)| record.timestamp);
            if let Some(pair) = lidar_readings
                .windows(2)
                .find(|w| w[0].1.timestamp >= w[1].1.timestamp)
            {
                return Err(SensorError::field(
                    &data_path,
                    format!("sample_data {}", pair[1].1.token),
                    "timestamp",
                    format!(
                        "timestamps are not strictly increasing within scene '{}' ({} then {})",
                        scene.name, pair[0].1.timestamp, pair[1].1.timestamp
                    ),
                ));
            }
            let scene_cameras: Vec<&(String, &SampleData, Reading)> = readings
                .iter()
                .filter(|(channel, record, _)| {
                    CameraChannel::from_name(channel).is_some()
                        && scene_samples.contains(record.sample_token.as_str())
                        && (options.sweeps || record.is_key_frame)
                })
                .collect();
            let first_index = frames.len();
            for (index_in_scene, (_, lidar_record, lidar)) in lidar_readings.iter().enumerate() {
                let mut cameras = Vec::new();
                for channel in CameraChannel::ALL {
                    let candidates = scene_cameras.iter().filter(|(name, record, _)| {
                        name == channel.name()
                            && (options.sweeps || record.sample_token == lidar_record.sample_token)
                    });
                    let nearest = candidates.min_by_key(|(_, record, _)| {
                        (record.timestamp - lidar_record.timestamp).abs()
                    });
                    if let Some((_, _, reading)) = nearest {
                        cameras.push((channel, reading.clone()));
                    }
                }
                frames.push(FrameRef {
                    sample_token: lidar_record.sample_token.clone(),
                    scene_name: scene.name.clone(),
                    index_in_scene,
                    lidar: lidar.clone(),
                    cameras,
                    action: None,
                    boxes: if lidar_record.is_key_frame {
                        boxes.remove(&lidar_record.sample_token).unwrap_or_default()
                    } else {
                        Vec::new()
                    },
                });
            }
            // Actions between consecutive frames of the scene.
            for index in first_index..frames.len().saturating_sub(1) {
                let (a, b) = (&frames[index].lidar, &frames[index + 1].lidar);
                frames[index].action = EgoAction::between(
                    &a.global_from_ego,
                    a.timestamp_us,
                    &b.global_from_ego,
                    b.timestamp_us,
                );
            }
        }
        // Normalised where they are used (a zero or non-finite one was refused above); how many
        // needed it is a figure of the run, since a table written by hand often has them.
        let non_unit_quaternions = poses.iter().filter(|p| is_non_unit(&p.rotation)).count()
            + calibrated
                .iter()
                .filter(|c| is_non_unit(&c.rotation))
                .count();
        Ok(Self {
            root: root.to_path_buf(),
            version,
            frames,
            options,
            non_unit_quaternions,
        })
    }

    /// Rotations in `ego_pose` and `calibrated_sensor` that were not unit quaternions and were
    /// normalised.
    pub fn non_unit_quaternions(&self) -> usize {
        self.non_unit_quaternions
    }

    pub fn version(&self) -> &str {
        &self.version
    }

    pub fn root(&self) -> &Path {
        &self.root
    }

    pub fn len(&self) -> usize {
        self.frames.len()
    }

    pub fn is_empty(&self) -> bool {
        self.frames.is_empty()
    }

    /// The index of the frame of a sample token.
    pub fn index_of_sample(&self, token: &str) -> Option<usize> {
        self.frames
            .iter()
            .position(|frame| frame.sample_token == token)
    }

    /// Scene name of each frame, in frame order.
    pub fn scene_names(&self) -> Vec<&str> {
        self.frames.iter().map(|f| f.scene_name.as_str()).collect()
    }

    /// Reads the raw bytes of a frame's files (I/O only; safe to run ahead on an I/O pool).
    pub fn fetch(&self, index: usize) -> Result<FrameFiles> {
        let frame = self.frame_ref(index)?;
        let read = |file: &str| {
            let path = self.root.join(file);
            std::fs::read(&path).map_err(|error| SensorError::io(path, error))
        };
        let lidar = read(&frame.lidar.file)?;
        let cameras = if self.options.skip_images {
            Vec::new()
        } else {
            frame
                .cameras
                .iter()
                .map(|(_, reading)| read(&reading.file))
                .collect::<Result<Vec<_>>>()?
        };
        Ok(FrameFiles {
            index,
            lidar,
            cameras,
        })
    }

    /// Decodes fetched files into a frame; the six JPEG decodes run in parallel.
    pub fn decode(&self, files: FrameFiles) -> Result<SensorFrame> {
        let frame = self.frame_ref(files.index)?;
        let lidar_path = self.root.join(&frame.lidar.file);
        let (points, dropped) = decode_points(
            &files.lidar,
            LidarLayout::NuScenes,
            self.options.non_finite,
            &lidar_path,
        )?;
        let cloud = PointCloud {
            points,
            ego_from_lidar: frame.lidar.ego_from_sensor,
            timestamp_us: frame.lidar.timestamp_us,
            global_from_ego: frame.lidar.global_from_ego,
            dropped_non_finite: dropped,
            source_file: frame.lidar.file.clone(),
        };
        let cameras: Vec<CameraImage> = files
            .cameras
            .par_iter()
            .zip(frame.cameras.par_iter())
            .map(|(bytes, (channel, reading))| self.decode_camera(bytes, *channel, reading))
            .collect::<Result<Vec<_>>>()?;
        Ok(SensorFrame {
            time_of_validity_us: frame.lidar.timestamp_us,
            sample_token: frame.sample_token.clone(),
            frame_token: frame.lidar.token.clone(),
            scene_name: frame.scene_name.clone(),
            index_in_scene: frame.index_in_scene,
            global_from_ego: frame.lidar.global_from_ego,
            cameras,
            lidar: Arc::new(cloud),
            action: frame.action,
            boxes: frame.boxes.clone(),
        })
    }

    pub fn read(&self, index: usize) -> Result<SensorFrame> {
        self.decode(self.fetch(index)?)
    }

    fn decode_camera(
        &self,
        bytes: &[u8],
        channel: CameraChannel,
        reading: &Reading,
    ) -> Result<CameraImage> {
        let path = self.root.join(&reading.file);
        let image = crate::image_file::decode_rgb(bytes).map_err(|message| SensorError::Image {
            path: path.clone(),
            message,
        })?;
        let intrinsics = reading
            .intrinsics
            .ok_or_else(|| SensorError::file(&path, "camera reading without intrinsics"))?;
        if image.width() != intrinsics.width || image.height() != intrinsics.height {
            return Err(SensorError::file(
                &path,
                format!(
                    "image is {}x{} but sample_data says {}x{}",
                    image.width(),
                    image.height(),
                    intrinsics.width,
                    intrinsics.height
                ),
            ));
        }
        Ok(CameraImage {
            channel,
            image: Arc::new(image),
            intrinsics,
            ego_from_camera: reading.ego_from_sensor,
            timestamp_us: reading.timestamp_us,
            global_from_ego: reading.global_from_ego,
            source_file: reading.file.clone(),
        })
    }

    fn frame_ref(&self, index: usize) -> Result<&FrameRef> {
        self.frames.get(index).ok_or_else(|| {
            SensorError::Other(format!(
                "frame {index} out of range (dataset has {})",
                self.frames.len()
            ))
        })
    }
}

/// Finds the single `v1.0-*`-style table folder under `root`.
fn detect_version(root: &Path) -> Result<String> {
    let entries = std::fs::read_dir(root).map_err(|error| SensorError::io(root, error))?;
    let mut versions: Vec<String> = entries
        .filter_map(|entry| entry.ok())
        .filter(|entry| entry.path().join("sample_data.json").is_file())
        .filter_map(|entry| entry.file_name().to_str().map(str::to_string))
        .collect();
    versions.sort();
    match versions.len() {
        1 => Ok(versions.remove(0)),
        0 => Err(SensorError::file(
            root,
            "no table folder with sample_data.json (expected <root>/v1.0-*/; missing table?)",
        )),
        _ => Err(SensorError::file(
            root,
            format!(
                "several table folders ({}); choose one with version",
                versions.join(", ")
            ),
        )),
    }
}

/// A scene's keyframes in time order: the prev/next chain when the tables have it, otherwise
/// sorted by timestamp (trimmed tables leave prev/next empty). Either way strictly increasing.
fn ordered_samples<'a>(
    scene: &Scene,
    samples: &'a [Sample],
    by_token: &HashMap<&str, &'a Sample>,
    path: &Path,
) -> Result<Vec<&'a Sample>> {
    let mut ordered: Vec<&Sample> = Vec::new();
    let mut cursor = by_token.get(scene.first_sample_token.as_str()).copied();
    if cursor.is_none() && !scene.first_sample_token.is_empty() {
        return Err(SensorError::field(
            path.with_file_name("scene.json"),
            format!("scene {}", scene.name),
            "first_sample_token",
            format!("dangling token '{}'", scene.first_sample_token),
        ));
    }
    while let Some(sample) = cursor {
        if ordered.len() > samples.len() {
            return Err(SensorError::field(
                path,
                format!("sample {}", sample.token),
                "next",
                "the prev/next chain loops",
            ));
        }
        ordered.push(sample);
        cursor = if sample.next.is_empty() {
            None
        } else {
            Some(by_token.get(sample.next.as_str()).copied().ok_or_else(|| {
                SensorError::field(
                    path,
                    format!("sample {}", sample.token),
                    "next",
                    format!("dangling token '{}'", sample.next),
                )
            })?)
        };
    }
    let in_scene: Vec<&Sample> = samples
        .iter()
        .filter(|s| s.scene_token == scene.token)
        .collect();
    if ordered.len() < in_scene.len() {
        // Trimmed chain: fall back to time order.
        ordered = in_scene;
        ordered.sort_by_key(|s| s.timestamp);
    }
    if let Some(pair) = ordered
        .windows(2)
        .find(|w| w[0].timestamp >= w[1].timestamp)
    {
        return Err(SensorError::field(
            path,
            format!("sample {}", pair[1].token),
            "timestamp",
            format!(
                "timestamps are not strictly increasing in scene '{}' ({} then {})",
                scene.name, pair[0].timestamp, pair[1].timestamp
            ),
        ));
    }
    Ok(ordered)
}
