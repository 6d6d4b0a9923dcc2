//! Every parser against generated and mutated input: the graph YAML, `--set`, the nuScenes
//! tables, `.pcd.bin`, the KITTI files, camera images, PLY, npy, burnpack weights, a
//! checkpoint's `state.json`, a world model's `.meta.json` and the latent statistics file.
//!
//! The bar, for every case: no panic; no single allocation out of proportion to the input (a
//! length field trusted before it is checked is how a 100-byte file asks for gigabytes); and an
//! error that names the input it read. Each input is mutated from a valid one (bytes flipped,
//! cut, repeated, overwritten with boundary numbers; tokens replaced with hostile values; JSON
//! fields removed or retyped), so the cases reach past the first line of each parser.
//!
//! The default budget keeps the suite to seconds. `PROPTEST_CASES=N` sets the cases per parser;
//! `bench/scripts/fuzz.sh` runs 20,000 each.

#[path = "../src/registry.rs"]
mod registry;

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::io::Cursor;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use bevworld_graph::validate::{Override, validate};
use bevworld_sensors::NonFinitePolicy;
use bevworld_sensors::kitti::Kitti;
use bevworld_sensors::lidar_file::{LidarLayout, decode_points, encode_points};
use bevworld_sensors::nuscenes::{NuScenes, NuScenesOptions};
use bevworld_sinks::npy::{npy_f32, read_npy_f32};
use bevworld_sinks::ply::{PlyEncoding, PlyPoint, decode_ply, encode_ply};
use bevworld_training::checkpoint::{self, CheckpointState};
use bevworld_types::LidarPoint;
use proptest::prelude::*;
use proptest::test_runner::{Config, TestRunner};

// ---------------------------------------------------------------------------------------------
// The largest single allocation a thread asked for, so that a case can say its parser kept
// within proportion.

struct Watched;

thread_local! {
    static LARGEST: Cell<usize> = const { Cell::new(0) };
}

fn note(size: usize) {
    let _ = LARGEST.try_with(|largest| largest.set(largest.get().max(size)));
}

// The one `unsafe` of the workspace, in a test: an allocator is an unsafe trait.
// SAFETY: every call is passed to the system allocator unchanged; the wrapper only records
// sizes in a thread-local cell, which allocates nothing.
#[allow(unsafe_code)]
unsafe impl GlobalAlloc for Watched {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        note(layout.size());
        unsafe { System.alloc(layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        note(layout.size());
        unsafe { System.alloc_zeroed(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        note(new_size);
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static ALLOCATOR: Watched = Watched;

/// No parser here needs more than this in one piece for inputs of a few kilobytes (the
/// datasets' own files included).
const LARGEST_ALLOWED: usize = 64 << 20;

/// How many cases a parser accepted and refused: printed (`--nocapture`) so that a run shows
/// the mutations reach both sides, not only the first check.
#[derive(Default)]
struct Tally {
    accepted: Cell<usize>,
    refused: Cell<usize>,
}

impl Tally {
    fn print(&self, what: &str) {
        eprintln!(
            "fuzz {what}: {} accepted, {} refused",
            self.accepted.get(),
            self.refused.get()
        );
    }
}

/// Runs `parse`, counts its outcome, and fails the case when it asked for one allocation
/// beyond the bound.
fn bounded<T, E>(
    tally: &Tally,
    what: &str,
    parse: impl FnOnce() -> Result<T, E>,
) -> Result<Result<T, E>, TestCaseError> {
    LARGEST.with(|largest| largest.set(0));
    let result = parse();
    let largest = LARGEST.with(Cell::get);
    prop_assert!(
        largest <= LARGEST_ALLOWED,
        "{what}: one allocation of {largest} bytes"
    );
    let counter = if result.is_ok() {
        &tally.accepted
    } else {
        &tally.refused
    };
    counter.set(counter.get() + 1);
    Ok(result)
}

fn runner(default_cases: u32) -> TestRunner {
    let cases = std::env::var("PROPTEST_CASES")
        .ok()
        .and_then(|text| text.parse().ok())
        .unwrap_or(default_cases);
    TestRunner::new(Config {
        cases,
        failure_persistence: None,
        ..Config::default()
    })
}

// ---------------------------------------------------------------------------------------------
// Mutations.

/// Numbers at the edges of what a length, a count or a float field can hold.
const BOUNDARY_WORDS: [u64; 10] = [
    0,
    1,
    0x7f,
    0xff,
    0xffff,
    0x7fff_ffff,
    0xffff_ffff,
    0x7fc0_0000, // f32 NaN
    0x7f80_0000, // f32 +inf
    0xffff_ffff_ffff_ffff,
];

/// Values a text field should never be trusted to hold.
const HOSTILE_TOKENS: [&str; 20] = [
    "0",
    "-1",
    "1e309",
    "-1e309",
    "nan",
    "NaN",
    ".inf",
    "99999999999999999999",
    "4294967296",
    "1e-300",
    "",
    "~",
    "[]",
    "{}",
    "\"\"",
    "0x10",
    "true",
    "-0",
    "18446744073709551615",
    "\u{feff}é\u{0}",
];

#[derive(Clone, Debug)]
enum ByteEdit {
    Flip {
        at: usize,
        bit: u8,
    },
    Set {
        at: usize,
        byte: u8,
    },
    Delete {
        at: usize,
        len: usize,
    },
    Insert {
        at: usize,
        bytes: Vec<u8>,
    },
    Repeat {
        at: usize,
        len: usize,
    },
    Truncate {
        at: usize,
    },
    Boundary {
        at: usize,
        word: usize,
        width: usize,
    },
}

fn byte_edit() -> impl Strategy<Value = ByteEdit> {
    prop_oneof![
        (any::<usize>(), 0u8..8).prop_map(|(at, bit)| ByteEdit::Flip { at, bit }),
        (any::<usize>(), any::<u8>()).prop_map(|(at, byte)| ByteEdit::Set { at, byte }),
        (any::<usize>(), 1usize..64).prop_map(|(at, len)| ByteEdit::Delete { at, len }),
        (any::<usize>(), prop::collection::vec(any::<u8>(), 1..16))
            .prop_map(|(at, bytes)| ByteEdit::Insert { at, bytes }),
        (any::<usize>(), 1usize..256).prop_map(|(at, len)| ByteEdit::Repeat { at, len }),
        any::<usize>().prop_map(|at| ByteEdit::Truncate { at }),
        (
            any::<usize>(),
            0..BOUNDARY_WORDS.len(),
            prop_oneof![Just(2usize), Just(4), Just(8)]
        )
            .prop_map(|(at, word, width)| ByteEdit::Boundary { at, word, width }),
    ]
}

fn apply_bytes(seed: &[u8], edits: &[ByteEdit]) -> Vec<u8> {
    let mut bytes = seed.to_vec();
    for edit in edits {
        let n = bytes.len();
        let at = |at: usize| if n == 0 { 0 } else { at % n };
        match edit {
            ByteEdit::Flip { at: a, bit } if n > 0 => bytes[at(*a)] ^= 1 << bit,
            ByteEdit::Set { at: a, byte } if n > 0 => bytes[at(*a)] = *byte,
            ByteEdit::Delete { at: a, len } if n > 0 => {
                let start = at(*a);
                bytes.drain(start..(start + len).min(n));
            }
            ByteEdit::Insert { at: a, bytes: new } => {
                let start = at(*a);
                bytes.splice(start..start, new.iter().copied());
            }
            ByteEdit::Repeat { at: a, len } if n > 0 => {
                let start = at(*a);
                let piece: Vec<u8> = bytes[start..(start + len).min(n)].to_vec();
                bytes.splice(start..start, piece);
            }
            ByteEdit::Truncate { at: a } => bytes.truncate(at(*a)),
            ByteEdit::Boundary { at: a, word, width } if n > 0 => {
                let value = BOUNDARY_WORDS[*word].to_le_bytes();
                let start = at(*a);
                for (k, byte) in value.iter().take(*width).enumerate() {
                    if let Some(slot) = bytes.get_mut(start + k) {
                        *slot = *byte;
                    }
                }
            }
            _ => {}
        }
    }
    bytes
}

/// Replaces the `index`-th token (a run of letters, digits and `._+-`) with a hostile one.
fn replace_token(text: &str, index: usize, hostile: usize) -> String {
    let is_token = |c: char| c.is_ascii_alphanumeric() || "._+-".contains(c);
    let mut spans = Vec::new();
    let mut start = None;
    for (i, c) in text.char_indices() {
        match (is_token(c), start) {
            (true, None) => start = Some(i),
            (false, Some(s)) => {
                spans.push((s, i));
                start = None;
            }
            _ => {}
        }
    }
    if let Some(s) = start {
        spans.push((s, text.len()));
    }
    if spans.is_empty() {
        return text.to_string();
    }
    let (s, e) = spans[index % spans.len()];
    format!(
        "{}{}{}",
        &text[..s],
        HOSTILE_TOKENS[hostile % HOSTILE_TOKENS.len()],
        &text[e..]
    )
}

#[derive(Clone, Debug)]
enum Mutation {
    Bytes(Vec<ByteEdit>),
    Tokens(Vec<(usize, usize)>),
}

fn mutation() -> impl Strategy<Value = Mutation> {
    prop_oneof![
        prop::collection::vec(byte_edit(), 1..6).prop_map(Mutation::Bytes),
        prop::collection::vec((any::<usize>(), any::<usize>()), 1..4).prop_map(Mutation::Tokens),
    ]
}

fn mutate(seed: &[u8], mutation: &Mutation) -> Vec<u8> {
    match mutation {
        Mutation::Bytes(edits) => apply_bytes(seed, edits),
        Mutation::Tokens(edits) => {
            let mut text = String::from_utf8_lossy(seed).to_string();
            for (index, hostile) in edits {
                text = replace_token(&text, *index, *hostile);
            }
            text.into_bytes()
        }
    }
}

#[derive(Clone, Debug)]
enum JsonEdit {
    /// Replace the value at a path (indices taken modulo each level's size).
    Replace { path: Vec<usize>, with: usize },
    /// Remove the member or element at a path.
    Remove { path: Vec<usize> },
    /// Repeat the element at a path (a record written twice).
    Repeat { path: Vec<usize> },
}

fn json_edit() -> impl Strategy<Value = JsonEdit> {
    let path = prop::collection::vec(any::<usize>(), 1..4);
    prop_oneof![
        (path.clone(), any::<usize>()).prop_map(|(path, with)| JsonEdit::Replace { path, with }),
        path.clone().prop_map(|path| JsonEdit::Remove { path }),
        path.prop_map(|path| JsonEdit::Repeat { path }),
    ]
}

fn hostile_json(which: usize) -> serde_json::Value {
    use serde_json::json;
    let values = [
        json!(null),
        json!(-1),
        json!(0),
        json!(1e308),
        json!(-1e308),
        json!(18446744073709551615u64),
        json!(""),
        json!("x"),
        json!([]),
        json!({}),
        json!([[1e308, 0], [0]]),
        json!(true),
        json!("../../../etc/passwd"),
        json!([0, 0, 0, 0]),
    ];
    values[which % values.len()].clone()
}

/// The container at `path` (all but its last step) and the index of the last step within it.
fn apply_json(value: &mut serde_json::Value, edit: &JsonEdit) {
    let path = match edit {
        JsonEdit::Replace { path, .. } | JsonEdit::Remove { path } | JsonEdit::Repeat { path } => {
            path
        }
    };
    let mut node = value;
    for (depth, step) in path.iter().enumerate() {
        let last = depth + 1 == path.len();
        match node {
            serde_json::Value::Array(items) if !items.is_empty() => {
                let i = step % items.len();
                if last {
                    match edit {
                        JsonEdit::Replace { with, .. } => items[i] = hostile_json(*with),
                        JsonEdit::Remove { .. } => {
                            items.remove(i);
                        }
                        JsonEdit::Repeat { .. } => {
                            let copy = items[i].clone();
                            items.insert(i, copy);
                        }
                    }
                    return;
                }
                node = &mut items[i];
            }
            serde_json::Value::Object(members) if !members.is_empty() => {
                let key = members
                    .keys()
                    .nth(step % members.len())
                    .cloned()
                    .unwrap_or_default();
                if last {
                    match edit {
                        JsonEdit::Replace { with, .. } => {
                            members.insert(key, hostile_json(*with));
                        }
                        JsonEdit::Remove { .. } | JsonEdit::Repeat { .. } => {
                            members.remove(&key);
                        }
                    }
                    return;
                }
                match members.get_mut(&key) {
                    Some(child) => node = child,
                    None => return,
                }
            }
            _ => return,
        }
    }
}

#[derive(Clone, Debug)]
enum TableMutation {
    Json(Vec<JsonEdit>),
    Raw(Mutation),
}

fn table_mutation() -> impl Strategy<Value = TableMutation> {
    prop_oneof![
        3 => prop::collection::vec(json_edit(), 1..4).prop_map(TableMutation::Json),
        1 => mutation().prop_map(TableMutation::Raw),
    ]
}

fn mutate_table(seed: &[u8], mutation: &TableMutation) -> Vec<u8> {
    match mutation {
        TableMutation::Raw(raw) => mutate(seed, raw),
        TableMutation::Json(edits) => {
            let Ok(mut value) = serde_json::from_slice::<serde_json::Value>(seed) else {
                return seed.to_vec();
            };
            for edit in edits {
                apply_json(&mut value, edit);
            }
            serde_json::to_vec(&value).unwrap_or_default()
        }
    }
}

fn names(message: &str, input: &Path) -> bool {
    message.contains(&input.display().to_string())
}

// ---------------------------------------------------------------------------------------------
// The parsers.

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn graph_files() -> Vec<(String, String)> {
    let mut files: Vec<(String, String)> = std::fs::read_dir(repo().join("configs/graphs"))
        .expect("configs/graphs")
        .map(|e| e.expect("entry").path())
        .filter(|p| p.extension().is_some_and(|e| e == "yaml"))
        .map(|p| {
            let text = std::fs::read_to_string(&p).expect("graph");
            (p.display().to_string(), text)
        })
        .collect();
    files.sort();
    files
}

#[test]
fn graph_yaml() {
    let registry = registry::registry();
    let graphs = graph_files();
    let tally = Tally::default();
    runner(48)
        .run(&(any::<usize>(), mutation()), |(which, mutation)| {
            let (_, seed) = &graphs[which % graphs.len()];
            let text = String::from_utf8_lossy(&mutate(seed.as_bytes(), &mutation)).to_string();
            let result = bounded(&tally, "graph YAML", || {
                validate(&text, "fuzzed-graph.yaml", &registry, &[])
            })?;
            if let Err(diagnostics) = result {
                let message = diagnostics.to_string();
                prop_assert!(message.contains("fuzzed-graph.yaml"), "{message}");
            }
            Ok(())
        })
        .expect("graph YAML");
    tally.print("graph YAML");
}

#[test]
fn set_overrides() {
    let registry = registry::registry();
    let (_, seed) = graph_files()
        .into_iter()
        .find(|(path, _)| path.ends_with("reconstruct.yaml"))
        .expect("reconstruct.yaml");
    let keys = [
        "source.data",
        "source.max_frames",
        "source.pacing.rate_hz",
        "pillars.grid.pillar_size",
        "render.sensors",
        "metrics.roi",
        "models.tiny.tokenizer.weights",
        "data",
        "settings.default_capacity",
        "nowhere.key",
        "source",
    ];
    let strategy = (0..keys.len(), ".{0,24}", any::<usize>(), any::<bool>());
    let tally = Tally::default();
    runner(64)
        .run(&strategy, |(key, free, hostile, use_hostile)| {
            let value = if use_hostile {
                HOSTILE_TOKENS[hostile % HOSTILE_TOKENS.len()].to_string()
            } else {
                free
            };
            let text = format!("{}={value}", keys[key]);
            let parsed = bounded(&tally, "--set", || Override::parse(&text))?;
            let Ok(parsed) = parsed else {
                return Ok(());
            };
            let result = bounded(&tally, "--set", || {
                validate(&seed, "reconstruct.yaml", &registry, &[parsed])
            })?;
            if let Err(diagnostics) = result {
                let message = diagnostics.to_string();
                prop_assert!(!message.trim().is_empty());
            }
            Ok(())
        })
        .expect("--set");
    tally.print("--set");
}

/// A small synthetic dataset in the nuScenes layout, made once for the whole file.
fn synthetic_dataset() -> &'static Path {
    static DATA: OnceLock<tempfile::TempDir> = OnceLock::new();
    DATA.get_or_init(|| {
        let dir = tempfile::tempdir().expect("tempdir");
        let config = bevworld_sensors::synth::SynthConfig {
            seed: 3,
            scenes: 1,
            seconds: 1.0,
            camera_width: 32,
            camera_height: 18,
            agents: 1,
            lidar: bevworld_sensors::synth::render::LidarSpec::nuscenes_like(4.0),
            ..Default::default()
        };
        bevworld_sensors::synth::generate(dir.path(), &config, |_, _| {}).expect("synth");
        dir
    })
    .path()
}

#[test]
fn nuscenes_tables() {
    let dir = tempfile::tempdir().expect("dir");
    copy_dir(synthetic_dataset(), dir.path());
    let tables_dir = dir.path().join(bevworld_sensors::synth::VERSION);
    let tables = [
        "scene",
        "sample",
        "sample_data",
        "calibrated_sensor",
        "sensor",
        "ego_pose",
    ];
    let seeds: Vec<Vec<u8>> = tables
        .iter()
        .map(|t| std::fs::read(tables_dir.join(format!("{t}.json"))).expect("table"))
        .collect();
    let tally = Tally::default();
    runner(48)
        .run(&(0..tables.len(), table_mutation()), |(which, mutation)| {
            let path = tables_dir.join(format!("{}.json", tables[which]));
            std::fs::write(&path, mutate_table(&seeds[which], &mutation)).expect("write");
            let outcome = bounded(&tally, "nuScenes tables", || {
                NuScenes::open(dir.path(), NuScenesOptions::default()).and_then(|data| {
                    for index in 0..data.len().min(2) {
                        data.read(index)?;
                    }
                    Ok(data.len())
                })
            });
            std::fs::write(&path, &seeds[which]).expect("restore");
            if let Err(error) = outcome? {
                let message = error.to_string();
                prop_assert!(names(&message, dir.path()), "{message}");
            }
            Ok(())
        })
        .expect("nuScenes tables");
    tally.print("nuScenes tables");
}

fn some_points(count: usize) -> Vec<LidarPoint> {
    (0..count)
        .map(|i| {
            let f = i as f32;
            LidarPoint {
                x: f,
                y: -f,
                z: 0.5 * f,
                intensity: f / 10.0,
                ring: (i % 32) as u16,
            }
        })
        .collect()
}

#[test]
fn lidar_files() {
    let path = Path::new("fuzzed/LIDAR_TOP.pcd.bin");
    let layouts = [LidarLayout::NuScenes, LidarLayout::Kitti];
    let seeds: Vec<Vec<u8>> = layouts
        .iter()
        .map(|layout| encode_points(&some_points(40), *layout))
        .collect();
    let strategy = (
        0..2usize,
        any::<bool>(),
        mutation(),
        prop::option::weighted(0.2, prop::collection::vec(any::<u8>(), 0..400)),
    );
    let tally = Tally::default();
    runner(256)
        .run(&strategy, |(layout, strict, mutation, raw)| {
            let bytes = raw.unwrap_or_else(|| mutate(&seeds[layout], &mutation));
            let policy = if strict {
                NonFinitePolicy::Error
            } else {
                NonFinitePolicy::Drop
            };
            let result = bounded(&tally, "LiDAR file", || {
                decode_points(&bytes, layouts[layout], policy, path)
            })?;
            match result {
                Ok((points, dropped)) => {
                    let stride = layouts[layout].floats_per_point() * 4;
                    prop_assert_eq!(points.len() + dropped, bytes.len() / stride);
                    prop_assert!(
                        points
                            .iter()
                            .all(|p| p.x.is_finite() && p.y.is_finite() && p.z.is_finite())
                    );
                }
                Err(error) => {
                    let message = error.to_string();
                    prop_assert!(names(&message, path), "{message}");
                }
            }
            Ok(())
        })
        .expect("LiDAR files");
    tally.print("LiDAR files");
}

#[test]
fn kitti_files() {
    let dir = tempfile::tempdir().expect("dir");
    let root = dir.path();
    std::fs::create_dir_all(root.join("velodyne")).expect("mkdir");
    for i in 0..3 {
        std::fs::write(
            root.join(format!("velodyne/{i:06}.bin")),
            encode_points(&some_points(20 + i), LidarLayout::Kitti),
        )
        .expect("scan");
    }
    let calib = "P0: 7.1e+02 0 6.0e+02 0 0 7.1e+02 1.8e+02 0 0 0 1 0\nTr: 4.2e-04 -9.9e-01 -7.2e-03 -1.1e-02 -7.2e-03 8.1e-03 -9.9e-01 -5.4e-02 9.9e-01 4.3e-04 -7.2e-03 -2.9e-01\n";
    let poses = "1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 0 0 1 0 0 0 0 1 0.8\n1 0 0 0 0 1 0 0 0 0 1 1.6\n";
    let times = "0.0\n0.1\n0.2\n";
    let files = [
        ("calib.txt", calib),
        ("poses.txt", poses),
        ("times.txt", times),
    ];
    for (name, text) in files {
        std::fs::write(root.join(name), text).expect("write");
    }
    assert!(
        Kitti::open(root, NonFinitePolicy::Drop).is_ok(),
        "the seed folder reads"
    );
    let tally = Tally::default();
    runner(96)
        .run(&(0..files.len(), mutation()), |(which, mutation)| {
            let (name, seed) = files[which];
            let path = root.join(name);
            std::fs::write(&path, mutate(seed.as_bytes(), &mutation)).expect("write");
            let outcome = bounded(&tally, "KITTI files", || {
                Kitti::open(root, NonFinitePolicy::Drop).and_then(|data| {
                    for index in 0..data.len() {
                        data.decode(data.fetch(index)?)?;
                    }
                    Ok(data.len())
                })
            });
            std::fs::write(&path, seed).expect("restore");
            if let Err(error) = outcome? {
                let message = error.to_string();
                prop_assert!(names(&message, root), "{message}");
            }
            Ok(())
        })
        .expect("KITTI files");
    tally.print("KITTI files");
}

#[test]
fn camera_images() {
    let mut image = image::RgbImage::new(24, 16);
    for (x, y, pixel) in image.enumerate_pixels_mut() {
        *pixel = image::Rgb([(x * 10) as u8, (y * 15) as u8, ((x + y) * 5) as u8]);
    }
    let mut jpeg = Vec::new();
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, 90)
        .encode_image(&image)
        .expect("jpeg");
    let mut png = Vec::new();
    image::codecs::png::PngEncoder::new(&mut png)
        .write_image(image.as_raw(), 24, 16, image::ExtendedColorType::Rgb8)
        .expect("png");
    let seeds = [jpeg, png];
    let tally = Tally::default();
    runner(128)
        .run(
            &(0..2usize, prop::collection::vec(byte_edit(), 1..6)),
            |(which, edits)| {
                let bytes = apply_bytes(&seeds[which], &edits);
                let result = bounded(&tally, "camera image", || {
                    bevworld_sensors::image_file::decode_rgb(&bytes)
                })?;
                match result {
                    // Whatever decodes is a whole image of the size its header gives.
                    Ok(decoded) => prop_assert_eq!(
                        decoded.as_raw().len(),
                        3 * decoded.width() as usize * decoded.height() as usize
                    ),
                    Err(message) => prop_assert!(!message.is_empty()),
                }
                Ok(())
            },
        )
        .expect("camera images");
    tally.print("camera images");
}

use image::ImageEncoder;

#[test]
fn ply_files() {
    let points: Vec<PlyPoint> = (0..12)
        .map(|i| PlyPoint::new(i as f32, 1.0, -2.0, 0.5))
        .collect();
    let seeds = [
        encode_ply(&points, PlyEncoding::BinaryLittleEndian, Some("fuzz")).expect("binary"),
        encode_ply(&points, PlyEncoding::Ascii, None).expect("ascii"),
    ];
    let tally = Tally::default();
    runner(192)
        .run(&(0..2usize, mutation()), |(which, mutation)| {
            let bytes = mutate(&seeds[which], &mutation);
            let result = bounded(&tally, "PLY", || {
                decode_ply(Cursor::new(&bytes), "fuzzed.ply")
            })?;
            if let Err(error) = result {
                let message = error.to_string();
                prop_assert!(message.contains("fuzzed.ply"), "{message}");
            }
            Ok(())
        })
        .expect("PLY");
    tally.print("PLY");
}

#[test]
fn npy_files() {
    let data: Vec<f32> = (0..48).map(|i| i as f32 * 0.25).collect();
    let seed = npy_f32(&[3, 4, 4], &data).expect("npy");
    let tally = Tally::default();
    runner(256)
        .run(&mutation(), |mutation| {
            let bytes = mutate(&seed, &mutation);
            match bounded(&tally, "npy", || read_npy_f32(&bytes))? {
                Ok((shape, values)) => {
                    prop_assert_eq!(shape.iter().product::<usize>(), values.len());
                }
                Err(message) => prop_assert!(!message.is_empty()),
            }
            Ok(())
        })
        .expect("npy");
    tally.print("npy");
}

#[test]
fn burnpack_weights() {
    use bevworld_blocks::{MlpConfig, check_file, load_module, save_module};
    let device = burn::prelude::Device::flex();
    let dir = tempfile::tempdir().expect("dir");
    let seed_path = dir.path().join("seed.bpk");
    save_module(&MlpConfig::new(8, 16).init(&device), "fuzz", &seed_path).expect("save");
    let seed = std::fs::read(&seed_path).expect("seed");
    let path = dir.path().join("fuzzed.bpk");
    let tally = Tally::default();
    runner(96)
        .run(&prop::collection::vec(byte_edit(), 1..6), |edits| {
            std::fs::write(&path, apply_bytes(&seed, &edits)).expect("write");
            let header = bounded(&tally, "burnpack header", || check_file("fuzz", &path))?;
            let loaded = bounded(&tally, "burnpack tensors", || {
                load_module(MlpConfig::new(8, 16).init(&device), "fuzz", "mlp-8", &path)
            })?;
            for message in [header.err(), loaded.err()]
                .into_iter()
                .flatten()
                .map(|e| e.to_string())
            {
                prop_assert!(message.contains("fuzzed.bpk"), "{message}");
            }
            Ok(())
        })
        .expect("burnpack");
    tally.print("burnpack");
}

#[test]
fn checkpoint_state() {
    let dir = tempfile::tempdir().expect("dir");
    let run = dir.path();
    let staged = checkpoint::staging(run, 5).expect("staging");
    std::fs::write(staged.file("model.bpk"), b"weights").expect("write");
    let state = CheckpointState {
        step: 5,
        rng_state: 9,
    };
    let folder = checkpoint::commit(run, staged, &state, 2).expect("commit");
    let state_path = folder.join("state.json");
    let seed = std::fs::read(&state_path).expect("state");
    let tally = Tally::default();
    runner(192)
        .run(&table_mutation(), |mutation| {
            std::fs::write(&state_path, mutate_table(&seed, &mutation)).expect("write");
            match bounded(&tally, "state.json", || checkpoint::latest(run))? {
                // Whatever resumes is the step its folder names.
                Ok((_, read)) => prop_assert_eq!(read.step, 5),
                Err(error) => {
                    let message = error.to_string();
                    prop_assert!(names(&message, run), "{message}");
                }
            }
            Ok(())
        })
        .expect("state.json");
    tally.print("state.json");
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).expect("mkdir");
    for entry in std::fs::read_dir(from).expect("read_dir") {
        let entry = entry.expect("entry");
        let target = to.join(entry.file_name());
        if entry.path().is_dir() {
            copy_dir(&entry.path(), &target);
        } else {
            std::fs::copy(entry.path(), &target).expect("copy");
        }
    }
}

#[test]
fn world_model_meta() {
    use bevworld_world_model::weights::{load_sealed_meta, meta_path_for};
    let dir = tempfile::tempdir().expect("dir");
    let weights = dir.path().join("world-model-tiny.bpk");
    let shipped = repo().join("nodes/world_model/weights/world-model-tiny.bpk");
    std::fs::copy(&shipped, &weights).expect("weights");
    let meta_path = meta_path_for(&weights);
    let seed = std::fs::read(meta_path_for(&shipped)).expect("meta");
    std::fs::write(&meta_path, &seed).expect("write");
    let original = load_sealed_meta(&weights)
        .expect("the shipped meta loads")
        .meta;
    let tally = Tally::default();
    runner(192)
        .run(&table_mutation(), |mutation| {
            std::fs::write(&meta_path, mutate_table(&seed, &mutation)).expect("write");
            match bounded(&tally, ".meta.json", || load_sealed_meta(&weights))? {
                // The seal lets through only what changes nothing (spacing, key order).
                Ok(read) => prop_assert_eq!(&read.meta, &original),
                Err(error) => {
                    let message = error.to_string();
                    prop_assert!(names(&message, &meta_path), "{message}");
                }
            }
            Ok(())
        })
        .expect(".meta.json");
    tally.print(".meta.json");
}

#[test]
fn latent_stats_file() {
    use bevworld_types::LatentStatsFile;
    let dir = tempfile::tempdir().expect("dir");
    let path = dir.path().join("tokenizer-tiny.stats.json");
    let seed = std::fs::read(repo().join("nodes/tokenizer/weights/tokenizer-tiny.stats.json"))
        .expect("stats");
    let tally = Tally::default();
    runner(192)
        .run(&table_mutation(), |mutation| {
            std::fs::write(&path, mutate_table(&seed, &mutation)).expect("write");
            match bounded(&tally, "stats.json", || LatentStatsFile::load(&path))? {
                // Whatever loads can standardise: one finite mean and a finite spread > 0
                // per channel.
                Ok(file) => {
                    let stats = &file.stats;
                    prop_assert!(!stats.mean.is_empty());
                    prop_assert_eq!(stats.mean.len(), stats.std.len());
                    prop_assert!(stats.mean.iter().all(|m| m.is_finite()));
                    prop_assert!(stats.std.iter().all(|s| s.is_finite() && *s > 0.0));
                }
                Err(error) => {
                    let message = error.to_string();
                    prop_assert!(names(&message, &path), "{message}");
                }
            }
            Ok(())
        })
        .expect("stats.json");
    tally.print("stats.json");
}
