//! Subcommands that are tools rather than graphs.

pub mod control;
pub mod eval;
pub mod graph_run;
pub mod inspect;
pub mod latent_cache;
pub mod reconstruction_eval;
pub mod synth;
pub mod tokenizer;
pub mod train;
