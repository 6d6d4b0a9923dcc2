//! Atomic file writes handed to the I/O pool, with a bound on how many are in flight so a slow
//! disk applies backpressure instead of growing memory. Every write must land inside the
//! sink's folder: names come from datasets, and a path that leaves the folder is refused.

use std::collections::VecDeque;
use std::path::PathBuf;

use bevworld_graph::NodeError;
use bevworld_graph::io::{PendingWrite, lies_inside, write_atomic};

pub struct Writes {
    /// The sink's folder: no write lands outside it.
    root: PathBuf,
    pending: VecDeque<PendingWrite>,
    max_in_flight: usize,
    written: u64,
}

impl Writes {
    pub fn new(root: PathBuf, max_in_flight: usize) -> Self {
        Self {
            root,
            pending: VecDeque::new(),
            max_in_flight: max_in_flight.max(1),
            written: 0,
        }
    }

    /// Queues a write; waits for the oldest one first when too many are in flight.
    pub fn write(&mut self, path: PathBuf, bytes: Vec<u8>) -> Result<(), NodeError> {
        if !lies_inside(&self.root, &path) {
            return Err(NodeError::fatal(format!(
                "refusing to write {}: it is not inside the sink's folder {}",
                path.display(),
                self.root.display()
            )));
        }
        if let Some(parent) = path.parent() {
            std::fs::create_dir_all(parent).map_err(|error| {
                NodeError::fatal(format!(
                    "{}: cannot create folder: {error}",
                    parent.display()
                ))
            })?;
        }
        while self.pending.len() >= self.max_in_flight
            || self.pending.front().is_some_and(PendingWrite::is_finished)
        {
            self.wait_oldest()?;
        }
        let pending = write_atomic(path.clone(), bytes).map_err(|error| {
            NodeError::fatal(format!("{}: cannot start write: {error}", path.display()))
        })?;
        self.pending.push_back(pending);
        Ok(())
    }

    fn wait_oldest(&mut self) -> Result<(), NodeError> {
        if let Some(oldest) = self.pending.pop_front() {
            let path = oldest.path().display().to_string();
            oldest
                .wait()
                .map_err(|error| NodeError::fatal(format!("{path}: write failed: {error}")))?;
            self.written += 1;
        }
        Ok(())
    }

    /// Waits for every write; the first failure is returned.
    pub fn flush(&mut self) -> Result<(), NodeError> {
        while !self.pending.is_empty() {
            self.wait_oldest()?;
        }
        Ok(())
    }

    pub fn written(&self) -> u64 {
        self.written
    }
}
