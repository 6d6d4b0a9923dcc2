//! The multi-modal BEV tokenizer of BEVWorld, as Burn modules: Swin backbones for the cameras
//! and the LiDAR BEV, the pillar feature net, the decoder that lifts the latent to voxels, and
//! the NeRF-style renderer that turns voxel features back into images and depths.

// Libraries return errors; a panic belongs to a broken invariant, said with `expect`.
#![cfg_attr(not(test), warn(clippy::unwrap_used))]

pub mod config;
pub mod decoder;
pub mod encoder;
pub mod flops;
pub mod frame_input;
pub mod latent;
pub mod modality;
pub mod model;
pub mod nodes;
pub mod render;
pub mod weights;
pub use config::TokenizerConfig;
pub use frame_input::{EncoderArrays, FrameInputs, FrameRays, InputError};
pub use modality::Modality;
pub use model::{Encoded, EncoderInput, RayRender, Tokenizer};
pub use nodes::register;
pub use weights::{WeightsError, load_weights, save_weights, weights_digest};
