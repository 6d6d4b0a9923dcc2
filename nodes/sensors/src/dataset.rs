//! One front for every dataset layout, so nodes and tools need not care which it is.

use std::path::Path;

use bevworld_types::SensorFrame;
use serde::{Deserialize, Serialize};

use crate::error::{Result, SensorError};
use crate::lidar_file::NonFinitePolicy;
use crate::nuscenes::reader::FrameFiles;
use crate::nuscenes::{NuScenes, NuScenesOptions};

#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DatasetFormat {
    /// nuScenes layout (a folder with `v1.0-*/sample_data.json`).
    #[default]
    Auto,
    Nuscenes,
}

#[derive(Clone, Debug, Default)]
pub struct DatasetOptions {
    pub format: DatasetFormat,
    pub version: Option<String>,
    pub scenes: Vec<String>,
    pub sweeps: bool,
    pub non_finite: NonFinitePolicy,
    pub skip_images: bool,
}

pub enum Dataset {
    NuScenes(NuScenes),
}

/// A frame's files, read and not yet decoded.
pub enum FetchedFrame {
    NuScenes(FrameFiles),
}

impl Dataset {
    pub fn open(root: &Path, options: &DatasetOptions) -> Result<Self> {
        if !root.exists() {
            return Err(SensorError::file(root, "dataset folder does not exist"));
        }
        let nuscenes = || {
            NuScenes::open(root, NuScenesOptions {
                version: options.version.clone(),
                scenes: options.scenes.clone(),
                sweeps: options.sweeps,
                non_finite: options.non_finite,
                skip_images: options.skip_images,
            })
            .map(Dataset::NuScenes)
        };
        match options.format {
            DatasetFormat::Nuscenes | DatasetFormat::Auto => nuscenes(),
        }
    }

    pub fn len(&self) -> usize {
        match self {
            Dataset::NuScenes(d) => d.len(),
        }
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    pub fn scene_names(&self) -> Vec<&str> {
        match self {
            Dataset::NuScenes(d) => d.scene_names(),
        }
    }

    pub fn fetch(&self, index: usize) -> Result<FetchedFrame> {
        match self {
            Dataset::NuScenes(d) => d.fetch(index).map(FetchedFrame::NuScenes),
        }
    }

    pub fn decode(&self, fetched: FetchedFrame) -> Result<SensorFrame> {
        match (self, fetched) {
            (Dataset::NuScenes(d), FetchedFrame::NuScenes(files)) => d.decode(files),
        }
    }

    pub fn read(&self, index: usize) -> Result<SensorFrame> {
        self.decode(self.fetch(index)?)
    }
}
