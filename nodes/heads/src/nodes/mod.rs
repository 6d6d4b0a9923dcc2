//! The heads' graph nodes: `detect`.

pub mod detect;

use bevworld_graph::Registry;

/// Registers the heads' node kinds.
pub fn register(registry: &mut Registry) {
    detect::register(registry);
}
