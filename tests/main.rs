//! The system's end-to-end tests: the `bevworld` command, its graphs and its models.
//!
//! One binary, one module per file and concern: a binary per file linked burn into each, some
//! 500 MB apiece, for the same tests.

mod cli;
mod common;
mod control;
mod detect;
mod detector_eval;
mod eval;
mod forecast;
mod hard_cases;
mod inspect;
mod layering;
mod models;
#[path = "../src/registry.rs"]
mod registry;
mod reliability;
mod tokenizer_graphs;
mod train_cli;
mod world_model;
