//! A synthetic set named by its seed range, as training configs name their sets: made once,
//! then held to exactly its scenes.

use bevworld_sensors::synth::SynthSet;

#[test]
fn a_synthetic_set_is_made_once_and_a_folder_of_other_scenes_is_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    let set = SynthSet {
        dir: dir.path().join("set"),
        seed: 5,
        scenes: 1,
        seconds: 0.5,
        camera_size: "112x64".into(),
    };
    set.ensure().expect("a missing set is made");
    let left: Vec<_> = std::fs::read_dir(dir.path())
        .expect("list")
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(left, ["set"], "no staging folder is left beside the set");
    set.ensure().expect("the set it made is accepted");

    let other_seed = SynthSet {
        seed: 6,
        ..set.clone()
    };
    let message = other_seed
        .ensure()
        .expect_err("scenes of another seed")
        .to_string();
    for part in [
        set.dir.display().to_string(),
        "holds 1 scene(s) (synth-000005)".into(),
        "from seed 6 (synth-000006)".into(),
    ] {
        assert!(message.contains(&part), "{message}: no '{part}'");
    }
    let more = SynthSet {
        scenes: 2,
        ..set.clone()
    };
    let message = more
        .ensure()
        .expect_err("fewer scenes than asked for")
        .to_string();
    assert!(
        message.contains("2 scene(s) from seed 5 (synth-000005 … synth-000006)"),
        "{message}"
    );
    let bad_size = SynthSet {
        dir: dir.path().join("other"),
        camera_size: "wide".into(),
        ..set.clone()
    };
    let message = bad_size
        .ensure()
        .expect_err("a size that is not WxH")
        .to_string();
    assert!(
        message.contains("other") && message.contains("camera_size"),
        "{message}"
    );
    assert!(!dir.path().join("other").exists(), "nothing made");
}
