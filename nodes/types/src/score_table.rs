//! A scoring node's table at the end of a run: what `forecast_metrics` and
//! `reconstruction_metrics` send on their `table` output, and what a command collects from a
//! graph in-process (`bevworld_graph::Collected`) instead of reading back a file the graph
//! wrote. The JSON is the shape the node's `json` file and the command's `--json` have.

#[derive(Clone, Debug, PartialEq)]
pub struct ScoreTable(pub serde_json::Value);
