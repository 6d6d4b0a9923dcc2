//! The tokenizer's encoder parts.

pub mod bilinear;
pub mod fusion;
pub mod pillar_net;
pub mod projection;

pub use pillar_net::{PillarNet, PillarNetConfig, scatter_to_bev};
