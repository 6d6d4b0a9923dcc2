//! Latent sequences to learn from, read from `export_features` folders: the same `.npy` files
//! and `index.json` a user exports, so nothing is written twice.
//!
//! - Every entry must come from the expected tokenizer (model name and weights digest) and
//!   have the model's latent shape; a latent with a non-finite value is refused, naming its
//!   file.
//! - Frames are grouped by scene and ordered by time. A scene is split wherever two frames are
//!   further apart than `gap_factor` times its usual interval: a forecast is never stitched
//!   across a gap.
//! - Latents are standardised per channel with the tokenizer's statistics on load.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use bevworld_sinks::export_index::{ExportIndexError, read_export_index};
use bevworld_types::{EgoAction, LatentStats, Pose};

#[derive(Debug, thiserror::Error)]
pub enum DataError {
    #[error("{path}: {message}")]
    Io { path: PathBuf, message: String },
    /// `found` and `expected` read "'model' with weights HASH".
    #[error(
        "{path}: frame {token} was encoded by {found}, but training expects {expected}; re-export the cache with those weights"
    )]
    OtherWeights {
        path: PathBuf,
        token: String,
        found: String,
        expected: String,
    },
    #[error("{path}: latent of shape {found:?}, but the world model config expects {expected:?}")]
    Shape {
        path: PathBuf,
        found: Vec<usize>,
        expected: [usize; 3],
    },
    #[error("{path}: the latent holds {count} non-finite values (NaN or Inf)")]
    NonFinite { path: PathBuf, count: usize },
    #[error(
        "{path}: scene '{scene}' has two frames at time {time_us} µs ({first} and {second}); a sequence needs strictly increasing times"
    )]
    DuplicateTime {
        path: PathBuf,
        scene: String,
        time_us: i64,
        first: String,
        second: String,
    },
    #[error("{path}: no frames")]
    Empty { path: PathBuf },
}

impl From<ExportIndexError> for DataError {
    fn from(error: ExportIndexError) -> Self {
        match error {
            ExportIndexError::Io { path, message } => DataError::Io { path, message },
            ExportIndexError::NonFinite { path, count } => DataError::NonFinite { path, count },
        }
    }
}

/// One frame of a sequence.
#[derive(Clone, Debug)]
pub struct LatentFrame {
    pub token: String,
    pub time_us: i64,
    pub global_from_ego: Pose,
    /// Standardised `[C, H, W]`.
    pub latent: Vec<f32>,
}

/// Frames of one scene without a gap, in time order.
#[derive(Clone, Debug)]
pub struct Sequence {
    pub scene: String,
    pub frames: Vec<LatentFrame>,
}

impl Sequence {
    /// The action into frame `k` (from frame `k − 1`), `None` for the first frame.
    pub fn action_into(&self, k: usize) -> Option<EgoAction> {
        let (a, b) = (self.frames.get(k.checked_sub(1)?)?, self.frames.get(k)?);
        EgoAction::between(&a.global_from_ego, a.time_us, &b.global_from_ego, b.time_us)
    }
}

/// What the cache must have been made with.
#[derive(Clone, Debug)]
pub struct Expected {
    pub model: String,
    pub weights_hash: String,
    /// `[C, H, W]`.
    pub shape: [usize; 3],
    pub stats: LatentStats,
    /// A scene is split where consecutive frames are more than this many usual intervals
    /// apart.
    pub gap_factor: f64,
}

#[derive(Clone, Debug)]
pub struct LatentSequences {
    pub sequences: Vec<Sequence>,
    /// Places where a scene was split at a time gap.
    pub gaps: usize,
}

impl LatentSequences {
    pub fn frames(&self) -> usize {
        self.sequences.iter().map(|s| s.frames.len()).sum()
    }

    /// Every action between consecutive frames.
    pub fn actions(&self) -> Vec<EgoAction> {
        self.sequences
            .iter()
            .flat_map(|s| (1..s.frames.len()).filter_map(move |k| s.action_into(k)))
            .collect()
    }

    /// Every `stride`-th frame: each sequence becomes `stride` interleaved ones (offsets 0 to
    /// `stride − 1`), so that a window of consecutive frames may start at any frame.
    pub fn strided(&self, stride: usize) -> LatentSequences {
        let stride = stride.max(1);
        let sequences = self
            .sequences
            .iter()
            .flat_map(|sequence| {
                (0..stride.min(sequence.frames.len())).map(move |offset| Sequence {
                    scene: sequence.scene.clone(),
                    frames: sequence.frames[offset..]
                        .iter()
                        .step_by(stride)
                        .cloned()
                        .collect(),
                })
            })
            .collect();
        LatentSequences {
            sequences,
            gaps: self.gaps,
        }
    }

    /// These sequences followed by `other`'s.
    pub fn joined(&self, other: &LatentSequences) -> LatentSequences {
        LatentSequences {
            sequences: self
                .sequences
                .iter()
                .chain(&other.sequences)
                .cloned()
                .collect(),
            gaps: self.gaps + other.gaps,
        }
    }

    /// Windows of `frames` consecutive frames that also have the frame before them (for the
    /// first frame's action): `(sequence, first frame)`.
    pub fn windows(&self, frames: usize) -> Vec<(usize, usize)> {
        self.sequences
            .iter()
            .enumerate()
            .flat_map(|(s, sequence)| {
                let last = sequence.frames.len().saturating_sub(frames);
                (1..=last).map(move |start| (s, start))
            })
            .collect()
    }
}

/// Reads the frames `dir/index` lists and splits them into gap-free sequences.
pub fn load_sequences(
    dir: &Path,
    index: &str,
    expected: &Expected,
) -> Result<LatentSequences, DataError> {
    let index_path = dir.join(index);
    let frames = read_export_index(dir, index).map_err(DataError::from)?;
    if frames.is_empty() {
        return Err(DataError::Empty { path: index_path });
    }
    let mut scenes: BTreeMap<String, Vec<LatentFrame>> = BTreeMap::new();
    for entry in frames {
        let path = dir.join(&entry.file);
        if entry.model != expected.model || entry.weights_hash != expected.weights_hash {
            return Err(DataError::OtherWeights {
                path: index_path,
                token: entry.frame_token,
                found: format!("'{}' with weights {}", entry.model, entry.weights_hash),
                expected: format!(
                    "'{}' with weights {}",
                    expected.model, expected.weights_hash
                ),
            });
        }
        if entry.shape != expected.shape {
            return Err(DataError::Shape {
                path,
                found: entry.shape,
                expected: expected.shape,
            });
        }
        let mut latent = entry.read_values(dir).map_err(DataError::from)?;
        expected.stats.standardize(&mut latent);
        let global_from_ego = entry.global_from_ego();
        scenes.entry(entry.scene).or_default().push(LatentFrame {
            token: entry.frame_token,
            time_us: entry.timestamp_us,
            global_from_ego,
            latent,
        });
    }
    let mut sequences = Vec::new();
    let mut gaps = 0;
    for (scene, mut frames) in scenes {
        frames.sort_by_key(|f| f.time_us);
        if let Some(pair) = frames.windows(2).find(|w| w[0].time_us == w[1].time_us) {
            return Err(DataError::DuplicateTime {
                path: index_path,
                scene,
                time_us: pair[0].time_us,
                first: pair[0].token.clone(),
                second: pair[1].token.clone(),
            });
        }
        let (parts, splits) = split_at_gaps(frames, expected.gap_factor);
        gaps += splits;
        sequences.extend(parts.into_iter().map(|frames| Sequence {
            scene: scene.clone(),
            frames,
        }));
    }
    Ok(LatentSequences { sequences, gaps })
}

/// Splits time-ordered frames wherever an interval exceeds `factor` times the median one.
fn split_at_gaps(frames: Vec<LatentFrame>, factor: f64) -> (Vec<Vec<LatentFrame>>, usize) {
    let mut intervals: Vec<i64> = frames
        .windows(2)
        .map(|w| w[1].time_us - w[0].time_us)
        .collect();
    if intervals.is_empty() {
        return (vec![frames], 0);
    }
    intervals.sort_unstable();
    let usual = intervals[intervals.len() / 2] as f64;
    let mut parts = vec![Vec::new()];
    let mut last_time = None;
    for frame in frames {
        if let Some(previous) = last_time
            && (frame.time_us - previous) as f64 > factor * usual
        {
            parts.push(Vec::new());
        }
        last_time = Some(frame.time_us);
        if let Some(part) = parts.last_mut() {
            part.push(frame);
        }
    }
    let splits = parts.len() - 1;
    (parts, splits)
}
