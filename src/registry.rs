//! Every node kind the `bevworld` tool knows. `graph/` stays free of sensor and model types;
//! this is where the families meet.

use bevworld_graph::Registry;

pub fn registry() -> Registry {
    let mut registry = Registry::new();
    bevworld_sensors::register(&mut registry);
    bevworld_sinks::register(&mut registry);
    bevworld_pillarize::register(&mut registry);
    bevworld_tokenizer::register(&mut registry);
    bevworld_metrics::register(&mut registry);
    bevworld_world_model::register(&mut registry);
    registry
}
