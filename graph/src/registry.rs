//! Node kinds, registered by the application. The runtime knows kinds only by name, ports and a
//! typed-parameter builder, so `graph/` stays free of sensor and model types.

use std::collections::BTreeMap;
use std::sync::Arc;

use serde::Serialize;
use serde::de::DeserializeOwned;

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

type Builder = dyn Fn(&serde_json::Value) -> Result<Built, ParamError> + Send + Sync;

/// A node built from its parameters, with the parameters as resolved (defaults filled in).
pub struct Built {
    pub node: Node,
    pub resolved_params: serde_json::Value,
}

/// One registered node kind.
#[derive(Clone)]
pub struct NodeKind {
    pub name: &'static str,
    pub summary: &'static str,
    pub role: Role,
    pub inputs: Vec<PortSpec>,
    pub outputs: Vec<PortSpec>,
    /// How several inputs are grouped unless the graph says otherwise.
    pub default_sync: SyncMode,
    builder: Arc<Builder>,
}

impl NodeKind {
    pub fn build(&self, params: &serde_json::Value) -> Result<Built, ParamError> {
        (self.builder)(params)
    }

    pub fn input(&self, name: &str) -> Option<(usize, &PortSpec)> {
        self.inputs
            .iter()
            .enumerate()
            .find(|(_, port)| port.name == name)
    }

    pub fn output(&self, name: &str) -> Option<(usize, &PortSpec)> {
        self.outputs
            .iter()
            .enumerate()
            .find(|(_, port)| port.name == name)
    }
}

/// The declaration part of a kind, before its builder is attached.
pub struct KindSpec {
    pub name: &'static str,
    pub summary: &'static str,
    pub role: Role,
    pub inputs: Vec<PortSpec>,
    pub outputs: Vec<PortSpec>,
    pub default_sync: SyncMode,
}

impl KindSpec {
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

/// All node kinds an application knows.
#[derive(Clone, Default)]
pub struct Registry {
    kinds: BTreeMap<&'static str, NodeKind>,
}

impl Registry {
    pub fn new() -> Self {
        Self::default()
    }

    /// Registers a kind whose parameters deserialize into `P`. `P` should use
    /// `#[serde(deny_unknown_fields)]` so a misspelt key is an error, not a silent default.
    pub fn register<P, F>(&mut self, spec: KindSpec, build: F)
    where
        P: DeserializeOwned + Serialize + 'static,
        F: Fn(P) -> Result<Node, ParamError> + Send + Sync + 'static,
    {
        let role = spec.role;
        let builder = move |raw: &serde_json::Value| -> Result<Built, ParamError> {
            let params: P = deserialize_params(raw)?;
            let resolved_params = serde_json::to_value(&params).unwrap_or(serde_json::Value::Null);
            let node = build(params)?;
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
            Ok(Built {
                node,
                resolved_params,
            })
        };
        self.kinds.insert(
            spec.name,
            NodeKind {
                name: spec.name,
                summary: spec.summary,
                role: spec.role,
                inputs: spec.inputs,
                outputs: spec.outputs,
                default_sync: spec.default_sync,
                builder: Arc::new(builder),
            },
        );
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
