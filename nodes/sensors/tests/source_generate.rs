//! A graph's `generate` block makes its own folder and nothing else: `--set source.data=DIR` at a
//! missing DIR is an error that names DIR, and concurrent makers of one folder leave one whole
//! dataset and no staging folders.

use std::path::Path;

use bevworld_graph::Source;
use bevworld_sensors::source::{DatasetSource, DatasetSourceParams};
use bevworld_sensors::synth::{InPlace, SynthConfig, VERSION, generate_in_place};
use bevworld_sensors::{Dataset, DatasetOptions};

fn params(data: &Path, generate_dir: &Path) -> DatasetSourceParams {
    serde_json::from_value(serde_json::json!({
        "data": data,
        "skip_images": true,
        "generate": {"dir": generate_dir, "seed": 3, "seconds": 0.5, "camera_size": "96x54"},
    }))
    .expect("valid source parameters")
}

fn half_second_scene() -> SynthConfig {
    SynthConfig {
        seed: 4,
        scenes: 1,
        seconds: 0.5,
        camera_width: 96,
        camera_height: 54,
        ..Default::default()
    }
}

fn names_in(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .expect("list folder")
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    names
}

#[test]
fn a_missing_data_folder_that_generate_does_not_name_is_an_error() {
    let root = tempfile::tempdir().expect("tempdir");
    let demo = root.path().join("synth-demo");
    let typo = root.path().join("nuscenes-smaple");
    let mut source = DatasetSource::new(params(&typo, &demo)).expect("params");
    let message = source.start().expect_err("missing data").to_string();
    assert!(
        message.contains(&typo.display().to_string())
            && message.contains("does not exist")
            && message.contains(&demo.display().to_string()),
        "{message}"
    );
    assert!(
        names_in(root.path()).is_empty(),
        "nothing is made for a missing folder: {:?}",
        names_in(root.path())
    );
}

#[test]
fn the_folder_generate_names_is_made_once_and_replayed() {
    let root = tempfile::tempdir().expect("tempdir");
    let demo = root.path().join("synth-demo");
    // Spelled differently from `data`, it is still the same folder.
    let spelled = root.path().join(".").join("synth-demo/");
    let mut source = DatasetSource::new(params(&demo, &spelled)).expect("params");
    let info = source.start().expect("generated and opened");
    assert_eq!(info.total, Some(1), "0.5 s holds one 2 Hz keyframe");
    assert_eq!(names_in(root.path()), ["synth-demo"]);
    let made = std::fs::metadata(demo.join(VERSION).join("scene.json"))
        .and_then(|m| m.modified())
        .expect("scene table");

    // A second start finds it and makes nothing.
    let mut again = DatasetSource::new(params(&demo, &demo)).expect("params");
    again.start().expect("reopened");
    let after = std::fs::metadata(demo.join(VERSION).join("scene.json"))
        .and_then(|m| m.modified())
        .expect("scene table");
    assert_eq!(made, after);
}

#[test]
fn concurrent_makers_of_one_folder_leave_one_whole_dataset() {
    let root = tempfile::tempdir().expect("tempdir");
    let dir = root.path().join("set");
    let config = half_second_scene();
    let outcomes: Vec<InPlace> = std::thread::scope(|scope| {
        let makers: Vec<_> = (0..3)
            .map(|_| scope.spawn(|| generate_in_place(&dir, &config, |_, _| {})))
            .collect();
        makers
            .into_iter()
            .map(|maker| {
                maker
                    .join()
                    .expect("no panic")
                    .expect("each maker succeeds")
            })
            .collect()
    });
    let generated = outcomes
        .iter()
        .filter(|o| matches!(o, InPlace::Generated(_)))
        .count();
    assert!(generated >= 1, "{outcomes:?}");
    assert_eq!(names_in(root.path()), ["set"], "no staging folder is left");
    let dataset = Dataset::open(&dir, &DatasetOptions::default()).expect("a whole dataset");
    assert_eq!(dataset.len(), 1);
}

#[test]
fn staging_left_by_a_killed_maker_is_removed() {
    let root = tempfile::tempdir().expect("tempdir");
    let dir = root.path().join("set");
    // No process has this id: Linux's pid_max is at most 2^22.
    let abandoned = root.path().join("set.partial-4294967-0");
    std::fs::create_dir_all(abandoned.join("samples")).expect("abandoned staging");
    let config = half_second_scene();
    generate_in_place(&dir, &config, |_, _| {}).expect("made");
    let expected: &[&str] = if cfg!(target_os = "linux") {
        &["set"]
    } else {
        &["set", "set.partial-4294967-0"]
    };
    assert_eq!(names_in(root.path()), expected);
}
