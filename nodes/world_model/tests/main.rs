//! The integration tests of `bevworld-world-model`.
//!
//! One binary, one module per file and concern: a binary per file linked burn into each, some
//! 500 MB apiece, for the same tests.

mod hard_cases;
mod nodes;
mod world_model;
