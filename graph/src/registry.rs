//! Node kinds, registered by the application. The runtime knows kinds only by name, ports and a
//! typed-parameter builder, so `graph/` stays free of sensor and model types.

use std::collections::BTreeMap;
use std::sync::Arc;

use serde::Serialize;
use serde::de::DeserializeOwned;

use crate::models::Models;
use crate::node::{Node, Role};
use crate::port::PortSpec;
use crate::schema::SyncMode;

/// A parameter problem found while building a node.
#[derive(Clone, Debug)]
pub struct ParamError {
    /// The parameter at fault, when one is; validation points at its line.
    pub field: Option<String>,
    pub message: String,
    /// The accepted values or range, when they can be stated.
    pub accepted: Option<String>,
}

impl ParamError {
    pub fn field(field: impl Into<String>, message: impl Into<String>) -> Self {
        Self {
            field: Some(field.into()),
            message: message.into(),
            accepted: None,
        }
    }

    pub fn with_accepted(mut self, accepted: impl Into<String>) -> Self {
        self.accepted = Some(accepted.into());
        self
    }
}

type Checker = dyn Fn(&serde_json::Value, &Models) -> Result<Checked, ParamError> + Send + Sync;

/// What builds a checked node, from the graph's models.
type Builder = dyn FnOnce(&Models) -> Result<Node, ParamError> + Send;

/// The application's check of one bundle of the graph's `models:` section: the bundle as
/// resolved (defaults filled in), or every problem found, each naming its field
/// (`world_model.weights`).
type BundleChecker =
    dyn Fn(&serde_json::Value) -> Result<serde_json::Value, Vec<ParamError>> + Send + Sync;

/// A node's parameters, typed and checked, with the node not yet built: validation (`bevworld
/// check`) stops here, so it loads nothing, and `run` builds.
pub struct Checked {
    /// The parameters as resolved (defaults filled in).
    pub resolved_params: serde_json::Value,
    build: Box<Builder>,
}

impl Checked {
    /// Builds the node: opens what it needs (files; model weights through `models`, which
    /// loads each part once per graph).
    pub fn build(self, models: &Models) -> Result<Node, ParamError> {
        (self.build)(models)
    }
}

/// One registered node kind: its declaration (name, role, typed ports; `NodeKind` reads as
/// its `KindSpec`) and its parameter checker.
#[derive(Clone)]
pub struct NodeKind {
    spec: KindSpec,
    checker: Arc<Checker>,
}

impl std::ops::Deref for NodeKind {
    type Target = KindSpec;

    fn deref(&self) -> &KindSpec {
        &self.spec
    }
}

impl NodeKind {
    /// Types and checks `params` without building the node; `models` are the graph's bundles,
    /// which a node that runs a model must name.
    pub fn check(
        &self,
        params: &serde_json::Value,
        models: &Models,
    ) -> Result<Checked, ParamError> {
        (self.checker)(params, models)
    }

    /// A kind the runtime adds itself (a command's collector), never named by a graph file.
    pub(crate) fn internal(spec: KindSpec) -> Self {
        let name = spec.name;
        Self {
            spec,
            checker: Arc::new(move |_: &serde_json::Value, _: &Models| {
                Err(ParamError {
                    field: None,
                    message: format!(
                        "'{name}' is added by the runtime, not built from a graph file"
                    ),
                    accepted: None,
                })
            }),
        }
    }

    /// Checks `params` and builds the node at once, for code that makes one node by itself.
    pub fn build(&self, params: &serde_json::Value) -> Result<Node, ParamError> {
        self.build_with(params, &Models::none())
    }

    /// As `build`, with model bundles to load from.
    pub fn build_with(
        &self,
        params: &serde_json::Value,
        models: &Models,
    ) -> Result<Node, ParamError> {
        self.check(params, models)?.build(models)
    }
}

/// The declaration part of a kind, before its builder is attached.
#[derive(Clone)]
pub struct KindSpec {
    pub name: &'static str,
    pub summary: &'static str,
    pub role: Role,
    pub inputs: Vec<PortSpec>,
    pub outputs: Vec<PortSpec>,
    /// How several inputs are grouped unless the graph says otherwise.
    pub default_sync: SyncMode,
}

impl KindSpec {
    /// The input port `name` and its index.
    pub fn input_port(&self, name: &str) -> Option<(usize, &PortSpec)> {
        self.inputs
            .iter()
            .enumerate()
            .find(|(_, port)| port.name == name)
    }

    /// The output port `name` and its index.
    pub fn output_port(&self, name: &str) -> Option<(usize, &PortSpec)> {
        self.outputs
            .iter()
            .enumerate()
            .find(|(_, port)| port.name == name)
    }

    pub fn source(name: &'static str, summary: &'static str) -> Self {
        Self {
            name,
            summary,
            role: Role::Source,
            inputs: Vec::new(),
            outputs: Vec::new(),
            default_sync: SyncMode::Aligned,
        }
    }

    pub fn task(name: &'static str, summary: &'static str) -> Self {
        Self {
            role: Role::Task,
            ..Self::source(name, summary)
        }
    }

    pub fn sink(name: &'static str, summary: &'static str) -> Self {
        Self {
            role: Role::Sink,
            ..Self::source(name, summary)
        }
    }

    pub fn input(mut self, port: PortSpec) -> Self {
        self.inputs.push(port);
        self
    }

    pub fn output(mut self, port: PortSpec) -> Self {
        self.outputs.push(port);
        self
    }

    pub fn sync(mut self, mode: SyncMode) -> Self {
        self.default_sync = mode;
        self
    }
}

/// A problem a graph rule finds: the node and parameter it points at.
#[derive(Clone, Debug)]
pub struct RuleProblem {
    /// The node id.
    pub node: String,
    pub error: ParamError,
}

/// A check of the whole graph, for what no one node can see: how kinds of different families
/// fit together (a sink that writes one method's renders must be fed that method).
pub type GraphRule = dyn Fn(&crate::validate::GraphSpec) -> Vec<RuleProblem> + Send + Sync;

/// All node kinds an application knows, and the rules its graphs must keep.
#[derive(Clone, Default)]
pub struct Registry {
    kinds: BTreeMap<&'static str, NodeKind>,
    rules: Vec<Arc<GraphRule>>,
    bundles: Option<Arc<BundleChecker>>,
}

impl Registry {
    pub fn new() -> Self {
        Self::default()
    }

    /// Registers a kind whose parameters deserialize into `P`, which the node is built from.
    /// `P` should use `#[serde(deny_unknown_fields)]` so a misspelt key is an error, not a
    /// silent default. Validation checks that the parameters deserialize; `build` runs only
    /// when the graph runs.
    pub fn register<P, F>(&mut self, spec: KindSpec, build: F)
    where
        P: DeserializeOwned + Serialize + Send + 'static,
        F: Fn(P) -> Result<Node, ParamError> + Send + Sync + 'static,
    {
        self.register_checked(spec, |_: &P| Ok(()), build);
    }

    /// As `register`, with `check` run at validation on the typed parameters: the problems a
    /// user should hear of from `bevworld check`, found without opening anything heavy.
    pub fn register_checked<P, C, F>(&mut self, spec: KindSpec, check: C, build: F)
    where
        P: DeserializeOwned + Serialize + Send + 'static,
        C: Fn(&P) -> Result<(), ParamError> + Send + Sync + 'static,
        F: Fn(P) -> Result<Node, ParamError> + Send + Sync + 'static,
    {
        self.register_with_models(
            spec,
            move |params: &P, _: &Models| check(params),
            move |params: P, _: &Models| build(params),
        );
    }

    /// As `register_checked`, for a kind that runs a model of the graph's `models:` section:
    /// `check` sees the bundles (`Models::require`), and `build` loads through them.
    pub fn register_with_models<P, C, F>(&mut self, spec: KindSpec, check: C, build: F)
    where
        P: DeserializeOwned + Serialize + Send + 'static,
        C: Fn(&P, &Models) -> Result<(), ParamError> + Send + Sync + 'static,
        F: Fn(P, &Models) -> Result<Node, ParamError> + Send + Sync + 'static,
    {
        let role = spec.role;
        let build = Arc::new(build);
        let checker = move |raw: &serde_json::Value,
                            models: &Models|
              -> Result<Checked, ParamError> {
            let params: P = deserialize_params(raw)?;
            check(&params, models)?;
            let resolved_params = serde_json::to_value(&params).unwrap_or(serde_json::Value::Null);
            let build = Arc::clone(&build);
            Ok(Checked {
                resolved_params,
                build: Box::new(move |models: &Models| {
                    let node = build(params, models)?;
                    if node.role() != role {
                        return Err(ParamError {
                            field: None,
                            message: format!(
                                "builder made a {} but the kind is a {}",
                                node.role().as_str(),
                                role.as_str()
                            ),
                            accepted: None,
                        });
                    }
                    Ok(node)
                }),
            })
        };
        self.kinds.insert(
            spec.name,
            NodeKind {
                spec,
                checker: Arc::new(checker),
            },
        );
    }

    /// Sets how a bundle of the graph's `models:` section is checked: it must deserialize into
    /// `S` (use `#[serde(deny_unknown_fields)]`), then pass `check`, which names each problem's
    /// field. Without it, a graph with a `models:` section is refused.
    pub fn models<S, C>(&mut self, check: C)
    where
        S: DeserializeOwned + Serialize + 'static,
        C: Fn(&S) -> Vec<ParamError> + Send + Sync + 'static,
    {
        self.bundles = Some(Arc::new(move |raw: &serde_json::Value| {
            let bundle: S = deserialize_params(raw).map_err(|error| vec![error])?;
            let problems = check(&bundle);
            if !problems.is_empty() {
                return Err(problems);
            }
            Ok(serde_json::to_value(&bundle).unwrap_or(serde_json::Value::Null))
        }));
    }

    /// Checks one bundle of a graph's `models:` section.
    pub fn check_bundle(
        &self,
        raw: &serde_json::Value,
    ) -> Result<serde_json::Value, Vec<ParamError>> {
        match &self.bundles {
            Some(check) => check(raw),
            None => Err(vec![ParamError {
                field: None,
                message: "this application registers no model bundles".into(),
                accepted: None,
            }]),
        }
    }

    /// Adds a rule every graph is checked against once its nodes and edges are valid; its
    /// problems are reported at the parameter they name, as a node's own are.
    pub fn rule(
        &mut self,
        rule: impl Fn(&crate::validate::GraphSpec) -> Vec<RuleProblem> + Send + Sync + 'static,
    ) {
        self.rules.push(Arc::new(rule));
    }

    pub fn rules(&self) -> impl Iterator<Item = &GraphRule> {
        self.rules.iter().map(|rule| rule.as_ref())
    }

    pub fn get(&self, name: &str) -> Option<&NodeKind> {
        self.kinds.get(name)
    }

    pub fn kinds(&self) -> impl Iterator<Item = &NodeKind> {
        self.kinds.values()
    }

    pub fn names(&self) -> impl Iterator<Item = &'static str> + '_ {
        self.kinds.keys().copied()
    }
}

/// Deserializes typed parameters, naming the field at fault and the values it accepts.
fn deserialize_params<P: DeserializeOwned>(raw: &serde_json::Value) -> Result<P, ParamError> {
    serde_path_to_error::deserialize::<_, P>(raw).map_err(|error| {
        let path = error.path().to_string();
        let message = error.inner().to_string();
        // serde reports an unknown key at its parent; name the key itself.
        let field = backticked_after(&message, "unknown field ")
            .or_else(|| (path != "." && !path.is_empty()).then(|| path.clone()))
            .or_else(|| backticked_after(&message, "missing field "));
        let accepted = message
            .split_once("expected one of ")
            .map(|(_, rest)| rest.to_string())
            .or_else(|| {
                message
                    .split_once("expected ")
                    .map(|(_, rest)| rest.to_string())
            });
        ParamError {
            field,
            message,
            accepted,
        }
    })
}

fn backticked_after(message: &str, marker: &str) -> Option<String> {
    let rest = message.split_once(marker)?.1;
    let rest = rest.strip_prefix('`')?;
    Some(rest.split('`').next()?.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde::Deserialize;

    #[derive(Debug, Deserialize, Serialize)]
    #[serde(deny_unknown_fields)]
    struct Params {
        rate: f64,
        #[serde(default)]
        mode: Mode,
    }

    #[derive(Debug, Default, Deserialize, Serialize)]
    #[serde(rename_all = "snake_case")]
    enum Mode {
        #[default]
        Fast,
        Exact,
    }

    #[test]
    fn unknown_key_names_the_key_and_the_accepted_ones() {
        let error =
            deserialize_params::<Params>(&serde_json::json!({"rate": 1.0, "rat": 2})).unwrap_err();
        assert_eq!(error.field.as_deref(), Some("rat"));
        assert!(error.accepted.unwrap().contains("rate"));
    }

    #[test]
    fn bad_enum_value_lists_the_variants() {
        let error = deserialize_params::<Params>(&serde_json::json!({"rate": 1.0, "mode": "slow"}))
            .unwrap_err();
        assert_eq!(error.field.as_deref(), Some("mode"));
        assert_eq!(error.accepted.as_deref(), Some("`fast` or `exact`"));
    }

    #[test]
    fn missing_key_is_named() {
        let error = deserialize_params::<Params>(&serde_json::json!({})).unwrap_err();
        assert_eq!(error.field.as_deref(), Some("rate"));
    }
}
