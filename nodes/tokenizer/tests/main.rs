//! The integration tests of `bevworld-tokenizer`.
//!
//! One binary, one module per file and concern: a binary per file linked burn into each, some
//! 500 MB apiece, for the same tests.

mod backends;
mod background;
mod bilinear;
mod common;
mod config;
mod flops;
mod frame_input;
mod fusion;
mod hard_cases;
mod latent;
mod model;
mod modules;
mod nodes;
mod projection;
mod rays;
mod render;
mod shipped_weights;
mod skipping;
mod weights;
