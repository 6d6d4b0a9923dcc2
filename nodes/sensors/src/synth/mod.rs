//! Our synthetic driving world: a town of roads, kerbs, buildings and traffic, seen by a
//! nuScenes-like rig through a ray caster, written in the nuScenes layout.
//!
//! It is the embedded default: tests, the demo and CPU training run on it, and because the ego
//! is driven by recorded controls through a bicycle model, its actions truly determine its
//! future: what action-conditioned forecasting needs to be learnable and testable.

pub mod geometry;
pub mod in_place;
pub mod people;
pub mod render;
pub mod rig;
pub mod rng;
pub mod scene;
pub mod schema;
pub mod set;
pub mod traffic;
pub mod world;
pub mod writer;

pub use in_place::{InPlace, generate_in_place};
pub use scene::SceneWorld;
pub use set::{SynthSet, SynthSetError};
pub use writer::{
    Branch, ImageEncoding, SynthConfig, SynthSummary, VERSION, generate, scene_name,
    scene_variant_name,
};
