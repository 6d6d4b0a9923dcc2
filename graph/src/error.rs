//! Errors a node returns, and the error a run ends with.

use thiserror::Error;

/// What a node's `next`, `process` or `consume` can fail with.
#[derive(Debug, Error)]
pub enum NodeError {
    /// This one input item is bad (a corrupt file, a NaN pose). Under `on_error: skip` it is
    /// skipped and counted; under `on_error: stop` it ends the run.
    #[error("bad input item: {0}")]
    Item(String),
    /// The node cannot go on (a missing weights file, a full disk). Always ends the run.
    #[error("{0}")]
    Fatal(String),
    /// The graph is shutting down; the node should return quietly.
    #[error("graph is shutting down")]
    Shutdown,
}

impl NodeError {
    pub fn item(message: impl Into<String>) -> Self {
        Self::Item(message.into())
    }

    pub fn fatal(message: impl Into<String>) -> Self {
        Self::Fatal(message.into())
    }

    /// Keeps the error's whole `source()` chain in the message.
    pub fn item_from(error: &(dyn std::error::Error + 'static)) -> Self {
        Self::Item(chain(error))
    }

    pub fn fatal_from(error: &(dyn std::error::Error + 'static)) -> Self {
        Self::Fatal(chain(error))
    }
}

/// `a: b: c` from an error and its sources.
pub fn chain(error: &(dyn std::error::Error + 'static)) -> String {
    let mut text = error.to_string();
    let mut source = error.source();
    while let Some(cause) = source {
        let cause_text = cause.to_string();
        if !text.contains(&cause_text) {
            text.push_str(": ");
            text.push_str(&cause_text);
        }
        source = cause.source();
    }
    text
}

/// Why a run ended unsuccessfully. Names the node and the cause.
#[derive(Debug, Error)]
pub enum RunError {
    #[error("node '{node}' ({kind}) failed: {cause}")]
    NodeFailed {
        node: String,
        kind: String,
        cause: String,
    },
    #[error("node '{node}' ({kind}) panicked: {cause}")]
    NodePanicked {
        node: String,
        kind: String,
        cause: String,
    },
    #[error("nodes did not stop within {grace_ms} ms after shutdown: {nodes:?}")]
    Hung { nodes: Vec<String>, grace_ms: u64 },
    #[error("could not start the runtime: {0}")]
    Startup(String),
    /// Stopped at once (a second Ctrl-C): what was in flight is lost.
    #[error("aborted; nodes that did not finish (their outputs are incomplete): {unfinished:?}")]
    Aborted { unfinished: Vec<String> },
    /// The sources produced nothing, or every item was skipped: a run that made nothing is
    /// not a success.
    #[error("nothing was done: {0}")]
    NothingDone(String),
}
