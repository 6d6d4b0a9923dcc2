//! Reading what `export_features` wrote: the index's entries (each frame's tokens, scene,
//! time, ego pose, file, shape and the model and weights digest that made it) and each
//! frame's array. The one reader of the export for every consumer (the world model's latent
//! caches, the detector's features), so the format has one home on each side.

use std::path::{Path, PathBuf};

use bevworld_types::{BevGrid, Pose};
use glam::{DMat4, DVec4};
use serde::Deserialize;

use crate::npy::read_npy_f32;

#[derive(Debug, thiserror::Error)]
pub enum ExportIndexError {
    #[error("{path}: {message}")]
    Io { path: PathBuf, message: String },
    #[error("{path}: the array holds {count} non-finite values (NaN or Inf)")]
    NonFinite { path: PathBuf, count: usize },
}

#[derive(Deserialize)]
struct IndexFile {
    frames: Vec<ExportEntry>,
}

/// One frame of an export index.
#[derive(Clone, Debug, Deserialize)]
pub struct ExportEntry {
    pub frame_token: String,
    #[serde(default)]
    pub sample_token: String,
    pub scene: String,
    pub timestamp_us: i64,
    /// Row-major 4 × 4.
    pub global_from_ego: [[f64; 4]; 4],
    /// Relative to the index's folder.
    pub file: String,
    /// `[C, H, W]`.
    pub shape: Vec<usize>,
    pub model: String,
    pub weights_hash: String,
    /// The extent the array covers (absent in indexes of other exporters).
    #[serde(default)]
    pub grid: Option<ExportGrid>,
}

/// The index's description of a frame's grid.
#[derive(Clone, Copy, Debug, Deserialize)]
pub struct ExportGrid {
    pub x_range: [f32; 2],
    pub y_range: [f32; 2],
    pub resolution_m: f32,
}

impl ExportEntry {
    /// The grid of the array, when the index describes it and its shape is `[C, H, W]`.
    pub fn bev_grid(&self) -> Option<BevGrid> {
        let grid = self.grid?;
        let [_, height, width] = self.shape[..] else {
            return None;
        };
        Some(BevGrid {
            x_range: grid.x_range,
            y_range: grid.y_range,
            resolution: grid.resolution_m,
            height,
            width,
        })
    }

    pub fn global_from_ego(&self) -> Pose {
        let rows = self.global_from_ego;
        Pose::from_mat4(DMat4::from_cols(
            DVec4::new(rows[0][0], rows[1][0], rows[2][0], rows[3][0]),
            DVec4::new(rows[0][1], rows[1][1], rows[2][1], rows[3][1]),
            DVec4::new(rows[0][2], rows[1][2], rows[2][2], rows[3][2]),
            DVec4::new(rows[0][3], rows[1][3], rows[2][3], rows[3][3]),
        ))
    }

    /// The frame's array, read from `dir` (the index's folder): its shape must be the
    /// entry's, and every value finite.
    pub fn read_values(&self, dir: &Path) -> Result<Vec<f32>, ExportIndexError> {
        let path = dir.join(&self.file);
        let error = |message: String| ExportIndexError::Io {
            path: path.clone(),
            message,
        };
        let bytes = std::fs::read(&path).map_err(|e| error(e.to_string()))?;
        let (shape, values) = read_npy_f32(&bytes).map_err(error)?;
        if shape != self.shape {
            return Err(error(format!(
                "array of shape {shape:?}, but the index says {:?}",
                self.shape
            )));
        }
        let count = values.iter().filter(|v| !v.is_finite()).count();
        if count > 0 {
            return Err(ExportIndexError::NonFinite { path, count });
        }
        Ok(values)
    }
}

/// The entries of `dir/index`, in the index's order (by frame token).
pub fn read_export_index(dir: &Path, index: &str) -> Result<Vec<ExportEntry>, ExportIndexError> {
    let path = dir.join(index);
    let error = |message: String| ExportIndexError::Io {
        path: path.clone(),
        message,
    };
    let text = std::fs::read_to_string(&path)
        .map_err(|e| error(format!("cannot read the export's index: {e}")))?;
    let file: IndexFile =
        serde_json::from_str(&text).map_err(|e| error(format!("not an export index: {e}")))?;
    Ok(file.frames)
}
