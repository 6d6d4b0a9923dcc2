//! Subcommands that are tools rather than graphs.

pub mod inspect;
pub mod synth;
