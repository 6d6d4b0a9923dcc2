//! The bevworld dataflow runtime.
//!
//! A graph is a YAML file of nodes and edges. Each node is a [`Source`], [`Task`] or [`Sink`]
//! running on its own thread; each edge is a bounded crossbeam channel with a policy
//! ([`EdgePolicy`]). The runtime knows nothing about sensors or models: applications register
//! node kinds in a [`Registry`].

// Libraries return errors; a panic belongs to a broken invariant, said with `expect`.
#![cfg_attr(not(test), warn(clippy::unwrap_used))]

pub mod align;
pub mod collect;
pub mod diagnostic;
pub mod dot;
pub mod error;
pub mod interface;
pub mod io;
pub mod message;
pub mod metrics;
pub mod models;
pub mod node;
pub mod pacing;
pub mod policy;
pub mod port;
pub mod registry;
pub mod runtime;
pub mod schema;
pub mod validate;
pub mod yaml;

pub use collect::Collected;
pub use diagnostic::{Diagnostic, Diagnostics};
pub use error::{NodeError, RunError};
pub use interface::{Contract, ExposedOutput, ExposedParam, Interface};
pub use message::{Header, Instant, Message};
pub use metrics::{NodeReport, RunReport};
pub use models::Models;
pub use node::{Figures, Inputs, Node, Outputs, Role, Sink, Source, SourceInfo, Task};
pub use pacing::{Pacing, PacingError};
pub use policy::EdgePolicy;
pub use port::{Port, PortSpec, PortType};
pub use registry::{GraphRule, KindSpec, NodeKind, ParamError, Registry, RuleProblem};
pub use runtime::{RunObserver, RunOptions, RunOutcome, StopHandle, run};
pub use schema::{OnError, SyncMode};
pub use validate::{
    GraphSpec, NodeSpec, Override, OverrideError, OverrideTarget, ResolvedGraph, ValidatedGraph,
    resolve, validate,
};

/// Reads and validates a graph file (nothing is built: `ValidatedGraph::build` does that).
pub fn load(
    path: &std::path::Path,
    registry: &Registry,
    overrides: &[Override],
) -> Result<ValidatedGraph, Diagnostics> {
    let file = path.display().to_string();
    match std::fs::read_to_string(path) {
        Ok(text) => validate(&text, &file, registry, overrides),
        Err(error) => Err(Diagnostics(vec![Diagnostic {
            file,
            position: None,
            message: format!("cannot read graph file: {error}"),
            hint: Some("graphs live in configs/graphs/*.yaml".into()),
        }])),
    }
}
