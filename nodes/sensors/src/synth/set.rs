//! A synthetic dataset named by its seed range, as training configs name their sets: made on
//! first use, and held to exactly its scenes afterwards.

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use super::{Branch, SynthConfig, generate_in_place};
use crate::source::parse_size;
use crate::{Dataset, DatasetOptions};

/// `scenes` scenes from seed `seed` on (scene k uses seed + k), made with `bevworld synth` if
/// `dir` does not exist yet; with `branch`, each scene once per manoeuvre
/// (`bevworld synth --branch-at`), named `<scene>-<manoeuvre>`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SynthSet {
    pub dir: PathBuf,
    pub seed: u64,
    pub scenes: usize,
    pub seconds: f64,
    pub camera_size: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub branch: Option<Branch>,
    /// Pedestrians and cyclists per scene (`bevworld synth --pedestrians --cyclists`).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub pedestrians: usize,
    #[serde(default, skip_serializing_if = "is_zero")]
    pub cyclists: usize,
}

fn is_zero(count: &usize) -> bool {
    *count == 0
}

#[derive(Debug, thiserror::Error)]
#[error("dataset {path}: {message}")]
pub struct SynthSetError {
    pub path: PathBuf,
    pub message: String,
}

impl SynthSet {
    /// The seeds `seed .. seed + scenes`.
    pub fn seeds(&self) -> std::ops::Range<u64> {
        self.seed..self.seed.saturating_add(self.scenes as u64)
    }

    /// Makes the set with the synthetic world unless its folder exists. The folder, found or
    /// made, must hold exactly the set's scenes: one made for another seed range would
    /// silently change what a run trains or validates on.
    pub fn ensure(&self) -> Result<(), SynthSetError> {
        let error = |message: String| SynthSetError {
            path: self.dir.clone(),
            message,
        };
        let (camera_width, camera_height) =
            parse_size(&self.camera_size).map_err(|e| error(format!("camera_size: {e}")))?;
        let config = SynthConfig {
            seed: self.seed,
            scenes: self.scenes,
            seconds: self.seconds,
            camera_width,
            camera_height,
            branch: self.branch.clone(),
            pedestrians: self.pedestrians,
            cyclists: self.cyclists,
            ..Default::default()
        };
        if !self.dir.exists() {
            // Another run may make a set in the same folder at once: `generate_in_place` keeps
            // whichever copy lands first, and the check below holds it to this set's scenes.
            generate_in_place(&self.dir, &config, |_, _| {}).map_err(|e| error(e.to_string()))?;
        }
        let dataset = Dataset::open(&self.dir, &DatasetOptions::default())
            .map_err(|e| error(e.to_string()))?;
        let mut held: Vec<&str> = dataset.scene_names();
        held.dedup();
        let wanted = config.scene_names();
        if held != wanted {
            return Err(error(format!(
                "holds {} scene(s) ({}), but the config's set is {} scene(s) from seed {} ({}): \
                 remove the folder to make it anew, or give the set another `dir`",
                held.len(),
                span(&held),
                wanted.len(),
                self.seed,
                span(&wanted),
            )));
        }
        Ok(())
    }
}

/// "first … last" of a list of scene names, or the one name.
fn span<S: AsRef<str>>(names: &[S]) -> String {
    match (names.first(), names.last()) {
        (Some(first), Some(last)) if names.len() > 1 => {
            format!("{} … {}", first.as_ref(), last.as_ref())
        }
        (Some(only), _) => only.as_ref().to_string(),
        _ => "none".into(),
    }
}
