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
    keyframe: bool,
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

/// The tables a dataset is opened from, each with the file it was read from.
struct Tables {
    scenes: (PathBuf, Vec<Scene>),
    samples: (PathBuf, Vec<Sample>),
    sample_data: (PathBuf, Vec<SampleData>),
    calibrated: (PathBuf, Vec<CalibratedSensor>),
    sensors: (PathBuf, Vec<Sensor>),
    poses: (PathBuf, Vec<EgoPose>),
}

impl Tables {
    fn read(dir: &Path) -> Result<Self> {
        Ok(Self {
            scenes: read_table::<Scene>(dir, "scene")?,
            samples: read_table::<Sample>(dir, "sample")?,
            sample_data: read_table::<SampleData>(dir, "sample_data")?,
            calibrated: read_table::<CalibratedSensor>(dir, "calibrated_sensor")?,
            sensors: read_table::<Sensor>(dir, "sensor")?,
            poses: read_table::<EgoPose>(dir, "ego_pose")?,
        })
    }
}

/// The tables' records by token, for resolving a `sample_data` record's references.
struct TableIndex<'t> {
    tables: &'t Tables,
    sensors: HashMap<&'t str, &'t Sensor>,
    calibrated: HashMap<&'t str, &'t CalibratedSensor>,
    poses: HashMap<&'t str, &'t EgoPose>,
    samples: HashMap<&'t str, &'t Sample>,
}

/// A resolved reading with its channel and record.
type ChannelReading<'t> = (String, &'t SampleData, Reading);

fn dangling(token: &str, table: &Path) -> String {
    format!("dangling token '{token}' (not in {})", table.display())
}

impl<'t> TableIndex<'t> {
    /// The index, once every camera sensor is known to name a camera channel.
    fn new(tables: &'t Tables) -> Result<Self> {
        let (sensor_path, sensors) = &tables.sensors;
        for sensor in sensors {
            if sensor.modality == "camera" && CameraChannel::from_name(&sensor.channel).is_none() {
                return Err(SensorError::field(
                    sensor_path,
                    format!("sensor {}", sensor.token),
                    "channel",
                    format!(
                        "unknown camera channel '{}' (known: CAM_FRONT, CAM_FRONT_RIGHT, CAM_BACK_RIGHT, CAM_BACK, CAM_BACK_LEFT, CAM_FRONT_LEFT)",
                        sensor.channel
                    ),
                ));
            }
        }
        Ok(Self {
            tables,
            sensors: sensors.iter().map(|s| (s.token.as_str(), s)).collect(),
            calibrated: tables
                .calibrated
                .1
                .iter()
                .map(|c| (c.token.as_str(), c))
                .collect(),
            poses: tables
                .poses
                .1
                .iter()
                .map(|p| (p.token.as_str(), p))
                .collect(),
            samples: tables
                .samples
                .1
                .iter()
                .map(|s| (s.token.as_str(), s))
                .collect(),
        })
    }

    /// One `sample_data` record resolved into a reading with its channel: every token it
    /// names exists, its poses are valid, and a camera's intrinsics are a real camera's.
    fn reading(&self, record: &'t SampleData) -> Result<ChannelReading<'t>> {
        let data_path = &self.tables.sample_data.0;
        let calib_path = &self.tables.calibrated.0;
        let pose_path = &self.tables.poses.0;
        let name = format!("sample_data {}", record.token);
        let calib = self
            .calibrated
            .get(record.calibrated_sensor_token.as_str())
            .ok_or_else(|| {
                SensorError::field(
                    data_path,
                    &name,
                    "calibrated_sensor_token",
                    dangling(&record.calibrated_sensor_token, calib_path),
                )
            })?;
        let sensor = self
            .sensors
            .get(calib.sensor_token.as_str())
            .ok_or_else(|| {
                SensorError::field(
                    calib_path,
                    format!("calibrated_sensor {}", calib.token),
                    "sensor_token",
                    dangling(&calib.sensor_token, &self.tables.sensors.0),
                )
            })?;
        let pose = self
            .poses
            .get(record.ego_pose_token.as_str())
            .ok_or_else(|| {
                SensorError::field(
                    data_path,
                    &name,
                    "ego_pose_token",
                    dangling(&record.ego_pose_token, pose_path),
                )
            })?;
        if !self.samples.contains_key(record.sample_token.as_str()) {
            return Err(SensorError::field(
                data_path,
                &name,
                "sample_token",
                dangling(&record.sample_token, &self.tables.samples.0),
            ));
        }
        let global_from_ego = pose_from_translation_quaternion(pose.translation, pose.rotation)
            .ok_or_else(|| {
                SensorError::field(
                    pose_path,
                    format!("ego_pose {}", pose.token),
                    "rotation",
                    "not a valid rotation quaternion or translation",
                )
            })?;
        let ego_from_sensor = pose_from_translation_quaternion(calib.translation, calib.rotation)
            .ok_or_else(|| {
            SensorError::field(
                calib_path,
                format!("calibrated_sensor {}", calib.token),
                "rotation",
                "not a valid rotation quaternion or translation",
            )
        })?;
        let intrinsics = if sensor.modality == "camera" {
            Some(camera_intrinsics(calib, record, calib_path)?)
        } else {
            None
        };
        Ok((
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
        ))
    }
}

/// A camera's intrinsics: a finite 3x3 matrix with positive focal lengths.
fn camera_intrinsics(
    calib: &CalibratedSensor,
    record: &SampleData,
    calib_path: &Path,
) -> Result<Intrinsics> {
    let rows = &calib.camera_intrinsic;
    if rows.len() != 3
        || rows
            .iter()
            .any(|row| row.len() != 3 || row.iter().any(|v| !v.is_finite()))
    {
        return Err(SensorError::field(
            calib_path,
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
    // A focal length of 0 projects every point onto the principal point, and a negative one
    // mirrors the image: no real camera has either.
    let (fx, fy) = (matrix[0][0], matrix[1][1]);
    if !(fx > 0.0 && fy > 0.0) {
        return Err(SensorError::field(
            calib_path,
            format!("calibrated_sensor {}", calib.token),
            "camera_intrinsic",
            format!("focal lengths fx = {fx}, fy = {fy}: a camera needs both > 0"),
        ));
    }
    Ok(Intrinsics::from_rows(matrix, record.width, record.height))
}

/// The scenes named in `wanted` (all when empty), in table order; a name no scene has is an
/// error listing the scenes.
fn select_scenes<'s>(
    scenes: &'s (PathBuf, Vec<Scene>),
    wanted: &[String],
) -> Result<Vec<&'s Scene>> {
    let (scene_path, scenes) = scenes;
    for name in wanted {
        if !scenes.iter().any(|s| &s.name == name) {
            let known: Vec<&str> = scenes.iter().map(|s| s.name.as_str()).collect();
            return Err(SensorError::file(
                scene_path,
                format!("no scene named '{name}' (scenes: {})", known.join(", ")),
            ));
        }
    }
    Ok(scenes
        .iter()
        .filter(|scene| wanted.is_empty() || wanted.contains(&scene.name))
        .collect())
}

/// The frames of one scene, appended to `frames`: one per LiDAR reading (keyframes, or every
/// sweep), in time order, each with the nearest image of every camera, its keyframe's boxes,
/// and the ego's action into the next frame.
fn scene_frames(
    scene: &Scene,
    keyframes: &[&Sample],
    readings: &[ChannelReading],
    options: &NuScenesOptions,
    data_path: &Path,
    boxes: &mut HashMap<String, Vec<ObjectBox>>,
    frames: &mut Vec<FrameRef>,
) -> Result<()> {
    let scene_samples: std::collections::HashSet<&str> =
        keyframes.iter().map(|s| s.token.as_str()).collect();
    // LiDAR readings that define frames, in time order.
    let mut lidar_readings: Vec<&ChannelReading> = readings
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
            data_path,
            format!("sample_data {}", pair[1].1.token),
            "timestamp",
            format!(
                "timestamps are not strictly increasing within scene '{}' ({} then {})",
                scene.name, pair[0].1.timestamp, pair[1].1.timestamp
            ),
        ));
    }
    let scene_cameras: Vec<&ChannelReading> = readings
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
            let nearest = candidates
                .min_by_key(|(_, record, _)| (record.timestamp - lidar_record.timestamp).abs());
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
            keyframe: lidar_record.is_key_frame,
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
    Ok(())
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
        let tables = Tables::read(&dir)?;
        let mut boxes = super::annotations::boxes_by_sample(&dir, &tables.samples.1)?;
        let index = TableIndex::new(&tables)?;
        let readings = tables
            .sample_data
            .1
            .iter()
            .map(|record| index.reading(record))
            .collect::<Result<Vec<_>>>()?;
        let mut frames = Vec::new();
        for scene in select_scenes(&tables.scenes, &options.scenes)? {
            let keyframes =
                ordered_samples(scene, &tables.samples.1, &index.samples, &tables.samples.0)?;
            scene_frames(
                scene,
                &keyframes,
                &readings,
                &options,
                &tables.sample_data.0,
                &mut boxes,
                &mut frames,
            )?;
        }
        // Normalised where they are used (a zero or non-finite one was refused above); how many
        // needed it is a figure of the run, since a table written by hand often has them.
        let non_unit_quaternions = tables
            .poses
            .1
            .iter()
            .filter(|p| is_non_unit(&p.rotation))
            .count()
            + tables
                .calibrated
                .1
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
            keyframe: frame.keyframe,
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
