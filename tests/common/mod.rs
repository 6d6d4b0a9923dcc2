//! Running the `bevworld` tool as a user does, for the end-to-end test files.
#![allow(dead_code)] // each test file uses its own part

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// The repository, from cargo at run time (a reused build cache may have compiled the tests
/// at another path).
pub fn repo() -> PathBuf {
    PathBuf::from(std::env::var_os("CARGO_MANIFEST_DIR").expect("cargo sets CARGO_MANIFEST_DIR"))
}

pub fn bevworld(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_bevworld"))
        .args(args)
        .current_dir(repo())
        .output()
        .expect("bevworld runs")
}

/// `bevworld` with owned arguments.
pub fn bevworld_owned(args: &[String]) -> Output {
    bevworld(&args.iter().map(String::as_str).collect::<Vec<_>>())
}

/// A node's row of a run's `--metrics` report.
pub fn node<'a>(report: &'a serde_json::Value, id: &str) -> &'a serde_json::Value {
    report["nodes"]
        .as_array()
        .expect("nodes")
        .iter()
        .find(|n| n["id"] == id)
        .unwrap_or_else(|| panic!("no node {id} in the metrics"))
}

/// A JSON file a run wrote (a `--metrics` report, an index, scores).
pub fn read_json(path: &Path) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(path).expect("the run wrote it")).expect("JSON")
}

/// Exports the keyframe latents of the dataset at `data` into `out` with
/// `export_latents.yaml`, and returns the index's frames in time order.
pub fn export_latents(data: &Path, out: &Path) -> Vec<serde_json::Value> {
    let output = bevworld_owned(&[
        "run".into(),
        "configs/graphs/export_latents.yaml".into(),
        "--set".into(),
        format!("data={}", data.display()),
        "--set".into(),
        format!("out={}", out.display()),
    ]);
    assert!(output.status.success(), "{}", text(&output));
    let index = read_json(&out.join("index.json"));
    let mut frames = index["frames"].as_array().expect("frames").clone();
    frames.sort_by_key(|f| f["timestamp_us"].as_i64());
    frames
}

pub fn text(output: &Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&output.stdout),
        String::from_utf8_lossy(&output.stderr)
    )
}

/// `--set` arguments sending every file `reconstruct.yaml` writes to `out`, by the names it
/// exposes.
pub fn reconstruct_outputs(out: &Path) -> Vec<String> {
    vec![
        "--set".into(),
        format!("out={}", out.display()),
        "--set".into(),
        format!("metrics_csv={}", out.join("metrics.csv").display()),
    ]
}

/// Every file under `dir`, relative to it, sorted.
pub fn files_under(dir: &Path) -> Vec<PathBuf> {
    let mut found = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(folder) = stack.pop() {
        for entry in std::fs::read_dir(&folder).expect("read_dir").flatten() {
            let path = entry.path();
            if path.is_dir() {
                stack.push(path);
            } else {
                found.push(path.strip_prefix(dir).expect("inside").to_path_buf());
            }
        }
    }
    found.sort();
    found
}
