//! Turns a graph file into a `ValidatedGraph` (every problem reported at once, nothing built),
//! and that into a runnable `ResolvedGraph`.

use std::collections::{BTreeMap, HashMap};
use std::sync::Arc;

use serde_saphyr::{Location, Spanned};

use crate::diagnostic::{Diagnostic, Diagnostics, Position, closest};
use crate::interface::Interface;
use crate::models::Models;
use crate::node::{Node, Role};
use crate::pacing::Pacing;
use crate::policy::EdgePolicy;
use crate::registry::{Checked, NodeKind, Registry};
use crate::schema::{GraphFile, NodeDecl, OnError, Settings, SyncMode};

/// A node as the graph declares it, its parameters typed and checked.
pub struct NodeSpec {
    pub id: String,
    pub kind: NodeKind,
    /// The parameters as resolved (defaults filled in).
    pub params: serde_json::Value,
    pub on_error: OnError,
    pub pacing: Pacing,
    pub sync: SyncMode,
    pub align_tolerance_us: i64,
}

/// A validated edge, by node index and port index.
#[derive(Clone, Debug)]
pub struct ResolvedEdge {
    pub from_node: usize,
    pub from_port: usize,
    pub to_node: usize,
    pub to_port: usize,
    pub capacity: usize,
    pub policy: EdgePolicy,
}

/// A graph checked against the registry: its nodes, parameters and typed edges. Nothing is
/// built or opened.
pub struct GraphSpec {
    pub name: String,
    pub file: String,
    pub settings: Settings,
    pub nodes: Vec<NodeSpec>,
    pub edges: Vec<ResolvedEdge>,
    /// The `models:` section, checked; loaded from as the nodes are built.
    pub models: Arc<Models>,
    /// What the graph exposes to commands.
    pub interface: Interface,
}

/// A validated graph, ready to build (`bevworld check` stops here).
pub struct ValidatedGraph {
    pub spec: GraphSpec,
    /// Per node: its checked parameters and where its problems point.
    pending: Vec<(Checked, ParamLocations)>,
}

/// A built graph, ready to run: `nodes[i]` is `spec.nodes[i]`, built.
pub struct ResolvedGraph {
    pub spec: GraphSpec,
    pub nodes: Vec<Node>,
}

/// Where a node's parameters are written, to point a parameter problem at its line.
#[derive(Clone, Default)]
struct ParamLocations {
    /// Each top-level key.
    keys: BTreeMap<String, Location>,
    /// The `params:` block, or the node's `kind:` when it has none.
    block: Option<Location>,
}

impl GraphSpec {
    pub fn edge_label(&self, edge: &ResolvedEdge) -> (String, String) {
        let from = &self.nodes[edge.from_node];
        let to = &self.nodes[edge.to_node];
        (
            format!("{}.{}", from.id, from.kind.outputs[edge.from_port].name),
            format!("{}.{}", to.id, to.kind.inputs[edge.to_port].name),
        )
    }

    /// The nodes whose outputs reach node `index`, directly or through others, nearest first.
    pub fn upstream_of(&self, index: usize) -> Vec<usize> {
        let mut found: Vec<usize> = Vec::new();
        let mut frontier = vec![index];
        while let Some(node) = frontier.pop() {
            for edge in self.edges.iter().filter(|e| e.to_node == node) {
                if edge.from_node != index && !found.contains(&edge.from_node) {
                    found.push(edge.from_node);
                    frontier.push(edge.from_node);
                }
            }
        }
        found
    }

    /// A readable listing of nodes (with resolved parameters) and edges, for `bevworld check`.
    pub fn describe(&self) -> String {
        use std::fmt::Write as _;
        let mut out = String::new();
        let _ = writeln!(
            out,
            "graph '{}' ({}): {} nodes, {} edges",
            self.name,
            self.file,
            self.nodes.len(),
            self.edges.len()
        );
        for (name, bundle) in self.models.bundles() {
            let _ = writeln!(out, "  models {name}: {bundle}");
        }
        for (name, targets) in &self.interface.params {
            let targets: Vec<String> = targets
                .iter()
                .map(|t| format!("{}.{}", t.node, t.key))
                .collect();
            let _ = writeln!(out, "  exposes parameter {name} = {}", targets.join(", "));
        }
        for (name, output) in &self.interface.outputs {
            let node = &self.nodes[output.node];
            let _ = writeln!(
                out,
                "  exposes output {name} = {}.{}",
                node.id, node.kind.outputs[output.port].name
            );
        }
        for node in &self.nodes {
            let _ = writeln!(
                out,
                "  node {} [{} {}]",
                node.id,
                node.kind.role.as_str(),
                node.kind.name
            );
            let _ = writeln!(out, "    params: {}", node.params);
            if node.kind.role == Role::Source {
                let _ = writeln!(out, "    pacing: {}", node.pacing.describe());
            }
            if node.kind.inputs.len() > 1 {
                let _ = writeln!(
                    out,
                    "    sync: {:?}, align_tolerance_us: {}",
                    node.sync, node.align_tolerance_us
                );
            }
            let _ = writeln!(out, "    on_error: {:?}", node.on_error);
        }
        for edge in &self.edges {
            let (from, to) = self.edge_label(edge);
            let ty = self.nodes[edge.from_node].kind.outputs[edge.from_port]
                .ty
                .name();
            let _ = writeln!(
                out,
                "  edge {from} -> {to} [{ty}, capacity {}, {}]",
                edge.capacity,
                edge.policy.as_str()
            );
        }
        out
    }
}

impl ValidatedGraph {
    /// Builds every node (loading what each needs); the problems of all nodes are reported
    /// together, pointing at their parameters.
    pub fn build(self) -> Result<ResolvedGraph, Diagnostics> {
        let mut finder = Finder {
            file: &self.spec.file,
            found: Vec::new(),
        };
        let mut nodes = Vec::with_capacity(self.pending.len());
        for ((checked, locations), spec) in self.pending.into_iter().zip(&self.spec.nodes) {
            match checked.build(&self.spec.models) {
                Ok(node) => nodes.push(node),
                Err(error) => {
                    param_problem(&mut finder, spec.kind.name, &spec.id, error, &locations)
                }
            }
        }
        if !finder.found.is_empty() {
            return Err(Diagnostics(finder.found));
        }
        Ok(ResolvedGraph {
            spec: self.spec,
            nodes,
        })
    }
}

/// A `--set` that is not `target=value`.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum OverrideError {
    #[error("'{0}' is not node.key=value (or name=value for a parameter the graph exposes)")]
    NoValue(String),
    #[error("'{0}' is not node.key, models.bundle.key or an exposed parameter's name")]
    NoKey(String),
    /// A value a graph file would refuse in the same place (`.nan`, `.inf`): refused here too,
    /// in the same words, rather than read as text.
    #[error("{target}={value}: {message}")]
    Value {
        target: String,
        value: String,
        message: String,
    },
}

/// What a `--set` changes.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum OverrideTarget {
    /// `node.key`: a parameter (`data`, `grid.size`) or `pacing.rate_hz`, `pacing.speed`,
    /// `on_error`.
    Node { node: String, key: String },
    /// `models.bundle.key`: a file of a model bundle, for every node that runs it.
    Model { bundle: String, key: String },
    /// `name`: a parameter the graph exposes in its `interface:`, whichever node holds it.
    Exposed(String),
}

/// The node id that names the `models:` section in a `--set`; no node may take it.
pub const MODELS_TARGET: &str = "models";

/// One `--set target=value` override.
#[derive(Clone, Debug)]
pub struct Override {
    pub target: OverrideTarget,
    pub value: serde_json::Value,
}

impl Override {
    /// Parses `node.key=value`, `models.bundle.key=value` or `name=value`; the value is read as
    /// YAML (`12`, `true`, `[1, 2]`, `text`), as the graph file reads a parameter: what the
    /// file refuses (a non-finite number) is refused here too, and a value that is not YAML at
    /// all is the text the user typed.
    pub fn parse(text: &str) -> Result<Self, OverrideError> {
        let (target, value) = text
            .split_once('=')
            .ok_or_else(|| OverrideError::NoValue(text.to_string()))?;
        let no_key = || OverrideError::NoKey(target.to_string());
        let parsed_target = match target.split_once('.') {
            None if is_name(target) => OverrideTarget::Exposed(target.to_string()),
            None => return Err(no_key()),
            Some((MODELS_TARGET, rest)) => {
                let (bundle, key) = rest.split_once('.').ok_or_else(no_key)?;
                if bundle.is_empty() || key.is_empty() {
                    return Err(no_key());
                }
                OverrideTarget::Model {
                    bundle: bundle.to_string(),
                    key: key.to_string(),
                }
            }
            Some((node, key)) if !node.is_empty() && !key.is_empty() => OverrideTarget::Node {
                node: node.to_string(),
                key: key.to_string(),
            },
            Some(_) => return Err(no_key()),
        };
        Ok(Self {
            target: parsed_target,
            value: parse_value(target, value)?,
        })
    }

    /// The override of node `id`'s parameter `key`, if this is one.
    fn of_node(&self, id: &str) -> Option<&str> {
        match &self.target {
            OverrideTarget::Node { node, key } if node == id => Some(key),
            _ => None,
        }
    }
}

/// A parameter name: letters, digits and `_`.
fn is_name(text: &str) -> bool {
    !text.is_empty() && text.chars().all(|c| c.is_ascii_alphanumeric() || c == '_')
}

fn parse_value(target: &str, value: &str) -> Result<serde_json::Value, OverrideError> {
    if value.trim().is_empty() {
        return Ok(serde_json::Value::String(String::new()));
    }
    match serde_saphyr::from_str::<serde_json::Value>(value) {
        // YAML would read `/tmp/x #2` as `/tmp/x` and a comment: a value on the command line
        // is the text the user typed.
        Ok(serde_json::Value::String(_))
            if value.contains(" #") && !value.trim_start().starts_with(['"', '\'']) =>
        {
            Ok(serde_json::Value::String(value.to_string()))
        }
        Ok(parsed) => Ok(parsed),
        Err(error)
            if matches!(
                error.without_snippet(),
                serde_saphyr::Error::NonFiniteFloat { .. }
            ) =>
        {
            Err(OverrideError::Value {
                target: target.to_string(),
                value: value.to_string(),
                message: crate::yaml::describe(&error),
            })
        }
        Err(_) => Ok(serde_json::Value::String(value.to_string())),
    }
}

pub(crate) struct Finder<'a> {
    file: &'a str,
    found: Vec<Diagnostic>,
}

/// The most messages an edge may queue: a bound on a graph's memory, far above what any
/// graph needs (a queue holds shared payloads, but each can be a frame of six images).
pub const MAX_CAPACITY: usize = 100_000;

impl Finder<'_> {
    /// A problem at a line found by other means than the parser's spans.
    fn at_line(&mut self, line: Option<usize>, message: impl Into<String>, hint: Option<String>) {
        self.found.push(Diagnostic {
            file: self.file.to_string(),
            position: line.map(|line| Position {
                line: line as u64,
                column: 1,
            }),
            message: message.into(),
            hint,
        });
    }

    pub(crate) fn at(
        &mut self,
        location: Option<Location>,
        message: impl Into<String>,
        hint: Option<String>,
    ) {
        let position = location
            .filter(|l| *l != Location::UNKNOWN)
            .map(|l| Position {
                line: l.line(),
                column: l.column(),
            });
        self.found.push(Diagnostic {
            file: self.file.to_string(),
            position,
            message: message.into(),
            hint,
        });
    }
}

pub(crate) fn loc<T>(spanned: &Spanned<T>) -> Option<Location> {
    Some(spanned.referenced)
}

/// Reports a parameter problem of node `id` at the key it names (or the params block).
fn param_problem(
    finder: &mut Finder,
    kind: &str,
    id: &str,
    error: crate::registry::ParamError,
    locations: &ParamLocations,
) {
    let top = error
        .field
        .as_deref()
        .map(|f| f.split('.').next().unwrap_or(f).to_string());
    let location = top
        .as_ref()
        .and_then(|f| locations.keys.get(f).copied())
        .or(locations.block);
    let field = error.field.clone().unwrap_or_else(|| "params".into());
    finder.at(
        location,
        format!(
            "bad parameter '{field}' of node '{id}' ({kind}): {}",
            error.message
        ),
        error
            .accepted
            .map(|accepted| format!("accepted: {accepted}")),
    );
}

/// Parses and validates a graph file's text, reporting every problem at once. Nothing is
/// built: `ValidatedGraph::build` does that. `file` names the file in diagnostics.
pub fn validate(
    text: &str,
    file: &str,
    registry: &Registry,
    overrides: &[Override],
) -> Result<ValidatedGraph, Diagnostics> {
    let mut finder = Finder {
        file,
        found: Vec::new(),
    };
    let parsed: GraphFile = match serde_saphyr::from_str(text) {
        Ok(parsed) => parsed,
        Err(error) => {
            let message = crate::yaml::describe(&error);
            finder.at(error.location(), format!("malformed graph file: {message}"), Some(
                "a graph has `nodes:` (each with id, kind, params) and `edges:` (each with from: node.port, to: node.port)".into(),
            ));
            return Err(Diagnostics(finder.found));
        }
    };
    let capacity = parsed.settings.default_capacity;
    if !(1..=MAX_CAPACITY).contains(&capacity) {
        let line = text
            .lines()
            .position(|l| l.contains("default_capacity"))
            .map(|i| i + 1);
        finder.at_line(
            line,
            format!("settings.default_capacity {capacity} is out of range"),
            Some(format!("accepted: 1 to {MAX_CAPACITY} messages")),
        );
    }
    let declared = DeclaredNodes::index(&mut finder, &parsed);
    let overrides = crate::interface::resolve_overrides(&mut finder, &parsed, overrides);
    let models = Arc::new(check_models(&mut finder, registry, &parsed, &overrides));
    let mut nodes = Vec::new();
    for (index, decl) in parsed.nodes.iter().enumerate() {
        if declared.first_of(&decl.value.id.value) == Some(index) {
            nodes.push(check_node(
                &mut finder,
                registry,
                &decl.value,
                &overrides,
                &models,
            ));
        }
    }
    check_override_targets(&mut finder, &overrides, &declared.ids);
    let edges = check_edges(&mut finder, registry, &parsed, &declared);
    if let Some(cycle) = find_cycle(declared.ids.len(), &edges) {
        let names: Vec<&str> = cycle.iter().map(|&i| declared.ids[i].as_str()).collect();
        let first = declared.decl(&parsed, names[0]).map(|d| d.id.referenced);
        finder.at(first, format!("cycle: {} -> {}", names.join(" -> "), names[0]), Some("graphs must be acyclic; keep state inside a node (e.g. a history buffer) instead of feeding outputs back".into()));
    }
    if parsed.nodes.is_empty() {
        finder.at(None, "the graph has no nodes", None);
    }
    if !finder.found.is_empty() {
        return Err(Diagnostics(finder.found));
    }
    let (specs, pending): (Vec<NodeSpec>, Vec<(Checked, ParamLocations)>) = nodes
        .into_iter()
        .flatten()
        .map(|(spec, checked, locations)| (spec, (checked, locations)))
        .unzip();
    let interface = crate::interface::check(&mut finder, &parsed, &specs);
    if !finder.found.is_empty() {
        return Err(Diagnostics(finder.found));
    }
    let spec = GraphSpec {
        name: parsed.name.unwrap_or_else(|| file.to_string()),
        file: file.to_string(),
        settings: parsed.settings,
        nodes: specs,
        edges,
        models,
        interface,
    };
    for rule in registry.rules() {
        for problem in rule(&spec) {
            let Some(index) = spec.nodes.iter().position(|n| n.id == problem.node) else {
                finder.at(None, problem.error.message, problem.error.accepted);
                continue;
            };
            let node = &spec.nodes[index];
            param_problem(
                &mut finder,
                node.kind.name,
                &node.id,
                problem.error,
                &pending[index].1,
            );
        }
    }
    if !finder.found.is_empty() {
        return Err(Diagnostics(finder.found));
    }
    Ok(ValidatedGraph { spec, pending })
}

/// Validates and builds a graph: what `run` needs.
pub fn resolve(
    text: &str,
    file: &str,
    registry: &Registry,
    overrides: &[Override],
) -> Result<ResolvedGraph, Diagnostics> {
    validate(text, file, registry, overrides)?.build()
}

/// The declared node ids in order (duplicates reported and left out), and each id's first
/// declaration.
struct DeclaredNodes {
    ids: Vec<String>,
    index: HashMap<String, usize>,
    first: HashMap<String, usize>,
}

impl DeclaredNodes {
    fn index(finder: &mut Finder, parsed: &GraphFile) -> Self {
        let mut nodes = DeclaredNodes {
            ids: Vec::new(),
            index: HashMap::new(),
            first: HashMap::new(),
        };
        for (position, decl) in parsed.nodes.iter().enumerate() {
            let decl = &decl.value;
            let id = decl.id.value.clone();
            if id.is_empty() || id.contains('.') || id == MODELS_TARGET {
                finder.at(
                    loc(&decl.id),
                    format!("node id '{id}' is not valid"),
                    Some(format!(
                        "ids are non-empty, have no '.', and are not '{MODELS_TARGET}' (which `--set models.*` names)"
                    )),
                );
            }
            if nodes.index.contains_key(&id) {
                finder.at(
                    loc(&decl.id),
                    format!("duplicate node id '{id}'"),
                    Some("every node needs its own id".into()),
                );
                continue;
            }
            nodes.index.insert(id.clone(), nodes.ids.len());
            nodes.first.insert(id.clone(), position);
            nodes.ids.push(id);
        }
        nodes
    }

    /// The declaration position of the first node with this id.
    fn first_of(&self, id: &str) -> Option<usize> {
        self.first.get(id).copied()
    }

    fn decl<'a>(&self, parsed: &'a GraphFile, id: &str) -> Option<&'a NodeDecl> {
        self.first_of(id)
            .and_then(|i| parsed.nodes.get(i))
            .map(|d| &d.value)
    }

    fn kind<'r>(
        &self,
        parsed: &GraphFile,
        registry: &'r Registry,
        id: &str,
    ) -> Option<&'r NodeKind> {
        self.decl(parsed, id)
            .and_then(|d| registry.get(&d.kind.value))
    }
}

/// One node: its kind, its parameters with `--set` applied and checked, its pacing, sync and
/// tolerance. `None` when a problem was reported.
fn check_node(
    finder: &mut Finder,
    registry: &Registry,
    decl: &NodeDecl,
    overrides: &[Override],
    models: &Models,
) -> Option<(NodeSpec, Checked, ParamLocations)> {
    let id = decl.id.value.clone();
    let Some(kind) = registry.get(&decl.kind.value) else {
        let hint = match closest(&decl.kind.value, registry.names()) {
            Some(near) => format!(
                "did you mean '{near}'? known kinds: {}",
                registry.names().collect::<Vec<_>>().join(", ")
            ),
            None => format!(
                "known kinds: {}",
                registry.names().collect::<Vec<_>>().join(", ")
            ),
        };
        finder.at(
            loc(&decl.kind),
            format!("unknown node kind '{}' for node '{id}'", decl.kind.value),
            Some(hint),
        );
        return None;
    };

    // Parameters, with `--set` overrides applied.
    let mut params = serde_json::Map::new();
    let mut locations = ParamLocations {
        keys: BTreeMap::new(),
        block: decl
            .params
            .as_ref()
            .map(|p| p.referenced)
            .or(Some(decl.kind.referenced)),
    };
    if let Some(map) = &decl.params {
        for (key, value) in &map.value {
            params.insert(key.clone(), value.value.clone());
            locations.keys.insert(key.clone(), value.referenced);
        }
    }
    // A `--set` of part of a nested parameter merges into its value as the file resolves it,
    // defaults included, so that `grid.pillar_size=0.5` keeps the default grid's ranges.
    let has_param_override = overrides
        .iter()
        .filter_map(|o| o.of_node(&id))
        .any(|key| !key.starts_with("pacing.") && key != "on_error");
    if has_param_override
        && let Ok(checked) = kind.check(&serde_json::Value::Object(params.clone()), models)
        && let serde_json::Value::Object(resolved) = checked.resolved_params
    {
        for (key, value) in resolved {
            params.entry(key).or_insert(value);
        }
    }
    let mut pacing_decl = decl.pacing.as_ref().map(|p| p.value).unwrap_or_default();
    let mut pacing_overridden = false;
    let mut on_error = decl.on_error.as_ref().map(|o| o.value).unwrap_or_default();
    for (key, over) in overrides
        .iter()
        .filter_map(|o| o.of_node(&id).map(|key| (key, o)))
    {
        match key {
            key @ ("pacing.speed" | "pacing.rate_hz") => {
                let Some(value) = over.value.as_f64() else {
                    finder.at(
                        None,
                        format!("--set {id}.{key}: '{}' is not a number", over.value),
                        Some("e.g. --set source.pacing.rate_hz=12".into()),
                    );
                    continue;
                };
                pacing_overridden = true;
                pacing_decl = if key == "pacing.speed" {
                    crate::schema::PacingDecl {
                        speed: Some(value),
                        rate_hz: None,
                    }
                } else {
                    crate::schema::PacingDecl {
                        speed: None,
                        rate_hz: Some(value),
                    }
                };
            }
            "on_error" => match serde_json::from_value::<OnError>(over.value.clone()) {
                Ok(value) => on_error = value,
                Err(_) => finder.at(
                    None,
                    format!("--set {id}.on_error: '{}' is not accepted", over.value),
                    Some("accepted: stop, skip".into()),
                ),
            },
            key => set_path(&mut params, key, over.value.clone()),
        }
    }
    // A node naming a bundle whose own check failed is not refused again for it.
    let names_refused_bundle = params
        .get(crate::models::MODEL_FIELD)
        .and_then(serde_json::Value::as_str)
        .is_some_and(|name| models.is_refused(name));
    let checked = match kind.check(&serde_json::Value::Object(params), models) {
        Ok(checked) => Some(checked),
        Err(error)
            if names_refused_bundle
                && error.field.as_deref() == Some(crate::models::MODEL_FIELD) =>
        {
            None
        }
        Err(error) => {
            param_problem(finder, kind.name, &id, error, &locations);
            None
        }
    };

    let pacing = match Pacing::from_decl(&pacing_decl) {
        Ok(pacing) => pacing,
        Err(error) => {
            finder.at(decl.pacing.as_ref().and_then(loc), format!("node '{id}': {error}"), Some("use `pacing: {speed: 1.0}` (0 = as fast as possible) or `pacing: {rate_hz: 12}`".into()));
            Pacing::Unpaced
        }
    };
    if pacing_overridden && kind.role != Role::Source {
        finder.at(
            None,
            format!(
                "--set {id}.pacing: node '{id}' is a {}, and only sources are paced",
                kind.role.as_str()
            ),
            Some("set pacing on the graph's source, e.g. --set source.pacing.rate_hz=12".into()),
        );
    }
    if decl.pacing.is_some() && kind.role != Role::Source {
        finder.at(
            decl.pacing.as_ref().and_then(loc),
            format!(
                "node '{id}' is a {}, only sources are paced",
                kind.role.as_str()
            ),
            None,
        );
    }
    let tolerance = decl
        .align_tolerance_us
        .as_ref()
        .map(|t| t.value)
        .unwrap_or(0);
    if tolerance < 0 {
        finder.at(
            decl.align_tolerance_us.as_ref().and_then(loc),
            format!("node '{id}': align_tolerance_us must be >= 0, got {tolerance}"),
            None,
        );
    }
    let checked = checked?;
    let spec = NodeSpec {
        id,
        kind: kind.clone(),
        params: checked.resolved_params.clone(),
        on_error,
        pacing,
        sync: decl
            .sync
            .as_ref()
            .map(|s| s.value)
            .unwrap_or(kind.default_sync),
        align_tolerance_us: tolerance.max(0),
    };
    Some((spec, checked, locations))
}

/// Every `node.key` `--set` must name a node of the graph.
fn check_override_targets(finder: &mut Finder, overrides: &[Override], node_ids: &[String]) {
    for over in overrides {
        let OverrideTarget::Node { node, .. } = &over.target else {
            continue;
        };
        if !node_ids.contains(node) {
            let hint = closest(node, node_ids.iter().map(String::as_str))
                .map(|near| format!("did you mean '{near}'?"));
            finder.at(
                None,
                format!("--set names node '{node}', which the graph does not have"),
                hint,
            );
        }
    }
}

/// The `models:` section with its `--set models.*` overrides, each bundle checked by the
/// application's bundle check; a problem points at the bundle's key it names.
fn check_models(
    finder: &mut Finder,
    registry: &Registry,
    parsed: &GraphFile,
    overrides: &[Override],
) -> Models {
    let mut bundles = BTreeMap::new();
    let mut refused = Vec::new();
    for over in overrides {
        if let OverrideTarget::Model { bundle, key } = &over.target
            && !parsed.models.contains_key(bundle)
        {
            let names = parsed.models.keys().map(String::as_str);
            finder.at(
                None,
                format!("--set models.{bundle}.{key}: the graph has no model bundle '{bundle}'"),
                closest(bundle, names).map(|near| format!("did you mean '{near}'?")),
            );
        }
    }
    for (name, declared) in &parsed.models {
        let mut raw = serde_json::Map::new();
        let mut keys = BTreeMap::new();
        for (key, value) in &declared.value {
            raw.insert(key.clone(), value.value.clone());
            keys.insert(key.clone(), value.referenced);
        }
        for over in overrides {
            if let OverrideTarget::Model { bundle, key } = &over.target
                && bundle == name
            {
                set_path(&mut raw, key, over.value.clone());
            }
        }
        match registry.check_bundle(&serde_json::Value::Object(raw)) {
            Ok(resolved) => {
                bundles.insert(name.clone(), resolved);
            }
            Err(problems) => {
                refused.push(name.clone());
                for problem in problems {
                    let top = problem
                        .field
                        .as_deref()
                        .map(|f| f.split('.').next().unwrap_or(f));
                    let location = top
                        .and_then(|top| keys.get(top).copied())
                        .or(Some(declared.referenced));
                    let field = problem.field.as_deref().unwrap_or("bundle");
                    finder.at(
                        location,
                        format!("model bundle '{name}', '{field}': {}", problem.message),
                        problem.accepted.map(|a| format!("accepted: {a}")),
                    );
                }
            }
        }
    }
    let mut models = Models::new(bundles);
    for name in refused {
        models.refuse(&name);
    }
    models
}

/// Edges: endpoints exist, types agree, capacities are positive; then every required input
/// must be connected.
fn check_edges(
    finder: &mut Finder,
    registry: &Registry,
    parsed: &GraphFile,
    declared: &DeclaredNodes,
) -> Vec<ResolvedEdge> {
    let node_ids = &declared.ids;
    let kind_of = |id: &str| declared.kind(parsed, registry, id);
    // Inputs that some edge names, valid or not: a broken edge is one problem, not two.
    let mut connected: Vec<Vec<bool>> = node_ids
        .iter()
        .map(|id| {
            kind_of(id)
                .map(|k| vec![false; k.inputs.len()])
                .unwrap_or_default()
        })
        .collect();
    let mut edges = Vec::new();
    for edge in &parsed.edges {
        let edge = &edge.value;
        let from = endpoint(finder, &edge.from, &declared.index, node_ids);
        let to = endpoint(finder, &edge.to, &declared.index, node_ids);
        let (Some((from_node, from_port_name)), Some((to_node, to_port_name))) = (from, to) else {
            continue;
        };
        let (Some(from_kind), Some(to_kind)) =
            (kind_of(&node_ids[from_node]), kind_of(&node_ids[to_node]))
        else {
            continue;
        };
        let from_port = port_of(
            finder,
            &edge.from,
            from_kind,
            &node_ids[from_node],
            &from_port_name,
            false,
        );
        let to_port = port_of(
            finder,
            &edge.to,
            to_kind,
            &node_ids[to_node],
            &to_port_name,
            true,
        );
        if let Some((index, _)) = to_port {
            connected[to_node][index] = true;
        }
        let (Some((from_port, from_spec)), Some((to_port, to_spec))) = (from_port, to_port) else {
            continue;
        };
        if from_spec.ty != to_spec.ty {
            finder.at(
                loc(&edge.to),
                format!(
                    "port type mismatch: {} carries {} but {} takes {}",
                    edge.from.value,
                    from_spec.ty.name(),
                    edge.to.value,
                    to_spec.ty.name()
                ),
                Some("connect ports that carry the same message type".into()),
            );
            continue;
        }
        let capacity_requested = edge
            .capacity
            .as_ref()
            .map(|c| c.value)
            .unwrap_or(parsed.settings.default_capacity);
        // A default capacity out of range is reported once, for the setting.
        if let Some(capacity) = &edge.capacity
            && !(1..=MAX_CAPACITY).contains(&capacity.value)
        {
            finder.at(
                loc(capacity),
                format!("edge capacity {} is out of range", capacity.value),
                Some(format!("accepted: 1 to {MAX_CAPACITY} messages")),
            );
        }
        let policy = edge
            .policy
            .as_ref()
            .map(|p| p.value)
            .unwrap_or(parsed.settings.default_policy);
        // The same edge twice would deliver every message twice: every forecast computed,
        // written and scored twice over, silently.
        if edges.iter().any(|e: &ResolvedEdge| {
            (e.from_node, e.from_port, e.to_node, e.to_port)
                == (from_node, from_port, to_node, to_port)
        }) {
            finder.at(
                loc(&edge.from),
                format!(
                    "edge {} -> {} is written twice",
                    edge.from.value, edge.to.value
                ),
                Some("each edge once: a second copy would deliver every message twice".into()),
            );
            continue;
        }
        edges.push(ResolvedEdge {
            from_node,
            from_port,
            to_node,
            to_port,
            capacity: policy.effective_capacity(capacity_requested),
            policy,
        });
    }
    for (index, id) in node_ids.iter().enumerate() {
        let Some(kind) = kind_of(id) else {
            continue;
        };
        for (port_index, port) in kind.inputs.iter().enumerate() {
            if port.required && !connected[index][port_index] {
                finder.at(
                    declared.decl(parsed, id).map(|d| d.id.referenced),
                    format!(
                        "required input '{id}.{}' ({}) is not connected",
                        port.name,
                        port.ty.name()
                    ),
                    Some(format!(
                        "add an edge `{{from: <node>.<port>, to: {id}.{}}}`",
                        port.name
                    )),
                );
            }
        }
    }
    edges
}

fn endpoint(
    finder: &mut Finder,
    spanned: &Spanned<String>,
    ids: &HashMap<String, usize>,
    node_ids: &[String],
) -> Option<(usize, String)> {
    let Some((node, port)) = spanned.value.split_once('.') else {
        finder.at(
            loc(spanned),
            format!("edge endpoint '{}' is not node.port", spanned.value),
            Some("write endpoints as `node_id.port_name`".into()),
        );
        return None;
    };
    match ids.get(node) {
        Some(&index) => Some((index, port.to_string())),
        None => {
            let hint = match closest(node, node_ids.iter().map(String::as_str)) {
                Some(near) => format!("did you mean '{near}'?"),
                None => format!("nodes: {}", node_ids.join(", ")),
            };
            finder.at(
                loc(spanned),
                format!("edge names unknown node '{node}'"),
                Some(hint),
            );
            None
        }
    }
}

/// The output (or, with `input`, the input) port `name` of node `id`, or a problem at `spanned`.
fn port_of<'k>(
    finder: &mut Finder,
    spanned: &Spanned<String>,
    kind: &'k NodeKind,
    id: &str,
    name: &str,
    input: bool,
) -> Option<(usize, &'k crate::port::PortSpec)> {
    let (found, direction, ports) = if input {
        (kind.input_port(name), "input", &kind.inputs)
    } else {
        (kind.output_port(name), "output", &kind.outputs)
    };
    if found.is_none() {
        finder.at(
            loc(spanned),
            format!(
                "node '{id}' ({}) has no {direction} port '{name}'",
                kind.name
            ),
            Some(port_list(&format!("{direction}s"), ports)),
        );
    }
    found
}

fn port_list(what: &str, ports: &[crate::port::PortSpec]) -> String {
    if ports.is_empty() {
        return format!("it has no {what}");
    }
    let names: Vec<String> = ports
        .iter()
        .map(|p| format!("{} ({})", p.name, p.ty.name()))
        .collect();
    format!("{what}: {}", names.join(", "))
}

fn set_path(
    params: &mut serde_json::Map<String, serde_json::Value>,
    path: &str,
    value: serde_json::Value,
) {
    match path.split_once('.') {
        None => {
            params.insert(path.to_string(), value);
        }
        Some((head, rest)) => {
            let entry = params
                .entry(head.to_string())
                .or_insert_with(|| serde_json::Value::Object(Default::default()));
            if !entry.is_object() {
                *entry = serde_json::Value::Object(Default::default());
            }
            if let serde_json::Value::Object(inner) = entry {
                set_path(inner, rest, value);
            }
        }
    }
}

/// A cycle as a list of node indices, if the edges have one.
fn find_cycle(count: usize, edges: &[ResolvedEdge]) -> Option<Vec<usize>> {
    let mut next: Vec<Vec<usize>> = vec![Vec::new(); count];
    for edge in edges {
        next[edge.from_node].push(edge.to_node);
    }
    // 0 = unvisited, 1 = on the stack, 2 = done.
    let mut state = vec![0u8; count];
    let mut stack: Vec<usize> = Vec::new();
    fn visit(
        node: usize,
        next: &[Vec<usize>],
        state: &mut [u8],
        stack: &mut Vec<usize>,
    ) -> Option<Vec<usize>> {
        state[node] = 1;
        stack.push(node);
        for &succ in &next[node] {
            if state[succ] == 1 {
                let start = stack.iter().position(|&n| n == succ).unwrap_or(0);
                return Some(stack[start..].to_vec());
            }
            if state[succ] == 0
                && let Some(cycle) = visit(succ, next, state, stack)
            {
                return Some(cycle);
            }
        }
        stack.pop();
        state[node] = 2;
        None
    }
    for start in 0..count {
        if state[start] == 0
            && let Some(cycle) = visit(start, &next, &mut state, &mut stack)
        {
            return Some(cycle);
        }
    }
    None
}
