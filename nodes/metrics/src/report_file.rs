//! A metrics node's report file (a per-frame CSV, a JSON summary), written as every output of
//! the project is: its folder made, then the file atomically, so a killed run never leaves a
//! truncated report.

use std::path::Path;

use bevworld_graph::NodeError;

/// Writes `text` to `path`, creating its folder; an error names the path.
pub fn write_report(path: &Path, text: &str) -> Result<(), NodeError> {
    if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent)
            .map_err(|e| NodeError::fatal(format!("creating {}: {e}", parent.display())))?;
    }
    bevworld_graph::io::write_atomic_now(path, text.as_bytes())
        .map_err(|e| NodeError::fatal(format!("writing {}: {e}", path.display())))
}

/// The population standard deviation of `values`, the spread of per-scene means that says how
/// far a figure moves with the scene; `None` for fewer than two values, which have no spread.
pub fn population_std(values: &[f64]) -> Option<f64> {
    (values.len() > 1).then(|| {
        let n = values.len() as f64;
        let mean = values.iter().sum::<f64>() / n;
        (values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n).sqrt()
    })
}
