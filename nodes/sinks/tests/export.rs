//! The feature export sink: files that parse back, the index, skipping and overwriting.

use bevworld_graph::{Header, Inputs, Instant, Message, Node, Registry, Sink};
use bevworld_sinks::npy::read_npy_f32;
use bevworld_types::{BevFeatures, BevGrid, FrameMeta, Pose};
use glam::DVec3;

fn features(token: &str, value: f32) -> BevFeatures {
    BevFeatures {
        meta: FrameMeta {
            sample_token: format!("sample-{token}"),
            frame_token: token.into(),
            scene_name: "s".into(),
            time_of_validity_us: 42,
            global_from_ego: Pose::from_translation(DVec3::new(1.0, 2.0, 3.0)),
            keyframe: true,
        },
        grid: BevGrid {
            x_range: [-2.0, 2.0],
            y_range: [-1.0, 1.0],
            resolution: 1.0,
            height: 2,
            width: 4,
        },
        channels: vec!["a".into(), "b".into()],
        data: (0..16).map(|k| value + k as f32).collect(),
        model: "test".into(),
        weights_hash: "none".into(),
    }
}

fn sink(params: serde_json::Value) -> Box<dyn Sink> {
    let mut registry = Registry::new();
    bevworld_sinks::register(&mut registry);
    match registry
        .get("export_features")
        .unwrap()
        .build(&params)
        .ok()
        .unwrap()
    {
        Node::Sink(sink) => sink,
        _ => unreachable!(),
    }
}

fn export(params: serde_json::Value, frames: &[BevFeatures]) -> bevworld_graph::Figures {
    let mut sink = sink(params);
    sink.start().unwrap();
    for (seq, frame) in frames.iter().enumerate() {
        let header = Header {
            seq: seq as u64,
            time_of_validity_us: 0,
            entered_graph: Instant::now(),
        };
        sink.consume(&Inputs::from_messages(
            &["features"],
            vec![Some(Message::new(header, frame.clone()))],
        ))
        .unwrap();
    }
    sink.finish().unwrap();
    sink.report()
}

#[test]
fn npy_files_and_index_describe_each_frame() {
    let dir = tempfile::tempdir().unwrap();
    export(
        serde_json::json!({"out": dir.path()}),
        &[features("tok-a", 0.0), features("scene/000001", 100.0)],
    );
    let (shape, data) =
        read_npy_f32(&std::fs::read(dir.path().join("tok-a.npy")).unwrap()).unwrap();
    assert_eq!((shape, data[15]), (vec![2, 2, 4], 15.0));
    assert!(
        dir.path().join("scene_000001.npy").exists(),
        "path separators in tokens become '_'"
    );
    let index: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.path().join("index.json")).unwrap()).unwrap();
    let frames = index["frames"].as_array().unwrap();
    assert_eq!(frames.len(), 2);
    let a = frames.iter().find(|f| f["frame_token"] == "tok-a").unwrap();
    assert_eq!(a["sample_token"], "sample-tok-a");
    assert_eq!(
        a["global_from_ego"][1],
        serde_json::json!([0.0, 1.0, 0.0, 2.0])
    );
    assert_eq!(a["timestamp_us"], 42);
    assert_eq!(a["channels"], serde_json::json!(["a", "b"]));
    assert_eq!(
        (a["model"].as_str(), a["weights_hash"].as_str()),
        (Some("test"), Some("none"))
    );
    assert_eq!(a["grid"]["resolution_m"], 1.0);
}

#[test]
fn reruns_skip_existing_files_unless_overwrite_and_keep_the_index_whole() {
    let dir = tempfile::tempdir().unwrap();
    let first = export(
        serde_json::json!({"out": dir.path()}),
        &[features("a", 0.0)],
    );
    assert_eq!(first["files_written"], 1.0);
    // A leftover temporary file from a killed run (its writer process is gone) is removed
    // at start.
    std::fs::write(dir.path().join("b.npy.4000000000.0.tmp"), b"partial").unwrap();
    let second = export(
        serde_json::json!({"out": dir.path()}),
        &[features("a", 7.0), features("b", 0.0)],
    );
    assert_eq!(
        (second["files_written"], second["skipped_existing"]),
        (1.0, 1.0)
    );
    assert!(!dir.path().join("b.npy.4000000000.0.tmp").exists());
    let (_, kept) = read_npy_f32(&std::fs::read(dir.path().join("a.npy")).unwrap()).unwrap();
    assert_eq!(kept[0], 0.0, "an existing file is not rewritten");
    let third = export(
        serde_json::json!({"out": dir.path(), "overwrite": true}),
        &[features("a", 7.0)],
    );
    assert_eq!(third["files_written"], 1.0);
    let (_, rewritten) = read_npy_f32(&std::fs::read(dir.path().join("a.npy")).unwrap()).unwrap();
    assert_eq!(rewritten[0], 7.0);
    let index: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.path().join("index.json")).unwrap()).unwrap();
    assert_eq!(
        index["frames"].as_array().unwrap().len(),
        2,
        "the index merges runs without duplicates"
    );
}

#[test]
fn safetensors_files_parse_back() {
    let dir = tempfile::tempdir().unwrap();
    export(
        serde_json::json!({"out": dir.path(), "format": "safetensors"}),
        &[features("a", 1.0)],
    );
    let bytes = std::fs::read(dir.path().join("a.safetensors")).unwrap();
    // A file copied away from its index still says what made it.
    let (_, header) = safetensors::SafeTensors::read_metadata(&bytes).unwrap();
    let metadata = header.metadata().clone().unwrap();
    assert_eq!(
        metadata.get("weights_hash").map(String::as_str),
        Some("none")
    );
    assert_eq!(metadata.get("model").map(String::as_str), Some("test"));
    assert_eq!(metadata.get("frame_token").map(String::as_str), Some("a"));
    let tensors = safetensors::SafeTensors::deserialize(&bytes).unwrap();
    let view = tensors.tensor("features").unwrap();
    assert_eq!(
        (view.shape(), view.dtype()),
        (&[2usize, 2, 4][..], safetensors::Dtype::F32)
    );
    assert_eq!(
        f32::from_le_bytes(view.data()[4..8].try_into().unwrap()),
        2.0
    );
}

#[test]
fn bad_parameters_and_a_corrupt_index_are_clear_errors() {
    let mut registry = Registry::new();
    bevworld_sinks::register(&mut registry);
    let kind = registry.get("export_features").unwrap();
    assert_eq!(
        kind.build(&serde_json::json!({"out": "o", "index": "../x.json"}))
            .err()
            .unwrap()
            .field
            .as_deref(),
        Some("index")
    );
    assert_eq!(
        kind.build(&serde_json::json!({"out": "o", "format": "hdf5"}))
            .err()
            .unwrap()
            .field
            .as_deref(),
        Some("format")
    );
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("index.json"), b"{not json").unwrap();
    let mut sink = sink(serde_json::json!({"out": dir.path()}));
    let error = sink.start().unwrap_err().to_string();
    assert!(
        error.contains("index.json") && error.contains("not a valid index"),
        "{error}"
    );
}

#[test]
fn a_resumed_export_keeps_only_files_made_by_the_same_weights() {
    let dir = tempfile::tempdir().unwrap();
    let untrained = |token: &str| BevFeatures {
        weights_hash: "untrained".into(),
        ..features(token, 0.0)
    };
    let shipped = |token: &str| BevFeatures {
        weights_hash: "a30358a23e03bb4b".into(),
        ..features(token, 5.0)
    };
    export(serde_json::json!({"out": dir.path()}), &[untrained("a")]);
    // Resumed with other weights, without overwrite: refused, naming both and the way out.
    let mut sink = sink(serde_json::json!({"out": dir.path()}));
    sink.start().unwrap();
    let header = Header {
        seq: 0,
        time_of_validity_us: 0,
        entered_graph: Instant::now(),
    };
    let error = sink
        .consume(&Inputs::from_messages(
            &["features"],
            vec![Some(Message::new(header, shipped("a")))],
        ))
        .expect_err("relabelled")
        .to_string();
    assert!(
        error.contains("untrained")
            && error.contains("a30358a23e03bb4b")
            && error.contains("--overwrite"),
        "{error}"
    );
    let index: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.path().join("index.json")).unwrap()).unwrap();
    assert_eq!(
        index["frames"][0]["weights_hash"], "untrained",
        "the index still tells the truth"
    );

    // A file no index knows (a run killed before its index) is written again, not trusted.
    std::fs::write(dir.path().join("b.npy"), b"unknown origin").unwrap();
    let figures = export(
        serde_json::json!({"out": dir.path(), "index": "other.json"}),
        &[shipped("b")],
    );
    assert_eq!(figures["rewritten_unindexed"], 1.0);
    let (_, values) = read_npy_f32(&std::fs::read(dir.path().join("b.npy")).unwrap()).unwrap();
    assert_eq!(values[0], 5.0);
    // And the same weights resume as before: kept, counted.
    let figures = export(serde_json::json!({"out": dir.path()}), &[untrained("a")]);
    assert_eq!(figures["skipped_existing"], 1.0);
}
