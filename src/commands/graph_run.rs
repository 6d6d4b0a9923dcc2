//! Running a graph from a command: the command's `name=value` settings bound through the graph's
//! `interface:` (never its node ids), the graph held to the command's contract before anything
//! is built, and its results collected in-process from the outputs it exposes.

use std::path::Path;

use anyhow::{Context, Result, bail};
use bevworld_graph::{Contract, Override, ResolvedGraph, RunOptions, StopHandle, ValidatedGraph};
use bevworld_types::ModelBundle;

use crate::commands::Refused;
use crate::registry;

/// Validates `graph` with `set` (`name=value` of exposed parameters, `models.b.k=value`, or a
/// user's own `node.key=value`) and holds it to `contract`.
pub fn validate_bound(graph: &Path, contract: &Contract, set: &[String]) -> Result<ValidatedGraph> {
    let overrides = set
        .iter()
        .map(|text| {
            Override::parse(text).map_err(|e| crate::commands::refuse(format!("--set {e}")))
        })
        .collect::<Result<Vec<_>>>()?;
    let validated = match bevworld_graph::load(graph, &registry::registry(), &overrides) {
        Ok(validated) => validated,
        Err(diagnostics) => return Err(Refused::Graph(diagnostics).into()),
    };
    if let Err(diagnostics) = validated.spec.check_contract(contract) {
        return Err(Refused::Graph(diagnostics).into());
    }
    Ok(validated)
}

/// As `validate_bound`, then built: the models loaded, the nodes made.
pub fn build_bound(graph: &Path, contract: &Contract, set: &[String]) -> Result<ResolvedGraph> {
    match validate_bound(graph, contract, set)?.build() {
        Ok(built) => Ok(built),
        Err(diagnostics) => Err(Refused::Graph(diagnostics).into()),
    }
}

/// Runs a built graph to the end, quietly.
pub fn run_built(graph: ResolvedGraph) -> Result<bevworld_graph::RunReport> {
    let file = graph.spec.file.clone();
    let outcome = bevworld_graph::run(
        graph,
        RunOptions {
            stop: StopHandle::new(),
            observer: None,
        },
    );
    if let Some(error) = outcome.error {
        bail!("{file}: {error}");
    }
    Ok(outcome.report)
}

/// The model bundle the graph's exposed `model` parameter names, as checked.
pub fn bundle_of(validated: &ValidatedGraph) -> Result<(String, ModelBundle)> {
    let spec = &validated.spec;
    let name = spec
        .exposed_param("model")
        .and_then(serde_json::Value::as_str)
        .with_context(|| format!("{}: the graph exposes no `model` bundle name", spec.file))?;
    let bundle = spec
        .models
        .bundles()
        .get(name)
        .with_context(|| format!("{}: no model bundle '{name}'", spec.file))?;
    Ok((name.to_string(), ModelBundle::from_json(bundle)?))
}

/// The name of the bundle the graph's exposed `model` parameter names: what a command's
/// `models.<name>.*` settings address.
pub fn bundle_name(graph: &Path, contract: &Contract) -> Result<String> {
    Ok(bundle_of(&validate_bound(graph, contract, &[])?)?.0)
}

/// The world model the graph's `model` bundle holds, read from its config: the facts a command
/// needs of the model (its condition frames, its frame interval, how far it forecasts) come
/// from there, never from a constant of the command's.
pub fn world_model_of(
    graph: &Path,
    contract: &Contract,
    set: &[String],
) -> Result<bevworld_world_model::WorldModelConfig> {
    let validated = validate_bound(graph, contract, set)?;
    let (name, bundle) = bundle_of(&validated)?;
    let files = bundle.world_model.with_context(|| {
        format!(
            "{}: model bundle '{name}' has no world model",
            graph.display()
        )
    })?;
    bevworld_world_model::WorldModelConfig::from_yaml_file(&files.config)
        .with_context(|| format!("the world model of {}", graph.display()))
}
