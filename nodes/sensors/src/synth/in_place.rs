//! Making a synthetic dataset at a folder that readers will trust: it is generated into a staging
//! folder of its own and renamed into place, so an interrupted run leaves no half-made dataset
//! behind, and two processes (or threads) making the same folder at once do not write into one
//! another's files.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

use super::writer::{SynthConfig, SynthSummary, generate};
use crate::error::{Result, SensorError};

/// What [`generate_in_place`] found or did.
#[derive(Debug)]
pub enum InPlace {
    /// This call made the dataset.
    Generated(SynthSummary),
    /// The folder already existed, or another process finished making it first.
    AlreadyThere,
}

/// Makes the dataset of `config` at `dir` unless `dir` exists. `progress(frames_done,
/// frames_total)` is called per frame.
pub fn generate_in_place(
    dir: &Path,
    config: &SynthConfig,
    progress: impl FnMut(usize, usize),
) -> Result<InPlace> {
    if dir.exists() {
        return Ok(InPlace::AlreadyThere);
    }
    let staging = staging_folder(dir)?;
    remove_abandoned_staging(dir);
    let summary = match generate(&staging, config, progress) {
        Ok(summary) => summary,
        Err(error) => {
            let _ = std::fs::remove_dir_all(&staging);
            return Err(error);
        }
    };
    match std::fs::rename(&staging, dir) {
        Ok(()) => Ok(InPlace::Generated(summary)),
        // Another maker renamed its copy into place first: theirs is as good as ours.
        Err(_) if dir.join(super::VERSION).exists() => {
            let _ = std::fs::remove_dir_all(&staging);
            Ok(InPlace::AlreadyThere)
        }
        Err(error) => {
            let _ = std::fs::remove_dir_all(&staging);
            Err(SensorError::file(
                dir,
                format!("cannot move the generated dataset into place: {error}"),
            ))
        }
    }
}

/// `NAME.partial-PID-N` beside `dir`: unique to this process and call.
fn staging_folder(dir: &Path) -> Result<PathBuf> {
    static CALLS: AtomicU64 = AtomicU64::new(0);
    let name = dir
        .file_name()
        .ok_or_else(|| SensorError::file(dir, "names no folder to generate a dataset into"))?;
    let call = CALLS.fetch_add(1, Ordering::Relaxed);
    let mut staging = name.to_os_string();
    staging.push(format!(".partial-{}-{call}", std::process::id()));
    Ok(dir.with_file_name(staging))
}

/// Removes staging folders left beside `dir` by makers that were killed: on Linux, those whose
/// process no longer runs. Elsewhere they stay, named `NAME.partial-PID-N`.
fn remove_abandoned_staging(dir: &Path) {
    let (Some(parent), Some(name)) = (dir.parent(), dir.file_name()) else {
        return;
    };
    let parent = if parent.as_os_str().is_empty() {
        Path::new(".")
    } else {
        parent
    };
    let prefix = format!("{}.partial-", name.to_string_lossy());
    let Ok(entries) = std::fs::read_dir(parent) else {
        return;
    };
    for entry in entries.flatten() {
        let file_name = entry.file_name();
        let Some(pid) = file_name
            .to_str()
            .and_then(|n| n.strip_prefix(&prefix))
            .and_then(|rest| rest.split('-').next())
            .and_then(|pid| pid.parse::<u32>().ok())
        else {
            continue;
        };
        if process_is_gone(pid) {
            let _ = std::fs::remove_dir_all(entry.path());
        }
    }
}

#[cfg(target_os = "linux")]
fn process_is_gone(pid: u32) -> bool {
    pid != std::process::id() && !Path::new(&format!("/proc/{pid}")).exists()
}

#[cfg(not(target_os = "linux"))]
fn process_is_gone(_pid: u32) -> bool {
    false
}
