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
        branch: None,
        pedestrians: 0,
        cyclists: 0,
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

#[test]
fn a_branched_set_holds_one_scene_per_manoeuvre_and_a_plain_set_is_not_taken_for_it() {
    use bevworld_sensors::synth::Branch;
    use bevworld_types::Manoeuvre;
    let dir = tempfile::tempdir().expect("tempdir");
    let branched = SynthSet {
        dir: dir.path().join("branches"),
        seed: 7,
        scenes: 1,
        seconds: 1.0,
        camera_size: "112x64".into(),
        branch: Some(Branch {
            at_s: 0.5,
            manoeuvres: vec![Manoeuvre::Left, Manoeuvre::Right],
        }),
        pedestrians: 0,
        cyclists: 0,
    };
    branched.ensure().expect("a missing branched set is made");
    let dataset =
        bevworld_sensors::Dataset::open(&branched.dir, &Default::default()).expect("the set opens");
    let mut names = dataset.scene_names();
    names.dedup();
    assert_eq!(names, ["synth-000007-left", "synth-000007-right"]);
    branched.ensure().expect("the set it made is accepted");

    // The same folder read as the plain scene of that seed: another set, refused.
    let plain = SynthSet {
        branch: None,
        ..branched.clone()
    };
    let message = plain
        .ensure()
        .expect_err("branches are not the scene")
        .to_string();
    assert!(
        message.contains("holds 2 scene(s) (synth-000007-left … synth-000007-right)")
            && message.contains("1 scene(s) from seed 7 (synth-000007)"),
        "{message}"
    );
    let parsed: SynthSet = serde_saphyr::from_str(
        "{dir: d, seed: 7, scenes: 1, seconds: 1.0, camera_size: 112x64, branch: {at_s: 0.5, manoeuvres: [left, right]}}",
    )
    .expect("the YAML form");
    assert_eq!(parsed.branch, branched.branch);
    let unknown = serde_saphyr::from_str::<SynthSet>(
        "{dir: d, seed: 7, scenes: 1, seconds: 1.0, camera_size: 112x64, branch: {at_s: 0.5, manoeuvres: [reverse]}}",
    )
    .expect_err("no such manoeuvre")
    .to_string();
    assert!(unknown.contains("reverse"), "{unknown}");
}
