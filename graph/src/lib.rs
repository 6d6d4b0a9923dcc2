//! The bevworld dataflow runtime.
//!
//! A graph is a YAML file of nodes and edges. Each node is a [`Source`], [`Task`] or [`Sink`]
//! running on its own thread; each edge is a bounded crossbeam channel with a policy
//! ([`EdgePolicy`]). The runtime knows nothing about sensors or models: applications register
//! node kinds in a [`Registry`].

pub mod align;
pub mod diagnostic;
pub mod dot;
pub mod error;
pub mod io;
pub mod message;
pub mod metrics;
pub mod node;
pub mod pacing;
pub mod policy;
pub mod port;
pub mod registry;
pub mod runtime;
pub mod schema;
pub mod validate;

pub use diagnostic::{Diagnostic, Diagnostics};
pub use error::{NodeError, RunError};
pub use message::{Header, Instant, Message};
pub use metrics::{NodeReport, RunReport};
pub use node::{Figures, Inputs, Node, Outputs, Role, Sink, Source, SourceInfo, Task};
pub use pacing::Pacing;
pub use policy::EdgePolicy;
pub use port::{PortSpec, PortType};
pub use registry::{KindSpec, NodeKind, ParamError, Registry};
pub use runtime::{RunOptions, RunOutcome, StopHandle, run};
pub use schema::{OnError, SyncMode};
pub use validate::{Override, ResolvedGraph, resolve};

/// Reads and validates a graph file.
pub fn load(
    path: &std::path::Path,
    registry: &Registry,
    overrides: &[Override],
) -> Result<ResolvedGraph, Diagnostics> {
    let file = path.display().to_string();
    match std::fs::read_to_string(path) {
        Ok(text) => resolve(&text, &file, registry, overrides),
        Err(error) => Err(Diagnostics(vec![Diagnostic {
            file,
            position: None,
            message: format!("cannot read graph file: {error}"),
            hint: Some("graphs live in configs/graphs/*.yaml".into()),
        }])),
    }
}
