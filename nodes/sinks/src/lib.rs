//! Sinks: files for people and programs.

// Libraries return errors; a panic belongs to a broken invariant, said with `expect`.
#![cfg_attr(not(test), warn(clippy::unwrap_used))]

pub mod detections_sink;
pub mod export;
pub mod export_index;
pub mod forecast_sink;
pub mod npy;
pub mod ply;
pub mod ply_sink;
pub mod png_sink;
pub mod writes;

/// Registers this family's node kinds.
pub fn register(registry: &mut bevworld_graph::Registry) {
    png_sink::register(registry);
    ply_sink::register(registry);
    export::register(registry);
    forecast_sink::register(registry);
    detections_sink::register(registry);
}
