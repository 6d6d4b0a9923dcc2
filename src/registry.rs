//! Every node kind the `bevworld` tool knows, and the rules that hold between kinds of
//! different families. `graph/` stays free of sensor and model types; this is where the
//! families meet.

use bevworld_graph::{GraphSpec, ParamError, Registry, RuleProblem};
use bevworld_types::{LatentStatsFile, ModelBundle};

pub fn registry() -> Registry {
    let mut registry = Registry::new();
    bevworld_sensors::register(&mut registry);
    bevworld_sinks::register(&mut registry);
    bevworld_pillarize::register(&mut registry);
    bevworld_tokenizer::register(&mut registry);
    bevworld_metrics::register(&mut registry);
    bevworld_world_model::register(&mut registry);
    bevworld_heads::register(&mut registry);
    registry.models(check_bundle);
    registry.rule(forecast_sink_is_fed_its_method);
    registry
}

/// A bundle of a graph's `models:` section, checked before anything runs: the tokenizer's
/// config and weights, its latent statistics, the world model's config and sealed weights, and
/// that they belong together (the world model was trained on this tokenizer's latents, and the
/// statistics are this tokenizer's). Each problem names its field.
fn check_bundle(bundle: &ModelBundle) -> Vec<ParamError> {
    let mut problems = Vec::new();
    let tokenizer = bundle.tokenizer.as_ref().and_then(|files| {
        bevworld_tokenizer::nodes::check_files(files)
            .map_err(|problem| problems.push(problem))
            .ok()
            .map(|checked| (files, checked))
    });
    // The statistics are read when something reads them: a world model, or a file named.
    let stats = tokenizer.as_ref().and_then(|(files, _)| {
        if bundle.world_model.is_none() && files.latent_stats.is_none() {
            return None;
        }
        let path = files.latent_stats_path()?;
        LatentStatsFile::load(&path)
            .map_err(|error| {
                problems.push(
                    ParamError::field("tokenizer.latent_stats", error.to_string()).with_accepted(
                        "the file `bevworld tokenizer stats` writes beside the weights",
                    ),
                )
            })
            .ok()
    });
    let Some(world_model) = &bundle.world_model else {
        return problems;
    };
    let checked = match bevworld_world_model::nodes::model_params::check_files(world_model) {
        Ok(checked) => checked,
        Err(problem) => {
            problems.push(problem);
            return problems;
        }
    };
    match (&tokenizer, &stats) {
        (None, _) if bundle.tokenizer.is_none() => problems.push(ParamError::field(
            "world_model",
            "a world model reads the latents of a tokenizer: the bundle needs the `tokenizer` it was trained with",
        )),
        (Some((files, _)), None) if files.is_untrained() => problems.push(ParamError::field(
            "tokenizer.weights",
            "a world model cannot run on an untrained tokenizer's latents",
        )),
        (Some((_, tokenizer)), Some(stats)) => {
            let (config, meta) = &checked;
            if let Err(problem) = bevworld_world_model::nodes::model_params::check_pairing(
                config,
                meta,
                (&tokenizer.config.name, &tokenizer.weights_hash),
                stats,
            ) {
                problems.push(problem);
            }
        }
        // The tokenizer's own problem is reported already.
        _ => {}
    }
    problems
}

/// A `forecast_sink` writes the renders of one method: the `future_views` upstream of it must
/// render that method, or the sink receives every view and writes none of them.
fn forecast_sink_is_fed_its_method(graph: &GraphSpec) -> Vec<RuleProblem> {
    let mut problems = Vec::new();
    for (index, sink) in graph.nodes.iter().enumerate() {
        if sink.kind.name != "forecast_sink" {
            continue;
        }
        let method = sink.params["method"].as_str().unwrap_or_default();
        let views: Vec<_> = graph
            .upstream_of(index)
            .into_iter()
            .map(|i| &graph.nodes[i])
            .filter(|n| n.kind.name == "future_views")
            .collect();
        let rendered: Vec<&str> = views
            .iter()
            .flat_map(|v| v.params["methods"].as_array().into_iter().flatten())
            .filter_map(serde_json::Value::as_str)
            .collect();
        if views.is_empty() || rendered.contains(&method) {
            continue;
        }
        let ids: Vec<&str> = views.iter().map(|v| v.id.as_str()).collect();
        problems.push(RuleProblem {
            node: sink.id.clone(),
            error: ParamError::field(
                "method",
                format!(
                    "'{method}' is not rendered upstream: node '{}' renders only [{}], so this sink would receive every view and write none",
                    ids.join("', '"),
                    rendered.join(", ")
                ),
            )
            .with_accepted(format!(
                "one of [{}], or add '{method}' to {}.methods",
                rendered.join(", "),
                ids.first().copied().unwrap_or("views")
            )),
        });
    }
    problems
}
