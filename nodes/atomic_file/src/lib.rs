//! Files written whole or not at all: the bytes go to a temporary file beside the target and a
//! rename puts it in place, so a reader, or a run killed mid-write, never sees half a file. The
//! workspace's one writer of finished files: sinks (through the graph's I/O pool), reports,
//! plots, training logs and configs, checkpoints' small files and the README's results.
//!
//! A temporary names the process writing it (`<name>.<pid>.<n>.tmp`), so that the leftovers of
//! a killed writer can be told from those of a writer still at work in the same folder.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

/// Writes `bytes` to `path`: a temporary beside it, then a rename over it.
pub fn write(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let temporary = temporary_path(path);
    if let Err(error) = std::fs::write(&temporary, bytes) {
        // A partial temporary (disk full) is removed; a missing folder has none to remove.
        let _ = std::fs::remove_file(&temporary);
        return Err(error);
    }
    std::fs::rename(&temporary, path)
}

/// A temporary name beside `path`, unique per write: two writes to one path in flight must
/// not share a temporary file.
pub fn temporary_path(path: &Path) -> PathBuf {
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let unique = COUNTER.fetch_add(1, Ordering::Relaxed);
    let mut name = path
        .file_name()
        .map(|n| n.to_os_string())
        .unwrap_or_default();
    name.push(format!(".{}.{unique}.tmp", std::process::id()));
    path.with_file_name(name)
}

/// The writer process a temporary file of `temporary_path` names, if `name` is one.
fn temporary_owner(name: &str) -> Option<u32> {
    let stem = name.strip_suffix(".tmp")?;
    let (rest, unique) = stem.rsplit_once('.')?;
    unique.parse::<u64>().ok()?;
    let (_, pid) = rest.rsplit_once('.')?;
    pid.parse().ok()
}

/// Whether process `pid` still runs. Where that cannot be known, it is taken to run, so that
/// nothing another writer may still be writing is ever removed.
fn process_runs(pid: u32) -> bool {
    let proc_root = Path::new("/proc");
    if cfg!(target_os = "linux") && proc_root.join("self").exists() {
        proc_root.join(pid.to_string()).exists()
    } else {
        true
    }
}

/// Removes the temporary files in `dir` that a killed writer left behind, and only those. A
/// temporary names the process writing it; one whose process still runs belongs to a writer
/// at work in the same folder (another shard, another sink) and is left alone. Returns how
/// many were removed.
pub fn remove_stale_temporaries(dir: &Path) -> usize {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return 0;
    };
    let mut removed = 0;
    for entry in entries.flatten() {
        let name = entry.file_name().to_string_lossy().to_string();
        let Some(pid) = temporary_owner(&name) else {
            continue;
        };
        if !process_runs(pid) && std::fs::remove_file(entry.path()).is_ok() {
            removed += 1;
        }
    }
    removed
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_write_leaves_only_the_final_file_and_replaces_an_old_one() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.bin");
        write(&path, b"old, longer contents").unwrap();
        write(&path, &[1, 2, 3]).unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), vec![1, 2, 3]);
        let names: Vec<_> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names.len(), 1, "{names:?}");
    }

    #[test]
    fn a_write_into_a_missing_folder_is_an_error_and_leaves_nothing() {
        let dir = tempfile::tempdir().unwrap();
        assert!(write(&dir.path().join("missing/a.bin"), b"x").is_err());
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
    }

    #[test]
    fn temporaries_are_unique_per_write_and_name_their_writer() {
        let path = Path::new("/x/a.png");
        let (a, b) = (temporary_path(path), temporary_path(path));
        assert_ne!(a, b);
        let name = a.file_name().unwrap().to_string_lossy().to_string();
        assert_eq!(temporary_owner(&name), Some(std::process::id()));
        assert_eq!(a.parent(), path.parent());
    }

    #[test]
    fn only_temporaries_of_writers_that_are_gone_are_removed() {
        let dir = tempfile::tempdir().unwrap();
        // Ours (this process runs), a dead writer's (pid far above any running one), and
        // files that only look like temporaries.
        let ours = dir
            .path()
            .join(format!("a.npy.{}.0.tmp", std::process::id()));
        let dead = dir.path().join("b.npy.4000000000.3.tmp");
        let kept = ["c.npy", "notes.tmp", "d.npy.x.1.tmp", "e.npy.12.y.tmp"];
        std::fs::write(&ours, b"in flight").unwrap();
        std::fs::write(&dead, b"left by a kill").unwrap();
        for name in kept {
            std::fs::write(dir.path().join(name), b"").unwrap();
        }
        assert_eq!(temporary_owner("a.npy.17.0.tmp"), Some(17));
        assert_eq!(temporary_owner("notes.tmp"), None);
        let removed = remove_stale_temporaries(dir.path());
        if cfg!(target_os = "linux") {
            assert_eq!(removed, 1);
            assert!(!dead.exists());
        }
        assert!(ours.exists(), "a running writer's temporary must stay");
        for name in kept {
            assert!(dir.path().join(name).exists(), "{name}");
        }
    }
}
