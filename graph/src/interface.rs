//! A graph's `interface:`: the parameters and outputs it exposes by name, and the contracts of
//! the commands that drive graphs through those names. A command never names a node: renaming
//! one breaks the graph's `interface:` entry, which validation reports, not a run.

use std::collections::BTreeMap;

use crate::diagnostic::{Diagnostic, Diagnostics, closest};
use crate::schema::GraphFile;
use crate::validate::{Finder, GraphSpec, NodeSpec, Override, OverrideTarget, loc};

/// An exposed parameter: the node holding it and the dotted key inside its parameters.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ExposedParam {
    pub node: String,
    pub key: String,
}

/// An exposed output: a node's output port, by index.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ExposedOutput {
    pub node: usize,
    pub port: usize,
}

/// The interface as validated.
#[derive(Clone, Debug, Default)]
pub struct Interface {
    /// Each name's targets (one, or several set together).
    pub params: BTreeMap<String, Vec<ExposedParam>>,
    pub outputs: BTreeMap<String, ExposedOutput>,
}

/// What a command needs of a graph: the parameters it sets and the outputs it collects.
#[derive(Clone, Copy, Debug)]
pub struct Contract {
    /// The command, as a user types it (`eval forecast`).
    pub command: &'static str,
    pub params: &'static [&'static str],
    pub outputs: &'static [&'static str],
}

impl GraphSpec {
    /// Every name of `contract` that this graph does not expose, as one problem each.
    pub fn check_contract(&self, contract: &Contract) -> Result<(), Diagnostics> {
        let mut found = Vec::new();
        let mut missing = |kind: &str, name: &str, exposed: Vec<&String>| {
            let listed: Vec<&str> = exposed.iter().map(|s| s.as_str()).collect();
            found.push(Diagnostic {
                file: self.file.clone(),
                position: None,
                message: format!(
                    "`{}` binds to the {kind} '{name}', which this graph's `interface:` does not expose",
                    contract.command
                ),
                hint: Some(match closest(name, listed.iter().copied()) {
                    Some(near) => format!("did you mean '{near}'? exposed: {}", listed.join(", ")),
                    None if listed.is_empty() => {
                        format!("add `interface: {{{kind}s: {{{name}: <node>.<key>}}}}`")
                    }
                    None => format!("exposed {kind}s: {}", listed.join(", ")),
                }),
            });
        };
        for name in contract.params {
            if !self.interface.params.contains_key(*name) {
                missing("parameter", name, self.interface.params.keys().collect());
            }
        }
        for name in contract.outputs {
            if !self.interface.outputs.contains_key(*name) {
                missing("output", name, self.interface.outputs.keys().collect());
            }
        }
        if found.is_empty() {
            Ok(())
        } else {
            Err(Diagnostics(found))
        }
    }

    /// The value of exposed parameter `name`, as the graph resolves it (its first target's).
    pub fn exposed_param(&self, name: &str) -> Option<&serde_json::Value> {
        let exposed = self.interface.params.get(name)?.first()?;
        let node = self.nodes.iter().find(|n| n.id == exposed.node)?;
        exposed
            .key
            .split('.')
            .try_fold(&node.params, |value, part| value.get(part))
    }
}

/// The exposed targets of `overrides` rewritten to the node parameters they stand for; an
/// exposed name the graph does not have is a problem.
pub(crate) fn resolve_overrides(
    finder: &mut Finder,
    parsed: &GraphFile,
    overrides: &[Override],
) -> Vec<Override> {
    let declared = parsed.interface.as_ref().map(|i| &i.value.params);
    overrides
        .iter()
        .flat_map(|over| {
            let OverrideTarget::Exposed(name) = &over.target else {
                return vec![over.clone()];
            };
            let Some(targets) = declared.and_then(|params| params.get(name)) else {
                let names = declared.map(|p| p.keys().map(String::as_str).collect::<Vec<_>>());
                let names = names.unwrap_or_default();
                finder.at(
                    None,
                    format!("--set {name}: the graph exposes no parameter '{name}'"),
                    Some(match closest(name, names.iter().copied()) {
                        Some(near) => format!("did you mean '{near}'?"),
                        None if names.is_empty() => {
                            "name a node's parameter as node.key, or expose it under `interface: {params: ...}`".into()
                        }
                        None => format!("exposed: {}", names.join(", ")),
                    }),
                );
                return Vec::new();
            };
            // A malformed target is reported by `check`, with its line.
            targets
                .value
                .targets()
                .into_iter()
                .filter_map(|target| target.split_once('.'))
                .map(|(node, key)| Override {
                    target: OverrideTarget::Node {
                        node: node.to_string(),
                        key: key.to_string(),
                    },
                    value: over.value.clone(),
                })
                .collect()
        })
        .collect()
}

/// Checks each `interface:` entry against the graph's nodes: a parameter must be one the node
/// has (its resolved parameters hold the key), an output one of its kind's output ports.
pub(crate) fn check(finder: &mut Finder, parsed: &GraphFile, nodes: &[NodeSpec]) -> Interface {
    let mut interface = Interface::default();
    let Some(declared) = &parsed.interface else {
        return interface;
    };
    let ids: Vec<&str> = nodes.iter().map(|n| n.id.as_str()).collect();
    let node_of = |finder: &mut Finder,
                   what: &str,
                   name: &str,
                   target: &str,
                   at: Option<serde_saphyr::Location>| {
        let Some((node, rest)) = target
            .split_once('.')
            .filter(|(n, r)| !n.is_empty() && !r.is_empty())
        else {
            let part = if what == "output" { "port" } else { "key" };
            finder.at(
                at,
                format!("interface {what} '{name}': '{target}' is not node.{part}"),
                None,
            );
            return None;
        };
        let Some(index) = nodes.iter().position(|n| n.id == node) else {
            finder.at(
                at,
                format!(
                    "interface {what} '{name}' names node '{node}', which the graph does not have"
                ),
                Some(match closest(node, ids.iter().copied()) {
                    Some(near) => format!("did you mean '{near}'?"),
                    None => format!("nodes: {}", ids.join(", ")),
                }),
            );
            return None;
        };
        Some((index, rest.to_string()))
    };
    for (name, targets) in &declared.value.params {
        let mut exposed = Vec::new();
        for target in targets.value.targets() {
            let Some((index, key)) = node_of(finder, "parameter", name, target, loc(targets))
            else {
                continue;
            };
            let node = &nodes[index];
            let top = key.split('.').next().unwrap_or(&key);
            if node.params.get(top).is_none() {
                let keys: Vec<&str> = node
                    .params
                    .as_object()
                    .map(|o| o.keys().map(String::as_str).collect())
                    .unwrap_or_default();
                finder.at(
                    loc(targets),
                    format!(
                        "interface parameter '{name}': node '{}' ({}) has no parameter '{top}'",
                        node.id, node.kind.name
                    ),
                    Some(format!("its parameters: {}", keys.join(", "))),
                );
                continue;
            }
            exposed.push(ExposedParam {
                node: node.id.clone(),
                key,
            });
        }
        interface.params.insert(name.clone(), exposed);
    }
    for (name, target) in &declared.value.outputs {
        let Some((index, port)) = node_of(finder, "output", name, &target.value, loc(target))
        else {
            continue;
        };
        let kind = &nodes[index].kind;
        let Some((port, _)) = kind.output_port(&port) else {
            let ports: Vec<&str> = kind.outputs.iter().map(|p| p.name).collect();
            finder.at(
                loc(target),
                format!(
                    "interface output '{name}': node '{}' ({}) has no output port '{port}'",
                    nodes[index].id, kind.name
                ),
                Some(format!("its outputs: {}", ports.join(", "))),
            );
            continue;
        };
        interface
            .outputs
            .insert(name.clone(), ExposedOutput { node: index, port });
    }
    interface
}
