//! Every node kind the `bevworld` tool knows, and the rules that hold between kinds of
//! different families. `graph/` stays free of sensor and model types; this is where the
//! families meet.

use bevworld_graph::{GraphSpec, ParamError, Registry, RuleProblem};

pub fn registry() -> Registry {
    let mut registry = Registry::new();
    bevworld_sensors::register(&mut registry);
    bevworld_sinks::register(&mut registry);
    bevworld_pillarize::register(&mut registry);
    bevworld_tokenizer::register(&mut registry);
    bevworld_metrics::register(&mut registry);
    bevworld_world_model::register(&mut registry);
    registry.rule(forecast_sink_is_fed_its_method);
    registry
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
