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

/// The same, blocking the caller; for tools that are not in a graph.
pub fn write_atomic_now(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let temporary = temporary_path(path);
    std::fs::write(&temporary, bytes)?;
    std::fs::rename(&temporary, path)
}

async fn write_atomic_async(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let temporary = temporary_path(path);
    tokio::fs::write(&temporary, bytes).await?;
    tokio::fs::rename(&temporary, path).await
}

/// A temporary name beside `path`, unique per write: two writes to one path in flight must
/// not share a temporary file.
fn temporary_path(path: &Path) -> PathBuf {
    static COUNTER: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
    let unique = COUNTER.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
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

/// Reads a whole file on the I/O pool, for prefetching the next item while this one computes.
pub fn read_ahead(path: PathBuf) -> std::io::Result<JoinHandle<std::io::Result<Vec<u8>>>> {
    let runtime = runtime()?;
    Ok(runtime.spawn(async move { tokio::fs::read(&path).await }))
}

/// Waits for a prefetch started with `read_ahead`.
pub fn wait_read(handle: JoinHandle<std::io::Result<Vec<u8>>>) -> std::io::Result<Vec<u8>> {
    let runtime = runtime()?;
    match runtime.block_on(handle) {
        Ok(result) => result,
        Err(join) => Err(std::io::Error::other(format!("read task failed: {join}"))),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
