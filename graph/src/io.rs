//! The I/O pool: a small tokio runtime for file prefetching and sink writes. Compute never runs
//! here; nodes compute on their own threads and hand finished bytes over.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use tokio::runtime::Runtime;
use tokio::task::JoinHandle;

fn runtime() -> Result<&'static Runtime, std::io::Error> {
    static RUNTIME: OnceLock<Result<Runtime, String>> = OnceLock::new();
    RUNTIME
        .get_or_init(|| {
            tokio::runtime::Builder::new_multi_thread()
                .worker_threads(2)
                .thread_name("bevworld-io")
                .enable_all()
                .build()
                .map_err(|error| error.to_string())
        })
        .as_ref()
        .map_err(|message| std::io::Error::other(message.clone()))
}

/// A write in flight; `wait` returns its outcome.
pub struct PendingWrite {
    path: PathBuf,
    handle: JoinHandle<std::io::Result<()>>,
}

impl PendingWrite {
    pub fn path(&self) -> &Path {
        &self.path
    }

    pub fn is_finished(&self) -> bool {
        self.handle.is_finished()
    }

    /// Blocks the calling (node) thread until the write is on disk.
    pub fn wait(self) -> std::io::Result<()> {
        let runtime = runtime()?;
        match runtime.block_on(self.handle) {
            Ok(result) => result,
            Err(join) => Err(std::io::Error::other(format!("write task failed: {join}"))),
        }
    }
}

/// Writes `bytes` to `path` atomically on the I/O pool: a temporary file beside it, then a
/// rename, so a reader never sees a half-written file and a crash leaves no corrupt output.
pub fn write_atomic(path: PathBuf, bytes: Vec<u8>) -> std::io::Result<PendingWrite> {
    let runtime = runtime()?;
    let target = path.clone();
    let handle = runtime.spawn(async move { write_atomic_async(&target, &bytes).await });
    Ok(PendingWrite { path, handle })
}

pub use bevworld_atomic_file::remove_stale_temporaries;
/// The same, blocking the caller; for tools that are not in a graph (the workspace's one
/// atomic writer, `bevworld_atomic_file::write`).
pub use bevworld_atomic_file::write as write_atomic_now;

async fn write_atomic_async(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let temporary = bevworld_atomic_file::temporary_path(path);
    tokio::fs::write(&temporary, bytes).await?;
    tokio::fs::rename(&temporary, path).await
}

/// Rewrites the file at `path` as `update` makes it from its current bytes (`None` when there
/// is no file yet), holding an exclusive lock on `<path>.lock` meanwhile, so that writers in
/// several processes (shards sharing one index) each merge into the others' result instead of
/// replacing it. The write itself is atomic, so readers need no lock.
pub fn update_locked<E>(
    path: &Path,
    update: impl FnOnce(Option<Vec<u8>>) -> Result<Vec<u8>, E>,
) -> Result<Result<(), E>, std::io::Error> {
    let mut lock_name = path
        .file_name()
        .map(|n| n.to_os_string())
        .unwrap_or_default();
    lock_name.push(".lock");
    let lock_path = path.with_file_name(lock_name);
    let lock = std::fs::OpenOptions::new()
        .create(true)
        .truncate(false)
        .write(true)
        .open(&lock_path)?;
    lock.lock()?;
    let current = match std::fs::read(path) {
        Ok(bytes) => Some(bytes),
        Err(error) if error.kind() == std::io::ErrorKind::NotFound => None,
        Err(error) => return Err(error),
    };
    let outcome = match update(current) {
        Ok(bytes) => {
            write_atomic_now(path, &bytes)?;
            Ok(())
        }
        Err(error) => Err(error),
    };
    lock.unlock()?;
    Ok(outcome)
}

/// A file or folder name made from a name a dataset chose (a scene, a token, a camera): path
/// separators, `..` and every character outside `[A-Za-z0-9._+-]` become `_`, so that no
/// name a dataset says can lead a write out of its folder. Never empty, `.` or `..`.
pub fn safe_file_name(name: &str) -> String {
    let cleaned: String = name
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || matches!(c, '-' | '.' | '_' | '+') {
                c
            } else {
                '_'
            }
        })
        .collect();
    // A name of dots alone (`.`, `..`, `...`) would name this folder or its parent.
    if cleaned.chars().all(|c| c == '.') {
        return cleaned.replace('.', "_") + "_";
    }
    cleaned
}

/// Whether `path` lies inside `root` by its words alone: it starts with `root` and no
/// component after it is `..`, the root or a prefix. A sink checks every path it writes.
pub fn lies_inside(root: &Path, path: &Path) -> bool {
    use std::path::Component;
    path.strip_prefix(root).is_ok_and(|rest| {
        !rest.as_os_str().is_empty() && rest.components().all(|c| matches!(c, Component::Normal(_)))
    })
}

/// An exclusive claim on an output folder for this process: a second run writing into the
/// same folder at the same time would silently overwrite the first's files, so it is refused
/// instead. Several sinks of one run may share a folder (each takes the claim; the lock is
/// released when the last lets go). The lock is `<dir>/.bevworld.lock`, held with the
/// operating system's advisory lock, so a killed run leaves no stale claim.
pub struct FolderClaim {
    key: PathBuf,
}

fn claims() -> &'static std::sync::Mutex<std::collections::HashMap<PathBuf, (std::fs::File, usize)>>
{
    static CLAIMS: OnceLock<
        std::sync::Mutex<std::collections::HashMap<PathBuf, (std::fs::File, usize)>>,
    > = OnceLock::new();
    CLAIMS.get_or_init(Default::default)
}

impl FolderClaim {
    /// Creates `dir` if needed and claims it; an error names the folder when another process
    /// holds it.
    pub fn acquire(dir: &Path) -> Result<Self, String> {
        std::fs::create_dir_all(dir)
            .map_err(|e| format!("{}: cannot create folder: {e}", dir.display()))?;
        let key = dir
            .canonicalize()
            .map_err(|e| format!("{}: {e}", dir.display()))?;
        let mut held = claims().lock().unwrap_or_else(|p| p.into_inner());
        if let Some((_, count)) = held.get_mut(&key) {
            *count += 1;
            return Ok(Self { key });
        }
        let lock_path = key.join(".bevworld.lock");
        let file = std::fs::OpenOptions::new()
            .create(true)
            .truncate(false)
            .write(true)
            .open(&lock_path)
            .map_err(|e| format!("{}: cannot open: {e}", lock_path.display()))?;
        match file.try_lock() {
            Ok(()) => {}
            Err(std::fs::TryLockError::WouldBlock) => {
                return Err(format!(
                    "{}: another run is writing into this folder now (it holds {}); wait for it, or write into another folder",
                    dir.display(),
                    lock_path.display()
                ));
            }
            Err(std::fs::TryLockError::Error(e)) => {
                return Err(format!("{}: cannot lock: {e}", lock_path.display()));
            }
        }
        held.insert(key.clone(), (file, 1));
        Ok(Self { key })
    }
}

impl Drop for FolderClaim {
    fn drop(&mut self) {
        let mut held = claims().lock().unwrap_or_else(|p| p.into_inner());
        if let Some((_, count)) = held.get_mut(&self.key) {
            *count -= 1;
            if *count == 0 {
                // Closing the file releases the lock.
                held.remove(&self.key);
            }
        }
    }
}

/// Runs a blocking I/O job (reading a frame's files) on the I/O pool.
pub fn spawn_io<T, F>(job: F) -> std::io::Result<JoinHandle<T>>
where
    T: Send + 'static,
    F: FnOnce() -> T + Send + 'static,
{
    Ok(runtime()?.spawn_blocking(job))
}

/// Waits for a job started with `spawn_io`.
pub fn wait<T>(handle: JoinHandle<T>) -> std::io::Result<T> {
    runtime()?
        .block_on(handle)
        .map_err(|join| std::io::Error::other(format!("I/O task failed: {join}")))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_from_datasets_stay_one_component() {
        for (name, expected) in [
            ("scene-0001", "scene-0001"),
            ("../../escaped/x", ".._.._escaped_x"),
            ("/etc/passwd", "_etc_passwd"),
            ("..", "___"),
            (".", "__"),
            ("", "_"),
            ("a\\b:c\0d", "a_b_c_d"),
            ("tok+0.5s", "tok+0.5s"),
        ] {
            assert_eq!(safe_file_name(name), expected, "{name:?}");
        }
        let root = Path::new("/out/forecast");
        assert!(lies_inside(root, &root.join("a/+1s/x.png")));
        assert!(!lies_inside(root, &root.join("../x.png")));
        assert!(!lies_inside(root, &root.join("a/../../x.png")));
        assert!(!lies_inside(root, Path::new("/out/forecast-2/x.png")));
        assert!(!lies_inside(root, Path::new("/etc/passwd")));
        assert!(!lies_inside(root, root));
    }

    #[test]
    fn a_folder_is_claimed_by_one_process_and_shared_within_it() {
        let dir = tempfile::tempdir().unwrap();
        let first = FolderClaim::acquire(dir.path()).unwrap();
        // A second sink of the same run shares it.
        let second = FolderClaim::acquire(dir.path()).unwrap();
        // Another process's claim is the same lock held through another open file.
        let other = std::fs::OpenOptions::new()
            .write(true)
            .open(dir.path().join(".bevworld.lock"))
            .unwrap();
        assert!(other.try_lock().is_err(), "held while claimed");
        drop(first);
        assert!(
            other.try_lock().is_err(),
            "held while one sink still claims it"
        );
        drop(second);
        other.try_lock().expect("released with the last claim");
        let refused = FolderClaim::acquire(dir.path()).err().unwrap_or_default();
        assert!(refused.contains("another run is writing"), "{refused}");
        drop(other);
        assert!(FolderClaim::acquire(dir.path()).is_ok());
    }

    #[test]
    fn atomic_write_leaves_only_the_final_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.bin");
        write_atomic(path.clone(), vec![1, 2, 3])
            .unwrap()
            .wait()
            .unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), vec![1, 2, 3]);
        let names: Vec<_> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names.len(), 1);
    }

    #[test]
    fn locked_updates_from_many_threads_lose_nothing() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("index.txt");
        std::thread::scope(|scope| {
            for writer in 0..8 {
                let path = &path;
                scope.spawn(move || {
                    for item in 0..10 {
                        update_locked(path, |current| {
                            let mut text = String::from_utf8(current.unwrap_or_default()).unwrap();
                            text.push_str(&format!("{writer}-{item}\n"));
                            Ok::<_, ()>(text.into_bytes())
                        })
                        .unwrap()
                        .unwrap();
                    }
                });
            }
        });
        let text = std::fs::read_to_string(&path).unwrap();
        assert_eq!(text.lines().count(), 80, "{text}");
    }

    #[test]
    fn write_into_missing_directory_is_an_error_not_a_panic() {
        let dir = tempfile::tempdir().unwrap();
        let result = write_atomic(dir.path().join("no/such/dir/a.bin"), vec![1])
            .unwrap()
            .wait();
        assert!(result.is_err());
    }
}
