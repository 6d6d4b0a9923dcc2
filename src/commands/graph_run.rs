//! Running a graph file from a command, with `--set` overrides, quietly: what the commands
//! that are built on graphs (`train world-model`'s caches, `eval forecast`) share.

use std::path::Path;

use anyhow::{Context, Result, bail};
use bevworld_graph::{Override, RunOptions, StopHandle};

use crate::commands::Refused;
use crate::registry;

/// Validates, builds and runs `graph` with `set` (`node.key=value`), to the end.
/// Each node's kind and parameters as resolved (defaults filled in).
pub type ResolvedParams = Vec<(&'static str, serde_json::Value)>;

/// Runs the graph; returns its nodes' resolved parameters and the run's report.
pub fn run_graph(
    graph: &Path,
    set: &[String],
) -> Result<(ResolvedParams, bevworld_graph::RunReport)> {
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
    let params: ResolvedParams = validated
        .spec
        .nodes
        .iter()
        .map(|n| (n.kind.name, n.params.clone()))
        .collect();
    let built = match validated.build() {
        Ok(built) => built,
        Err(diagnostics) => return Err(Refused::Graph(diagnostics).into()),
    };
    let outcome = bevworld_graph::run(
        built,
        RunOptions {
            stop: StopHandle::new(),
            observer: None,
        },
    );
    if let Some(error) = outcome.error {
        bail!("{}: {error}", graph.display());
    }
    Ok((params, outcome.report))
}

/// The world model a graph's `diffusion_rollout` node loads, read from its config: the facts a
/// command needs of the model (its condition frames, its frame interval, how far it forecasts)
/// come from there, never from a constant of the command's.
pub fn world_model_of(graph: &Path) -> Result<bevworld_world_model::WorldModelConfig> {
    let validated = match bevworld_graph::load(graph, &registry::registry(), &[]) {
        Ok(validated) => validated,
        Err(diagnostics) => return Err(Refused::Graph(diagnostics).into()),
    };
    let model = validated
        .spec
        .nodes
        .iter()
        .find(|n| n.kind.name == "diffusion_rollout")
        .and_then(|n| n.params.get("model"))
        .and_then(serde_json::Value::as_str)
        .map(Path::new)
        .with_context(|| {
            format!(
                "{}: no diffusion_rollout node names the world model",
                graph.display()
            )
        })?;
    bevworld_world_model::WorldModelConfig::from_yaml_file(model)
        .with_context(|| format!("the world model of {}", graph.display()))
}

/// Runs the graph, whose sink writes the JSON file `report`, and returns the resolved
/// parameters and that file parsed. An old `report` is removed first, so that a run that
/// writes none is an error, not a stale table.
pub fn run_graph_for_report(
    graph: &Path,
    set: &[String],
    report: &Path,
) -> Result<(ResolvedParams, serde_json::Value)> {
    if report.exists() {
        std::fs::remove_file(report)
            .with_context(|| format!("removing the old {}", report.display()))?;
    }
    let (params, _) = run_graph(graph, set)?;
    let table = serde_json::from_slice(
        &std::fs::read(report).with_context(|| format!("reading {}", report.display()))?,
    )
    .with_context(|| format!("parsing {}", report.display()))?;
    Ok((params, table))
}
