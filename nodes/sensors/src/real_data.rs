//! Where the real recordings are: the folder `BEVWORLD_DATA` names, by default `../shared/data`
//! beside the checkout (a nuScenes keyframe in `nuscenes-sample/`, KITTI odometry scans in
//! `kitti-odometry-00/`; their licences forbid copying them into the repository).
//!
//! Tests and benchmarks that need them ask here. When a dataset is missing, a test says so in
//! one line naming the variable and skips, unless `BEVWORLD_REQUIRE_DATA` is set (CI sets it),
//! and then it fails: in CI missing data is never a silent skip.

use std::path::PathBuf;

/// The variable that names the data folder.
pub const DATA_VARIABLE: &str = "BEVWORLD_DATA";
/// The variable that turns a missing dataset into a failure.
pub const REQUIRE_VARIABLE: &str = "BEVWORLD_REQUIRE_DATA";

/// The data folder: `$BEVWORLD_DATA`, or `../shared/data` beside the checkout.
pub fn data_root() -> PathBuf {
    std::env::var_os(DATA_VARIABLE)
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data"))
}

/// The real dataset `name` (e.g. `nuscenes-sample`), if it is there. When it is not, one line
/// on stderr names it and the variable; with `BEVWORLD_REQUIRE_DATA` set, this panics instead.
pub fn real_dataset(name: &str) -> Option<PathBuf> {
    let path = data_root().join(name);
    if path.is_dir() {
        return Some(path);
    }
    let line = format!(
        "real data missing: {} is not a folder (set {DATA_VARIABLE} to the folder that holds {name})",
        path.display()
    );
    if std::env::var_os(REQUIRE_VARIABLE).is_some() {
        panic!("{line}; {REQUIRE_VARIABLE} is set, so this is a failure");
    }
    eprintln!("skipped: {line}");
    None
}
