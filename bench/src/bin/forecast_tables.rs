//! The tables of a forecast evaluation, from its JSON (`bevworld eval forecast --json`, or a
//! forecast graph's `scores.json`): the whole-scene scores per horizon and method, the
//! agents' split, and with several draws of the model (`--samples K`) their mean and best of
//! K, as markdown. The pages quote these, generated from the figures, never typed.
//!
//!   cargo run --release -p bevworld-bench --bin forecast_tables -- bench/results/forecast-test.json
//!
//! With `--compare LABEL=FILE ...`, the point forecasts of several runs of the same scenes
//! side by side, per horizon, beside the first run's latent ego warp and oracle;
//! `LABEL=FILE#METHOD` shows that run's METHOD (`latent_box_warp`, `model_with_agents`)
//! instead of its point forecast. With
//! `--pooled FILE`, the moving vehicles' scores pooled over every true point.

use bevworld_metrics::forecast_node::{
    agents_markdown_of, compare_markdown_of, draws_markdown_of, markdown_of, pooled_markdown_of,
};

const USAGE: &str = "usage: forecast_tables SCORES.json | forecast_tables --compare LABEL=SCORES.json ... | forecast_tables --pooled SCORES.json";

fn read(path: &str) -> serde_json::Value {
    match std::fs::read(path)
        .map_err(|e| e.to_string())
        .and_then(|bytes| serde_json::from_slice(&bytes).map_err(|e| e.to_string()))
    {
        Ok(table) => table,
        Err(error) => {
            eprintln!("{path}: {error}");
            std::process::exit(1);
        }
    }
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.first().map(String::as_str) == Some("--compare") {
        let mut runs = Vec::new();
        for arg in &args[1..] {
            let Some((label, path)) = arg.split_once('=') else {
                eprintln!("{arg}: not LABEL=FILE\n{USAGE}");
                std::process::exit(2);
            };
            let (path, method) = path.split_once('#').unwrap_or((path, "model"));
            let mut table = read(path);
            if method != "model" {
                let Some(rows) = table["horizons"].as_array_mut() else {
                    eprintln!("{path}: no horizons");
                    std::process::exit(1);
                };
                for row in rows {
                    let Some(cell) = row.get(method).cloned() else {
                        eprintln!("{path}: no {method} at every horizon");
                        std::process::exit(1);
                    };
                    row["model"] = cell;
                }
            }
            runs.push((label.to_string(), table));
        }
        if runs.is_empty() {
            eprintln!("{USAGE}");
            std::process::exit(2);
        }
        println!("{}", compare_markdown_of(&runs));
        return;
    }
    if let [flag, path] = args.as_slice()
        && flag == "--pooled"
    {
        println!("{}", pooled_markdown_of(&read(path)));
        return;
    }
    let [path] = args.as_slice() else {
        eprintln!("{USAGE}");
        std::process::exit(2);
    };
    let table = read(path);
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
