//! `export_features`: BEV features for 3D detection and motion heads, one file per frame plus a
//! dataset-level `index.json`.
//!
//! - Files are `<out>/<frame token>.npy` (NumPy, `[C, H, W]` float32) or `.safetensors` (one
//!   tensor named `features`, with the channel meanings, model, weights digest and tokens in
//!   its metadata, so that a file copied away still says what made it). The token becomes a
//!   file name with `safe_file_name`: no token a dataset writes can lead outside `out`.
//! - Writes are atomic. A rerun skips files that exist unless `overwrite` is set, so a killed
//!   run restarted with the same command completes the set without duplicates; temporary files
//!   a kill left behind are removed at start, and only those (a temporary names its writer's
//!   process; a running writer's are left alone).
//! - A file is kept only when an index in the folder says it was made by the same model and
//!   weights as the features now arriving. Made by others, it is refused (naming both digests
//!   and `overwrite`): keeping it would relabel it. Of unknown origin (a run killed before it
//!   wrote its index), it is written again.
//! - At the end the run's entries are merged into the index on disk (keyed by frame token),
//!   under an exclusive lock on `<index>.lock`, and the index is replaced atomically. So shards
//!   (`--shard I/N`) can share one folder and one `index.json`: each adds its frames, none loses
//!   another's. An `index` of its own per shard works too.

use std::collections::BTreeMap;
use std::path::PathBuf;

use bevworld_graph::{
    Figures, Inputs, KindSpec, Node, NodeError, ParamError, Port, Registry, Sink,
};
use bevworld_types::BevFeatures;
use serde::{Deserialize, Serialize};

use crate::npy::npy_f32;
use crate::writes::Writes;

// The node's ports, each named once (`bevworld_graph::Port`).
const FEATURES: Port<BevFeatures> = Port::new("features");

#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ExportFormat {
    #[default]
    Npy,
    Safetensors,
}

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct ExportParams {
    pub out: PathBuf,
    #[serde(default)]
    pub format: ExportFormat,
    /// Rewrite files that already exist (otherwise they are kept and skipped).
    #[serde(default)]
    pub overwrite: bool,
    /// Index file name inside `out`; give each shard its own when shards share a folder.
    #[serde(default = "default_index")]
    pub index: String,
}

fn default_index() -> String {
    "index.json".into()
}

pub struct ExportSink {
    params: ExportParams,
    writes: Writes,
    entries: BTreeMap<String, serde_json::Value>,
    /// What every index in the folder says made each file: file name -> (model, weights).
    provenance: BTreeMap<String, (String, String)>,
    written: u64,
    skipped_existing: u64,
    rewritten_unindexed: u64,
}

fn encode(features: &BevFeatures, format: ExportFormat) -> Result<Vec<u8>, String> {
    let shape = [
        features.channels.len(),
        features.grid.height,
        features.grid.width,
    ];
    match format {
        ExportFormat::Npy => npy_f32(&shape, &features.data),
        ExportFormat::Safetensors => {
            let expected: usize = shape.iter().product();
            if features.data.len() != expected {
                return Err(format!(
                    "array has {} values but shape {shape:?} needs {expected}",
                    features.data.len()
                ));
            }
            let bytes: Vec<u8> = features.data.iter().flat_map(|v| v.to_le_bytes()).collect();
            let view = safetensors::tensor::TensorView::new(
                safetensors::Dtype::F32,
                shape.to_vec(),
                &bytes,
            )
            .map_err(|e| e.to_string())?;
            let metadata = std::collections::HashMap::from([
                ("channels".to_string(), features.channels.join(",")),
                (
                    "sample_token".to_string(),
                    features.meta.sample_token.clone(),
                ),
                ("model".to_string(), features.model.clone()),
                // What made it, in the file itself: a copy taken away from its index.json
                // still says which weights it came from.
                ("weights_hash".to_string(), features.weights_hash.clone()),
                ("frame_token".to_string(), features.meta.frame_token.clone()),
            ]);
            safetensors::tensor::serialize([("features", view)], Some(metadata))
                .map_err(|e| e.to_string())
        }
    }
}

impl Sink for ExportSink {
    fn start(&mut self) -> Result<(), NodeError> {
        let out = &self.params.out;
        std::fs::create_dir_all(out).map_err(|e| {
            NodeError::fatal(format!("{}: cannot create folder: {e}", out.display()))
        })?;
        // A killed run may have left temporary files: they are never valid outputs. Those of a
        // writer still at work (another shard in this folder) are its own business.
        bevworld_graph::io::remove_stale_temporaries(out);
        // Every index in the folder (each shard's, each pass's) says who made its files.
        if let Ok(entries) = std::fs::read_dir(out) {
            for entry in entries.flatten() {
                let path = entry.path();
                if path.extension().is_none_or(|e| e != "json") {
                    continue;
                }
                let Ok(text) = std::fs::read_to_string(&path) else {
                    continue;
                };
                let Ok(index) = serde_json::from_str::<serde_json::Value>(&text) else {
                    continue;
                };
                for frame in index["frames"].as_array().into_iter().flatten() {
                    if let (Some(file), Some(model), Some(hash)) = (
                        frame["file"].as_str(),
                        frame["model"].as_str(),
                        frame["weights_hash"].as_str(),
                    ) {
                        self.provenance
                            .insert(file.to_string(), (model.to_string(), hash.to_string()));
                    }
                }
            }
        }
        // The index this run merges into must be readable: refuse it now, not after the work.
        let index = out.join(&self.params.index);
        if index.exists() {
            let text = std::fs::read_to_string(&index)
                .map_err(|e| NodeError::fatal(format!("{}: cannot read: {e}", index.display())))?;
            serde_json::from_str::<serde_json::Value>(&text).map_err(|e| {
                NodeError::fatal(format!("{}: not a valid index: {e}", index.display()))
            })?;
        }
        Ok(())
    }

    fn consume(&mut self, inputs: &Inputs) -> Result<(), NodeError> {
        let features = inputs.get(&FEATURES)?;
        // Files and index entries are keyed by the frame token: sweeps share a sample token.
        let token = &features.meta.frame_token;
        if token.is_empty() {
            return Err(NodeError::item("features carry no frame token"));
        }
        let extension = match self.params.format {
            ExportFormat::Npy => "npy",
            ExportFormat::Safetensors => "safetensors",
        };
        let file = format!("{}.{extension}", bevworld_graph::io::safe_file_name(token));
        let path = self.params.out.join(&file);
        let made_by = self.provenance.get(&file);
        let same_maker = made_by.is_some_and(|(model, hash)| {
            *model == features.model && *hash == features.weights_hash
        });
        if path.exists()
            && !self.params.overwrite
            && !same_maker
            && let Some((model, hash)) = made_by
        {
            return Err(NodeError::fatal(format!(
                "{}: made by model '{model}' with weights {hash}, but this run exports model '{}' with weights {}: keeping it would relabel it; rerun with --overwrite (or `overwrite: true`) to replace it, or export into another folder",
                path.display(),
                features.model,
                features.weights_hash
            )));
        }
        if path.exists() && !self.params.overwrite && same_maker {
            self.skipped_existing += 1;
        } else {
            if path.exists() && !self.params.overwrite {
                self.rewritten_unindexed += 1;
            }
            let bytes = encode(features, self.params.format)
                .map_err(|e| NodeError::item(format!("{token}: {e}")))?;
            self.writes.write(path, bytes)?;
            self.written += 1;
        }
        let pose = features.meta.global_from_ego;
        let m = glam::DMat4::from(pose);
        let rows: Vec<[f64; 4]> = (0..4)
            .map(|r| [m.col(0)[r], m.col(1)[r], m.col(2)[r], m.col(3)[r]])
            .collect();
        self.entries.insert(
            token.clone(),
            serde_json::json!({
                "frame_token": token,
                "sample_token": features.meta.sample_token,
                "scene": features.meta.scene_name,
                "timestamp_us": features.meta.time_of_validity_us,
                "global_from_ego": rows,
                "file": file,
                "shape": [features.channels.len(), features.grid.height, features.grid.width],
                "dtype": "float32",
                "grid": {"x_range": features.grid.x_range, "y_range": features.grid.y_range, "resolution_m": features.grid.resolution,
                         "frame": "ego", "layout": "[C, H, W], row i = y, column j = x"},
                "channels": features.channels,
                "model": features.model,
                "weights_hash": features.weights_hash,
            }),
        );
        Ok(())
    }

    fn finish(&mut self) -> Result<(), NodeError> {
        self.writes.flush()?;
        // Merged under the index's lock, into what is on disk now: shards sharing one index
        // each add their entries, and none replaces another's.
        let path = self.params.out.join(&self.params.index);
        let format = match self.params.format {
            ExportFormat::Npy => "npy",
            ExportFormat::Safetensors => "safetensors",
        };
        let ours = &self.entries;
        let merged = bevworld_graph::io::update_locked(&path, |current| {
            let mut frames: BTreeMap<String, serde_json::Value> = BTreeMap::new();
            if let Some(bytes) = current {
                let existing: serde_json::Value = serde_json::from_slice(&bytes)
                    .map_err(|e| format!("not a valid index: {e}"))?;
                for entry in existing["frames"].as_array().into_iter().flatten() {
                    if let Some(token) = entry["frame_token"].as_str() {
                        frames.insert(token.to_string(), entry.clone());
                    }
                }
            }
            for (token, entry) in ours {
                frames.insert(token.clone(), entry.clone());
            }
            let frames: Vec<&serde_json::Value> = frames.values().collect();
            serde_json::to_vec_pretty(&serde_json::json!({"format": format, "frames": frames}))
                .map_err(|e| e.to_string())
        });
        match merged {
            Ok(Ok(())) => Ok(()),
            Ok(Err(message)) => Err(NodeError::fatal(format!("{}: {message}", path.display()))),
            Err(e) => Err(NodeError::fatal(format!(
                "{}: index update failed: {e}",
                path.display()
            ))),
        }
    }

    fn report(&self) -> Figures {
        Figures::from([
            ("files_written".to_string(), self.written as f64),
            ("skipped_existing".to_string(), self.skipped_existing as f64),
            (
                "rewritten_unindexed".to_string(),
                self.rewritten_unindexed as f64,
            ),
        ])
    }
}

pub fn register(registry: &mut Registry) {
    registry.register_checked(
        KindSpec::sink("export_features", "writes BEV features per frame (.npy or .safetensors) with a dataset index.json; resumable")
            .input(FEATURES.spec()),
        |params: &ExportParams| {
            if params.out.as_os_str().is_empty() {
                return Err(ParamError::field("out", "is empty").with_accepted("an output folder"));
            }
            if params.index.is_empty() || params.index.contains('/') || !params.index.ends_with(".json") {
                return Err(ParamError::field("index", format!("'{}' is not a .json file name", params.index)).with_accepted("a file name ending in .json"));
            }
            Ok(())
        },
        |params: ExportParams| {
            let writes = Writes::new(params.out.clone(), 8);
            Ok(Node::Sink(Box::new(ExportSink { params, writes, entries: BTreeMap::new(), provenance: BTreeMap::new(), written: 0, skipped_existing: 0, rewritten_unindexed: 0 })))
        },
    );
}
