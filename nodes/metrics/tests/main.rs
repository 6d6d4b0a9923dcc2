//! The integration tests of `bevworld-metrics`.
//!
//! One binary, one module per file and concern: a binary per file linked burn into each, some
//! 500 MB apiece, for the same tests.

mod chamfer;
mod detection;
mod fid;
mod frechet;
#[path = "image.rs"]
mod image_tests;
mod reconstruction_node;
