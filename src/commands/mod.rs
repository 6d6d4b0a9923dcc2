//! Subcommands that are tools rather than graphs, and the exit-code rule they share.

pub mod contracts;
pub mod control;
pub mod detector_eval;
pub mod detector_motion;
pub mod detector_train;
pub mod eval;
pub mod graph_run;
pub mod inspect;
pub mod latent_cache;
pub mod reconstruction_eval;
pub mod synth;
pub mod tokenizer;
pub mod train;

/// A command refused before it did any work. Every command exits by one rule:
///
/// - **2**: refused before any work: a bad flag (as clap does), a graph or parameter that
///   does not validate (as `run` and `check` do);
/// - **1**: it ran and failed, or produced nothing;
/// - **130**: aborted by a second Ctrl-C.
#[derive(Debug)]
pub enum Refused {
    /// A flag's value, in the flag's words.
    Flag(String),
    /// A graph's validation problems, each at its `file:line:col`.
    Graph(bevworld_graph::Diagnostics),
}

impl std::fmt::Display for Refused {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Refused::Flag(message) => f.write_str(message),
            Refused::Graph(diagnostics) => write!(f, "{diagnostics}"),
        }
    }
}

impl std::error::Error for Refused {}

/// Refuses a flag's value before the command does any work (exit 2).
pub fn refuse(message: impl Into<String>) -> anyhow::Error {
    Refused::Flag(message.into()).into()
}
