//! One front for every dataset layout, so nodes and tools need not care which it is.

use std::path::Path;

use bevworld_types::SensorFrame;
use serde::{Deserialize, Serialize};

use crate::error::{Result, SensorError};
use crate::kitti::Kitti;
use crate::lidar_file::NonFinitePolicy;
use crate::nuscenes::reader::FrameFiles;
use crate::nuscenes::{NuScenes, NuScenesOptions};

#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DatasetFormat {
    /// Recognised from the folder: `v1.0-*/sample_data.json` is nuScenes (synthetic included),
    /// `velodyne/` with `poses.txt` is KITTI odometry.
    #[default]
    Auto,
    Nuscenes,
    /// Our synthetic world: the nuScenes layout with version `v1.0-synth`.
    Synth,
    Kitti,
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
    Kitti(Kitti),
}

/// A frame's files, read and not yet decoded.
pub enum FetchedFrame {
    NuScenes(FrameFiles),
    Kitti((usize, Vec<u8>)),
}

impl Dataset {
    pub fn open(root: &Path, options: &DatasetOptions) -> Result<Self> {
        if !root.exists() {
            return Err(SensorError::file(root, "dataset folder does not exist"));
        }
        let nuscenes = |version: Option<String>| {
            NuScenes::open(
                root,
                NuScenesOptions {
                    version,
                    scenes: options.scenes.clone(),
                    sweeps: options.sweeps,
                    non_finite: options.non_finite,
                    skip_images: options.skip_images,
                },
            )
            .map(Dataset::NuScenes)
        };
        match options.format {
            DatasetFormat::Nuscenes => nuscenes(options.version.clone()),
            DatasetFormat::Synth => nuscenes(Some(
                options
                    .version
                    .clone()
                    .unwrap_or_else(|| crate::synth::VERSION.to_string()),
            )),
            DatasetFormat::Kitti => Kitti::open(root, options.non_finite).map(Dataset::Kitti),
            DatasetFormat::Auto if Kitti::recognise(root) => {
                Kitti::open(root, options.non_finite).map(Dataset::Kitti)
            }
            DatasetFormat::Auto => nuscenes(options.version.clone()).map_err(|error| {
                // Say what each layout would need, not only what the nuScenes reader missed.
                if root.join("velodyne").is_dir() && !Kitti::recognise(root) {
                    SensorError::file(
                        root,
                        format!(
                            "has velodyne/ but no poses.txt, so it is not a KITTI odometry sequence (velodyne/*.bin, poses.txt, calib.txt); read as nuScenes instead: {error}"
                        ),
                    )
                } else {
                    error
                }
            }),
        }
    }

    pub fn len(&self) -> usize {
        match self {
            Dataset::NuScenes(d) => d.len(),
            Dataset::Kitti(d) => d.len(),
        }
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Pose rotations that were not unit quaternions and were normalised (KITTI's poses are
    /// matrices: none).
    pub fn non_unit_quaternions(&self) -> usize {
        match self {
            Dataset::NuScenes(d) => d.non_unit_quaternions(),
            Dataset::Kitti(_) => 0,
        }
    }

    /// The frame of a nuScenes sample token.
    pub fn index_of_sample(&self, token: &str) -> Option<usize> {
        match self {
            Dataset::NuScenes(d) => d.index_of_sample(token),
            Dataset::Kitti(d) => {
                (0..d.len()).find(|i| format!("{}/{:06}", d.sequence(), i) == token)
            }
        }
    }

    pub fn scene_names(&self) -> Vec<&str> {
        match self {
            Dataset::NuScenes(d) => d.scene_names(),
            Dataset::Kitti(d) => vec![d.sequence(); d.len()],
        }
    }

    pub fn fetch(&self, index: usize) -> Result<FetchedFrame> {
        match self {
            Dataset::NuScenes(d) => d.fetch(index).map(FetchedFrame::NuScenes),
            Dataset::Kitti(d) => d.fetch(index).map(FetchedFrame::Kitti),
        }
    }

    pub fn decode(&self, fetched: FetchedFrame) -> Result<SensorFrame> {
        match (self, fetched) {
            (Dataset::NuScenes(d), FetchedFrame::NuScenes(files)) => d.decode(files),
            (Dataset::Kitti(d), FetchedFrame::Kitti(files)) => d.decode(files),
            _ => Err(SensorError::Other(
                "fetched files belong to another dataset".into(),
            )),
        }
    }

    pub fn read(&self, index: usize) -> Result<SensorFrame> {
        self.decode(self.fetch(index)?)
    }
}
