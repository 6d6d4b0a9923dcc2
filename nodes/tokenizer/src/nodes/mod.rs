//! The tokenizer's graph nodes: `encode` (frame and pillars to the BEV latent) and `render`
//! (latent to camera images and a LiDAR sweep).

pub mod encode;
pub mod loaded_model;
pub mod render;

pub use loaded_model::{CheckedTokenizer, LoadedModel, ModelParams, check_files};

/// Registers this family's node kinds.
pub fn register(registry: &mut bevworld_graph::Registry) {
    encode::register(registry);
    render::register(registry);
}
