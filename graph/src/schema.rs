//! The YAML graph file, as written by people. Positions are kept so validation can point at
//! the exact line and column of every problem.
//!
//! ```yaml
//! name: replay
//! settings: {default_capacity: 16, default_policy: block}
//! nodes:
//!   - id: source
//!     kind: nuscenes_source
//!     params: {data: ../shared/data/nuscenes-sample}
//!     pacing: {rate_hz: 12}
//!   - {id: png, kind: png_sink, params: {out: out/replay}}
//! edges:
//!   - {from: source.frame, to: png.frame, capacity: 4, policy: drop_oldest}
//! ```

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};
use serde_saphyr::Spanned;

use crate::policy::EdgePolicy;

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GraphFile {
    #[serde(default)]
    pub name: Option<String>,
    #[serde(default)]
    pub description: Option<String>,
    #[serde(default)]
    pub settings: Settings,
    /// Named model bundles (`models.rs`): each loaded once and shared by the nodes naming it.
    #[serde(default)]
    pub models: BTreeMap<String, Spanned<BTreeMap<String, Spanned<serde_json::Value>>>>,
    /// What the graph offers the commands that drive it (`interface.rs`).
    #[serde(default)]
    pub interface: Option<Spanned<InterfaceDecl>>,
    pub nodes: Vec<Spanned<NodeDecl>>,
    #[serde(default)]
    pub edges: Vec<Spanned<EdgeDecl>>,
}

/// Graph-wide settings.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct Settings {
    /// Queue capacity of edges that name none.
    pub default_capacity: usize,
    /// Policy of edges that name none.
    pub default_policy: EdgePolicy,
    /// Milliseconds the runtime waits for nodes to stop after an error before giving up on them.
    pub shutdown_grace_ms: u64,
    /// Show a progress bar when the total is known and stderr is a terminal.
    pub progress: bool,
    /// Microseconds an idle node polls its input before parking its thread. Polling saves the
    /// wake-up latency of a hop (~7 µs on a VM) when spare cores exist, at the price of CPU while
    /// idle; on a machine with fewer cores than nodes it costs more than it saves. 0 parks at once.
    pub idle_spin_us: u64,
}

impl Default for Settings {
    fn default() -> Self {
        Self {
            default_capacity: 16,
            default_policy: EdgePolicy::Block,
            shutdown_grace_ms: 5000,
            progress: true,
            idle_spin_us: 0,
        }
    }
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NodeDecl {
    pub id: Spanned<String>,
    pub kind: Spanned<String>,
    #[serde(default)]
    pub params: Option<Spanned<BTreeMap<String, Spanned<serde_json::Value>>>>,
    #[serde(default)]
    pub on_error: Option<Spanned<OnError>>,
    #[serde(default)]
    pub pacing: Option<Spanned<PacingDecl>>,
    /// How a node with several inputs groups them: `aligned` (by time of validity) or `any`.
    #[serde(default)]
    pub sync: Option<Spanned<SyncMode>>,
    /// Largest time-of-validity difference the aligner pairs, in microseconds.
    #[serde(default)]
    pub align_tolerance_us: Option<Spanned<i64>>,
}

/// The parameters and outputs a graph exposes by name, so that a command binds to the names and
/// never to node ids:
///
/// ```yaml
/// interface:
///   params: {data: source.data, horizons: rollout.horizons}
///   outputs: {scores: scores.table}
/// ```
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InterfaceDecl {
    /// Name -> `node.param` (a dotted path inside the node's parameters is allowed), or a list
    /// of them, set together (one output folder for several sinks).
    #[serde(default)]
    pub params: BTreeMap<String, Spanned<ParamTargets>>,
    /// Name -> `node.port`, an output port.
    #[serde(default)]
    pub outputs: BTreeMap<String, Spanned<String>>,
}

/// What an exposed parameter stands for: one `node.param`, or several set together.
#[derive(Debug, Deserialize)]
#[serde(untagged)]
pub enum ParamTargets {
    One(String),
    Many(Vec<String>),
}

impl ParamTargets {
    pub fn targets(&self) -> Vec<&str> {
        match self {
            ParamTargets::One(one) => vec![one.as_str()],
            ParamTargets::Many(many) => many.iter().map(String::as_str).collect(),
        }
    }
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EdgeDecl {
    pub from: Spanned<String>,
    pub to: Spanned<String>,
    #[serde(default)]
    pub capacity: Option<Spanned<usize>>,
    #[serde(default)]
    pub policy: Option<Spanned<EdgePolicy>>,
}

/// What a bad input item does.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum OnError {
    /// End the run (the default).
    #[default]
    Stop,
    /// Skip the item, count it, and go on.
    Skip,
}

#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum SyncMode {
    /// One call per set of messages whose times of validity agree within the tolerance.
    #[default]
    Aligned,
    /// One call per message, whichever input it came on.
    Any,
}

/// Source pacing as written: at most one of the two.
#[derive(Clone, Copy, Debug, Default, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct PacingDecl {
    /// Replay at recorded timestamps times this factor; 0 = as fast as possible.
    pub speed: Option<f64>,
    /// Replay at a fixed rate.
    pub rate_hz: Option<f64>,
}
