//! The README's results table, generated from `bench/results/*.json` (`bevworld_bench::readme`):
//! prints it, or with `--write` puts it into README.md between its markers.
//!
//!   cargo run --release -p bevworld-bench --bin readme_results -- --write

use bevworld_bench::readme::{readme_path, results_table, with_table};
use bevworld_bench::results_dir;

fn main() {
    let write = match std::env::args().nth(1).as_deref() {
        None => false,
        Some("--write") => true,
        Some(other) => {
            eprintln!(
                "readme_results: unknown argument '{other}' (usage: readme_results [--write])"
            );
            std::process::exit(2);
        }
    };
    let table = match results_table(&results_dir()) {
        Ok(table) => table,
        Err(error) => {
            eprintln!("{error}");
            std::process::exit(1);
        }
    };
    if !write {
        println!("{table}");
        return;
    }
    let path = readme_path();
    let updated = std::fs::read_to_string(&path)
        .map_err(|e| e.to_string())
        .and_then(|readme| with_table(&readme, &table, &path).map_err(|e| e.to_string()))
        .and_then(|updated| {
            bevworld_atomic_file::write(&path, updated.as_bytes()).map_err(|e| e.to_string())
        });
    match updated {
        Ok(()) => println!("{} updated", path.display()),
        Err(error) => {
            eprintln!("{}: {error}", path.display());
            std::process::exit(1);
        }
    }
}
