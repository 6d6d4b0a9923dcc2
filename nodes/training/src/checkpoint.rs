//! Checkpoints: `RUN/checkpoints/step-NNNNNNN/` holds the files a trainer names (its modules
//! and optimiser states, as burnpack) and `state.json` (step, RNG state). A checkpoint is
//! written into a temporary folder and renamed into place, and `RUN/checkpoints/latest` names
//! the newest complete one, replaced atomically, so a crash at any instant leaves the last
//! good checkpoint loadable.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use bevworld_types::file_digest;
use serde::{Deserialize, Serialize};

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CheckpointState {
    /// Steps completed.
    pub step: usize,
    pub rng_state: u64,
}

/// `state.json` on disk: the state and the digest of each file of the checkpoint.
#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct StateFile {
    step: usize,
    rng_state: u64,
    /// File name → `bytes_digest` of its content.
    files: BTreeMap<String, String>,
}

#[derive(Debug, thiserror::Error)]
pub enum CheckpointError {
    #[error("checkpoint {path}: {message}")]
    Io { path: PathBuf, message: String },
    #[error(
        "no checkpoint to resume from in {path} (a run writes one every `checkpoint_every` steps)"
    )]
    None { path: PathBuf },
}

pub fn io_error(path: &Path, error: impl ToString) -> CheckpointError {
    CheckpointError::Io {
        path: path.to_path_buf(),
        message: error.to_string(),
    }
}

/// The folder of one checkpoint; a trainer names the files in it.
#[derive(Debug)]
pub struct CheckpointFiles {
    pub dir: PathBuf,
}

impl CheckpointFiles {
    /// The path of file `name` (e.g. `model.bpk`) in this checkpoint.
    pub fn file(&self, name: &str) -> PathBuf {
        self.dir.join(name)
    }

    pub fn state(&self) -> PathBuf {
        self.dir.join("state.json")
    }
}

pub fn checkpoints_dir(run: &Path) -> PathBuf {
    run.join("checkpoints")
}

fn step_name(step: usize) -> String {
    format!("step-{step:07}")
}

/// A temporary folder to write checkpoint `step` into; `commit` moves it into place.
pub fn staging(run: &Path, step: usize) -> Result<CheckpointFiles, CheckpointError> {
    let dir = checkpoints_dir(run).join(format!("{}.partial", step_name(step)));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).map_err(|e| io_error(&dir, e))?;
    Ok(CheckpointFiles { dir })
}

/// Writes `state.json`, renames the staged folder into place, points `latest` at it and keeps
/// only the newest `keep` checkpoints.
pub fn commit(
    run: &Path,
    staged: CheckpointFiles,
    state: &CheckpointState,
    keep: usize,
) -> Result<PathBuf, CheckpointError> {
    let mut files = BTreeMap::new();
    for entry in std::fs::read_dir(&staged.dir).map_err(|e| io_error(&staged.dir, e))? {
        let path = entry.map_err(|e| io_error(&staged.dir, e))?.path();
        let name = path
            .file_name()
            .and_then(|n| n.to_str())
            .map(str::to_string);
        match name {
            Some(name) if name != "state.json" => {
                let digest = file_digest(&path).map_err(|e| io_error(&path, e))?;
                files.insert(name, digest);
            }
            _ => {}
        }
    }
    let on_disk = StateFile {
        step: state.step,
        rng_state: state.rng_state,
        files,
    };
    let text = serde_json::to_string_pretty(&on_disk).map_err(|e| io_error(&staged.state(), e))?;
    std::fs::write(staged.state(), text).map_err(|e| io_error(&staged.state(), e))?;
    let root = checkpoints_dir(run);
    let name = step_name(state.step);
    let target = root.join(&name);
    let _ = std::fs::remove_dir_all(&target);
    std::fs::rename(&staged.dir, &target).map_err(|e| io_error(&target, e))?;
    let latest = root.join("latest");
    bevworld_atomic_file::write(&latest, name.as_bytes()).map_err(|e| io_error(&latest, e))?;

    let mut complete: Vec<PathBuf> = std::fs::read_dir(&root)
        .map_err(|e| io_error(&root, e))?
        .filter_map(|entry| entry.ok().map(|e| e.path()))
        .filter(|p| {
            p.is_dir()
                && p.file_name()
                    .and_then(|n| n.to_str())
                    .is_some_and(|n| n.starts_with("step-") && !n.ends_with(".partial"))
        })
        .collect();
    complete.sort();
    let excess = complete.len().saturating_sub(keep.max(1));
    for old in complete.into_iter().take(excess) {
        let _ = std::fs::remove_dir_all(old);
    }
    Ok(target)
}

/// The newest complete checkpoint of a run, checked: its step is its folder's, and every file
/// is the one its `state.json` recorded.
pub fn latest(run: &Path) -> Result<(CheckpointFiles, CheckpointState), CheckpointError> {
    let root = checkpoints_dir(run);
    let pointer = root.join("latest");
    let name = std::fs::read_to_string(&pointer).map_err(|_| CheckpointError::None {
        path: run.to_path_buf(),
    })?;
    let name = name.trim();
    if !(name.starts_with("step-") && !name.contains(['/', '\\']) && name != "step-") {
        return Err(io_error(
            &pointer,
            format!("names `{name}`, not a checkpoint folder (step-NNNNNNN)"),
        ));
    }
    let files = CheckpointFiles {
        dir: root.join(name),
    };
    let state = verify(&files)?;
    Ok((files, state))
}

/// Reads a checkpoint's `state.json` and checks the folder against it.
pub fn verify(files: &CheckpointFiles) -> Result<CheckpointState, CheckpointError> {
    let state_path = files.state();
    let text = std::fs::read_to_string(&state_path).map_err(|e| io_error(&state_path, e))?;
    let on_disk: StateFile = serde_json::from_str(&text).map_err(|e| {
        // A checkpoint from before digests were recorded: say so, not only the missing field.
        let legacy = serde_json::from_str::<serde_json::Value>(&text)
            .is_ok_and(|v| v.get("step").is_some() && v.get("files").is_none());
        if legacy {
            io_error(
                &state_path,
                "was written before checkpoints recorded their files' digests, so its files cannot be checked; start the run again in a new folder",
            )
        } else {
            io_error(&state_path, e)
        }
    })?;
    let folder = files
        .dir
        .file_name()
        .and_then(|n| n.to_str())
        .unwrap_or_default();
    if folder != step_name(on_disk.step) {
        return Err(io_error(
            &state_path,
            format!(
                "says step {}, but it lies in {folder}; the checkpoint was edited or moved, refusing to resume from it",
                on_disk.step
            ),
        ));
    }
    for (name, recorded) in &on_disk.files {
        let path = files.dir.join(name);
        if name.contains(['/', '\\']) {
            return Err(io_error(
                &state_path,
                format!("lists `{name}`, not a file name"),
            ));
        }
        let digest = file_digest(&path)
            .map_err(|e| io_error(&path, format!("listed in state.json but unreadable ({e})")))?;
        if &digest != recorded {
            return Err(io_error(
                &path,
                format!(
                    "digest {digest} differs from {recorded} recorded in state.json; the file changed after it was written"
                ),
            ));
        }
    }
    for entry in std::fs::read_dir(&files.dir).map_err(|e| io_error(&files.dir, e))? {
        let path = entry.map_err(|e| io_error(&files.dir, e))?.path();
        let name = path
            .file_name()
            .and_then(|n| n.to_str())
            .unwrap_or_default();
        if name != "state.json" && !on_disk.files.contains_key(name) {
            return Err(io_error(
                &path,
                "is not listed in state.json; it was not written with this checkpoint",
            ));
        }
    }
    Ok(CheckpointState {
        step: on_disk.step,
        rng_state: on_disk.rng_state,
    })
}
