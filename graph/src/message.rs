//! The message that travels along every edge: a small header and a shared, type-erased payload.
//!
//! Payloads sit behind an `Arc`, so fan-out and hand-over between nodes move a pointer and never
//! deep-copy a camera image or a point cloud.

pub use quanta::Instant;
use std::any::Any;
use std::sync::Arc;

use crate::error::NodeError;

/// Bookkeeping that every message carries.
#[derive(Clone, Copy, Debug)]
pub struct Header {
    /// Position in the producing source's stream, from 0.
    pub seq: u64,
    /// Sensor time of validity in microseconds (the nuScenes convention).
    pub time_of_validity_us: i64,
    /// When the item entered the graph at its source; end-to-end latency is measured from here.
    /// A TSC clock (`quanta`): two reads per hop on the hot path must cost nanoseconds.
    pub entered_graph: Instant,
}

/// A header plus a shared payload of any `Send + Sync` type.
#[derive(Clone)]
pub struct Message {
    header: Header,
    payload: Arc<dyn Any + Send + Sync>,
}

impl std::fmt::Debug for Message {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Message")
            .field("header", &self.header)
            .finish_non_exhaustive()
    }
}

impl Message {
    pub fn new<T: Any + Send + Sync>(header: Header, payload: T) -> Self {
        Self {
            header,
            payload: Arc::new(payload),
        }
    }

    pub fn from_shared<T: Any + Send + Sync>(header: Header, payload: Arc<T>) -> Self {
        Self { header, payload }
    }

    pub(crate) fn restamp(&mut self, entered_graph: Instant) {
        self.header.entered_graph = entered_graph;
    }

    pub fn header(&self) -> &Header {
        &self.header
    }

    /// Borrows the payload as `T`. Validation guarantees port types, so a mismatch here is a
    /// node bug, reported as an error rather than a panic.
    pub fn get<T: Any>(&self) -> Result<&T, NodeError> {
        self.payload.downcast_ref::<T>().ok_or_else(|| {
            NodeError::fatal(format!(
                "message payload is not a {}",
                crate::port::short_type_name::<T>()
            ))
        })
    }

    /// Shares the payload as `Arc<T>` without copying it.
    pub fn shared<T: Any + Send + Sync>(&self) -> Result<Arc<T>, NodeError> {
        Arc::clone(&self.payload).downcast::<T>().map_err(|_| {
            NodeError::fatal(format!(
                "message payload is not a {}",
                crate::port::short_type_name::<T>()
            ))
        })
    }

    /// True when both messages point at the same payload allocation (no copy was made).
    pub fn shares_payload_with(&self, other: &Message) -> bool {
        Arc::ptr_eq(&self.payload, &other.payload)
    }
}
