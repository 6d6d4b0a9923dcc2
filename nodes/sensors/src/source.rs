//! The `dataset_source` node: replays a dataset (nuScenes, KITTI odometry or our synthetic
//! world) as `SensorFrame`s. While one frame is decoded, the next frame's files are already
//! being read on the I/O pool.

use std::path::{Component, Path, PathBuf};
use std::sync::Arc;

use bevworld_graph::io::{spawn_io, wait};
use bevworld_graph::{
    Figures, KindSpec, Node, NodeError, Outputs, ParamError, Port, Registry, Source, SourceInfo,
};
use bevworld_types::{ImageSet, PointCloud, SensorFrame};
use serde::{Deserialize, Serialize};
use tokio::task::JoinHandle;

use crate::dataset::{Dataset, DatasetFormat, DatasetOptions, FetchedFrame};
use crate::lidar_file::NonFinitePolicy;

// The node's ports, each named once (`bevworld_graph::Port`).
const FRAME: Port<SensorFrame> = Port::new("frame");
const IMAGES: Port<ImageSet> = Port::new("images");
const LIDAR: Port<PointCloud> = Port::new("lidar");

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct DatasetSourceParams {
    /// Dataset root folder.
    pub data: PathBuf,
    /// `auto` recognises the layout from the folder.
    #[serde(default)]
    pub format: DatasetFormat,
    /// nuScenes table folder (`v1.0-mini`, `v1.0-synth`); found automatically when unique.
    #[serde(default)]
    pub version: Option<String>,
    /// Scene names to replay; empty = all.
    #[serde(default)]
    pub scenes: Vec<String>,
    /// Every LiDAR sweep instead of keyframes only (nuScenes layout).
    #[serde(default)]
    pub sweeps: bool,
    /// `drop` (count) or `error` on NaN/Inf points.
    #[serde(default)]
    pub non_finite: NonFinitePolicy,
    /// Do not decode camera images.
    #[serde(default)]
    pub skip_images: bool,
    /// First frame to emit.
    #[serde(default)]
    pub start: usize,
    /// Stop after this many frames.
    #[serde(default)]
    pub max_frames: Option<usize>,
    /// Replay the selected frames this many times (soak tests, benchmarks on one real frame).
    #[serde(default = "one")]
    pub repeat: usize,
    /// Shard `i/n`: only scenes whose position in the dataset is i mod n.
    #[serde(default)]
    pub shard: Option<String>,
    /// A synthetic dataset to make at `generate.dir` when that folder does not exist. It applies
    /// only while `data` names that folder: pointed elsewhere (`--set source.data=DIR`), a
    /// missing `data` is an error, never a fabricated dataset.
    #[serde(default)]
    pub generate: Option<GenerateParams>,
}

/// A synthetic dataset to make on the fly (see `bevworld synth`).
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct GenerateParams {
    /// The folder this block makes; the source generates only when `data` is this folder.
    pub dir: PathBuf,
    #[serde(default)]
    pub seed: u64,
    #[serde(default = "one")]
    pub scenes: usize,
    #[serde(default = "four")]
    pub seconds: f64,
    /// Camera image size `WxH`.
    #[serde(default = "default_size")]
    pub camera_size: String,
    /// Pedestrians and cyclists per scene.
    #[serde(default)]
    pub pedestrians: usize,
    #[serde(default)]
    pub cyclists: usize,
}

fn one() -> usize {
    1
}

fn four() -> f64 {
    4.0
}

fn default_size() -> String {
    "400x224".into()
}

/// Parses `WxH`.
pub fn parse_size(text: &str) -> Result<(u32, u32), SizeError> {
    let (w, h) = text
        .split_once(['x', 'X'])
        .ok_or_else(|| SizeError::Form(text.to_string()))?;
    let w: u32 = w
        .trim()
        .parse()
        .map_err(|_| SizeError::Width(w.to_string()))?;
    let h: u32 = h
        .trim()
        .parse()
        .map_err(|_| SizeError::Height(h.to_string()))?;
    if w < 16 || h < 16 || w > 8192 || h > 8192 {
        return Err(SizeError::Range(w, h));
    }
    Ok((w, h))
}

/// A `WxH` size that cannot be used.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum SizeError {
    #[error("'{0}' is not WxH")]
    Form(String),
    #[error("'{0}' is not a width")]
    Width(String),
    #[error("'{0}' is not a height")]
    Height(String),
    #[error("{0}x{1} is outside 16..8192")]
    Range(u32, u32),
}

/// An `I/N` shard that cannot be used.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum ShardError {
    #[error("'{0}' is not I/N")]
    Form(String),
    #[error("'{0}' is not a shard index")]
    Index(String),
    #[error("'{0}' is not a shard count")]
    Count(String),
    #[error("shard {0}/{1} needs 0 <= I < N")]
    Range(usize, usize),
}

pub struct DatasetSource {
    params: DatasetSourceParams,
    dataset: Option<Arc<Dataset>>,
    indices: Vec<usize>,
    cursor: usize,
    prefetch: Option<(usize, JoinHandle<crate::error::Result<FetchedFrame>>)>,
    /// NaN or infinite LiDAR points dropped from the frames emitted (`non_finite: drop`).
    non_finite_points_dropped: u64,
}

impl DatasetSourceParams {
    /// The parameters' own consistency, found without opening the dataset.
    pub fn check(params: &Self) -> Result<(), ParamError> {
        if let Some(shard) = &params.shard {
            parse_shard(shard).map_err(|error| {
                ParamError::field("shard", error.to_string()).with_accepted("I/N with 0 <= I < N")
            })?;
        }
        if params.repeat == 0 {
            return Err(
                ParamError::field("repeat", "must be at least 1").with_accepted("an integer >= 1")
            );
        }
        if params.data.as_os_str().is_empty() {
            return Err(ParamError::field("data", "is empty").with_accepted("a dataset folder"));
        }
        if let Some(generate) = &params.generate {
            if generate.dir.as_os_str().is_empty() {
                return Err(ParamError::field("generate", "dir is empty")
                    .with_accepted("dir: the folder to make, e.g. out/synth-demo"));
            }
            parse_size(&generate.camera_size).map_err(|error| {
                ParamError::field("generate", error.to_string())
                    .with_accepted("camera_size: WxH, e.g. 400x224")
            })?;
            if !(generate.seconds > 0.0 && generate.seconds <= 600.0) || generate.scenes == 0 {
                return Err(ParamError::field(
                    "generate",
                    "needs scenes >= 1 and 0 < seconds <= 600",
                ));
            }
        }
        Ok(())
    }
}

impl DatasetSource {
    pub fn new(params: DatasetSourceParams) -> Result<Self, ParamError> {
        DatasetSourceParams::check(&params)?;
        Ok(Self {
            params,
            dataset: None,
            indices: Vec::new(),
            cursor: 0,
            prefetch: None,
            non_finite_points_dropped: 0,
        })
    }

    fn generate(&self, generate: &GenerateParams) -> Result<(), NodeError> {
        let (camera_width, camera_height) =
            parse_size(&generate.camera_size).map_err(|e| NodeError::fatal_from(&e))?;
        let config = crate::synth::SynthConfig {
            seed: generate.seed,
            scenes: generate.scenes,
            seconds: generate.seconds,
            camera_width,
            camera_height,
            pedestrians: generate.pedestrians,
            cyclists: generate.cyclists,
            ..Default::default()
        };
        tracing::info!(
            "generating synthetic dataset in {}",
            self.params.data.display()
        );
        crate::synth::generate_in_place(&self.params.data, &config, |_, _| {})
            .map_err(|e| NodeError::fatal_from(&e))?;
        Ok(())
    }

    fn start_prefetch(&mut self) {
        let (Some(dataset), Some(&index)) = (&self.dataset, self.indices.get(self.cursor)) else {
            return;
        };
        let dataset = Arc::clone(dataset);
        if let Ok(handle) = spawn_io(move || dataset.fetch(index)) {
            self.prefetch = Some((index, handle));
        }
    }
}

/// Whether two paths name one folder, read lexically (`./out/a/` and `out/a` do): the folder may
/// not exist yet, so it cannot be canonicalised.
fn same_folder(a: &Path, b: &Path) -> bool {
    fn parts(p: &Path) -> impl Iterator<Item = Component<'_>> {
        p.components().filter(|c| !matches!(c, Component::CurDir))
    }
    parts(a).eq(parts(b))
}

/// Parses `i/n`.
pub fn parse_shard(text: &str) -> Result<(usize, usize), ShardError> {
    let (i, n) = text
        .split_once('/')
        .ok_or_else(|| ShardError::Form(text.to_string()))?;
    let i: usize = i
        .trim()
        .parse()
        .map_err(|_| ShardError::Index(i.to_string()))?;
    let n: usize = n
        .trim()
        .parse()
        .map_err(|_| ShardError::Count(n.to_string()))?;
    if n == 0 || i >= n {
        return Err(ShardError::Range(i, n));
    }
    Ok((i, n))
}

impl Source for DatasetSource {
    fn start(&mut self) -> Result<SourceInfo, NodeError> {
        if !self.params.data.exists()
            && let Some(generate) = &self.params.generate
        {
            if !same_folder(&generate.dir, &self.params.data) {
                return Err(NodeError::fatal(format!(
                    "{}: dataset folder does not exist (the graph's `generate` block makes \
                         {}, not this folder)",
                    self.params.data.display(),
                    generate.dir.display()
                )));
            }
            self.generate(generate)?;
        }
        let options = DatasetOptions {
            format: self.params.format,
            version: self.params.version.clone(),
            scenes: self.params.scenes.clone(),
            sweeps: self.params.sweeps,
            non_finite: self.params.non_finite,
            skip_images: self.params.skip_images,
        };
        let dataset =
            Dataset::open(&self.params.data, &options).map_err(|e| NodeError::fatal_from(&e))?;
        let shard = self
            .params
            .shard
            .as_deref()
            .map(parse_shard)
            .transpose()
            .map_err(|e| NodeError::fatal_from(&e))?;
        let scene_names = dataset.scene_names();
        let mut scene_order: Vec<&str> = Vec::new();
        for name in &scene_names {
            if !scene_order.contains(name) {
                scene_order.push(name);
            }
        }
        let mut indices: Vec<usize> = (0..dataset.len())
            .filter(|&i| match shard {
                Some((k, n)) => scene_order
                    .iter()
                    .position(|s| *s == scene_names[i])
                    .is_some_and(|p| p % n == k),
                None => true,
            })
            .skip(self.params.start)
            .collect();
        if let Some(max) = self.params.max_frames {
            indices.truncate(max);
        }
        let once = indices.clone();
        for _ in 1..self.params.repeat {
            indices.extend_from_slice(&once);
        }
        let total = indices.len() as u64;
        self.indices = indices;
        self.dataset = Some(Arc::new(dataset));
        self.start_prefetch();
        Ok(SourceInfo { total: Some(total) })
    }

    fn next(&mut self, out: &mut Outputs) -> Result<Option<i64>, NodeError> {
        let Some(dataset) = self.dataset.clone() else {
            return Ok(None);
        };
        let Some(&index) = self.indices.get(self.cursor) else {
            return Ok(None);
        };
        self.cursor += 1;
        let fetched = match self.prefetch.take() {
            Some((prefetched, handle)) if prefetched == index => {
                wait(handle).map_err(|e| NodeError::fatal_from(&e))?
            }
            _ => dataset.fetch(index),
        };
        // Read the next frame's files while this one decodes.
        self.start_prefetch();
        let frame: SensorFrame = dataset
            .decode(fetched.map_err(|e| NodeError::item_from(&e))?)
            .map_err(|e| NodeError::item_from(&e))?;
        self.non_finite_points_dropped += frame.lidar.dropped_non_finite as u64;
        let time_of_validity = frame.time_of_validity_us;
        out.set_time_of_validity(time_of_validity);
        if out.is_connected(&IMAGES) {
            out.send(&IMAGES, frame.image_set())?;
        }
        if out.is_connected(&LIDAR) {
            out.send_shared(&LIDAR, Arc::clone(&frame.lidar))?;
        }
        out.send(&FRAME, frame)?;
        Ok(Some(time_of_validity))
    }

    fn report(&self) -> Figures {
        let mut figures = Figures::new();
        figures.insert(
            "non_finite_points_dropped".into(),
            self.non_finite_points_dropped as f64,
        );
        if let Some(dataset) = &self.dataset {
            figures.insert(
                "non_unit_quaternions_normalised".into(),
                dataset.non_unit_quaternions() as f64,
            );
        }
        figures
    }
}

pub fn register(registry: &mut Registry) {
    registry.register_checked(
        KindSpec::source(
            "dataset_source",
            "replays a nuScenes-layout, synthetic or KITTI odometry dataset as sensor frames",
        )
        .output(FRAME.spec())
        .output(IMAGES.spec())
        .output(LIDAR.spec()),
        DatasetSourceParams::check,
        |params: DatasetSourceParams| Ok(Node::Source(Box::new(DatasetSource::new(params)?))),
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shard_and_size_parsing() {
        assert_eq!(parse_shard("1/4"), Ok((1, 4)));
        assert!(
            parse_shard("4/4")
                .unwrap_err()
                .to_string()
                .contains("0 <= I < N")
        );
        assert!(
            parse_shard("a/4").is_err() && parse_shard("3").is_err() && parse_shard("0/0").is_err()
        );
        assert_eq!(parse_size("400x224"), Ok((400, 224)));
        assert!(
            parse_size("400").is_err() && parse_size("8x8").is_err() && parse_size("ax2").is_err()
        );
    }

    #[test]
    fn bad_source_parameters_are_refused() {
        let mut registry = Registry::new();
        register(&mut registry);
        let kind = registry.get("dataset_source").unwrap();
        let field = |params: serde_json::Value| kind.build(&params).err().and_then(|e| e.field);
        assert_eq!(
            field(serde_json::json!({"data": "d", "repeat": 0})).as_deref(),
            Some("repeat")
        );
        assert_eq!(
            field(serde_json::json!({"data": "d", "shard": "2/2"})).as_deref(),
            Some("shard")
        );
        for generate in [
            serde_json::json!({"dir": "d", "camera_size": "big"}),
            serde_json::json!({"dir": "", "seed": 1}),
            serde_json::json!({"seed": 1}),
            serde_json::json!({"dir": "d", "scenes": 0}),
        ] {
            let error = kind
                .build(&serde_json::json!({"data": "d", "generate": generate}))
                .err()
                .unwrap_or_else(|| panic!("{generate} is refused"));
            assert_eq!(
                error.field.as_deref(),
                Some("generate"),
                "{generate}: {error:?}"
            );
        }
        assert_eq!(
            field(serde_json::json!({"data": "d", "format": "waymo"})).as_deref(),
            Some("format")
        );
        assert_eq!(field(serde_json::json!({})).as_deref(), Some("data"));
    }
}
