//! The tables of a forecast evaluation, from its JSON (`bevworld eval forecast --json`, or a
//! forecast graph's `scores.json`): the whole-scene scores per horizon and method, the
//! agents' split, and with several draws of the model (`--samples K`) their mean and best of
//! K, as markdown. The pages quote these, generated from the figures, never typed.
//!
//!   cargo run --release -p bevworld-bench --bin forecast_tables -- bench/results/forecast-test.json

use bevworld_metrics::forecast_node::{agents_markdown_of, draws_markdown_of, markdown_of};

fn main() {
    let Some(path) = std::env::args().nth(1) else {
        eprintln!("usage: forecast_tables SCORES.json");
        std::process::exit(2);
    };
    let table: serde_json::Value = match std::fs::read(&path)
        .map_err(|e| e.to_string())
        .and_then(|bytes| serde_json::from_slice(&bytes).map_err(|e| e.to_string()))
    {
        Ok(table) => table,
        Err(error) => {
            eprintln!("{path}: {error}");
            std::process::exit(1);
        }
    };
    println!("{}", markdown_of(&table));
    let agents = agents_markdown_of(&table);
    if !agents.is_empty() {
        println!("{agents}");
    }
    let draws = draws_markdown_of(&table);
    if !draws.is_empty() {
        println!("{draws}");
    }
}
