//! The integration tests of `bevworld-tokenizer-train`.
//!
//! One binary, one module per file and concern: a binary per file linked burn into each, some
//! 500 MB apiece, for the same tests.

mod perceptual;
mod train;
