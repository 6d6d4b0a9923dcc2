//! The nuScenes tables this project reads, as in the official schema. The synthetic world
//! writes the same tables, so one reader serves both.

use std::path::{Path, PathBuf};

use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};

use crate::error::{Result, SensorError};

#[derive(Clone, Debug, Deserialize, Serialize)]
pub struct Scene {
    pub token: String,
    pub log_token: String,
    pub nbr_samples: usize,
    pub name: String,
    pub description: String,
    pub first_sample_token: String,
    pub last_sample_token: String,
}

#[derive(Clone, Debug, Deserialize, Serialize)]
pub struct Sample {
    pub token: String,
    pub timestamp: i64,
    pub scene_token: String,
    pub prev: String,
    pub next: String,
}

#[derive(Clone, Debug, Deserialize, Serialize)]
pub struct SampleData {
    pub token: String,
    pub sample_token: String,
    pub ego_pose_token: String,
    pub calibrated_sensor_token: String,
    pub timestamp: i64,
    pub fileformat: String,
    pub is_key_frame: bool,
    pub height: u32,
    pub width: u32,
    pub filename: String,
    pub prev: String,
    pub next: String,
}

#[derive(Clone, Debug, Deserialize, Serialize)]
pub struct CalibratedSensor {
    pub token: String,
    pub sensor_token: String,
    pub translation: [f64; 3],
    /// [w, x, y, z]
    pub rotation: [f64; 4],
    /// 3x3 row-major for cameras, empty for other sensors.
    pub camera_intrinsic: Vec<Vec<f64>>,
}

#[derive(Clone, Debug, Deserialize, Serialize)]
pub struct Sensor {
    pub token: String,
    pub channel: String,
    pub modality: String,
}

#[derive(Clone, Debug, Deserialize, Serialize)]
pub struct EgoPose {
    pub token: String,
    pub timestamp: i64,
    /// [w, x, y, z]
    pub rotation: [f64; 4],
    pub translation: [f64; 3],
}

#[derive(Clone, Debug, Deserialize, Serialize)]
pub struct Log {
    pub token: String,
    pub logfile: String,
    pub vehicle: String,
    pub date_captured: String,
    pub location: String,
}

/// An annotated 3D box (the synthetic world writes its agents here).
#[derive(Clone, Debug, Deserialize, Serialize)]
pub struct SampleAnnotation {
    pub token: String,
    pub sample_token: String,
    pub instance_token: String,
    #[serde(default)]
    pub visibility_token: String,
    #[serde(default)]
    pub attribute_tokens: Vec<String>,
    pub translation: [f64; 3],
    /// width, length, height
    pub size: [f64; 3],
    /// [w, x, y, z]
    pub rotation: [f64; 4],
    pub prev: String,
    pub next: String,
    #[serde(default)]
    pub num_lidar_pts: i64,
    #[serde(default)]
    pub num_radar_pts: i64,
}

/// An object across keyframes: its category.
#[derive(Clone, Debug, Deserialize, Serialize)]
pub struct Instance {
    pub token: String,
    pub category_token: String,
}

/// An attribute an annotation may carry, e.g. `vehicle.parked`.
#[derive(Clone, Debug, Deserialize, Serialize)]
pub struct Attribute {
    pub token: String,
    pub name: String,
}

/// A category of objects, e.g. `vehicle.car`.
#[derive(Clone, Debug, Deserialize, Serialize)]
pub struct Category {
    pub token: String,
    pub name: String,
}

/// Reads one table, naming the file in every error.
pub fn read_table<T: DeserializeOwned>(
    dir: &Path,
    table: &'static str,
) -> Result<(PathBuf, Vec<T>)> {
    let path = dir.join(format!("{table}.json"));
    let bytes = std::fs::read(&path).map_err(|error| SensorError::io(&path, error))?;
    let rows = serde_json::from_slice::<Vec<T>>(&bytes).map_err(|error| SensorError::Table {
        path: path.clone(),
        table,
        message: error.to_string(),
    })?;
    Ok((path, rows))
}
