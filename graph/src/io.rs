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
    fn write_into_missing_directory_is_an_error_not_a_panic() {
        let dir = tempfile::tempdir().unwrap();
        let result = write_atomic(dir.path().join("no/such/dir/a.bin"), vec![1])
            .unwrap()
            .wait();
        assert!(result.is_err());
    }
}
