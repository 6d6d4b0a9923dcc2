//! The sinks outside a graph: what they write, and clear errors when they cannot.

use std::sync::Arc;

use bevworld_graph::{Header, Inputs, Instant, Message, Node, Registry};
use bevworld_sinks::ply::read_ply;
use bevworld_types::{ImageSet, LidarPoint, NamedImage, PointCloud, Pose};
use glam::{DQuat, DVec3};

fn header(seq: u64) -> Header {
    Header {
        seq,
        time_of_validity_us: 0,
        entered_graph: Instant::now(),
    }
}

fn build(kind: &str, params: serde_json::Value) -> Box<dyn bevworld_graph::Sink> {
    let mut registry = Registry::new();
    bevworld_sinks::register(&mut registry);
    match registry.get(kind).unwrap().build(&params).ok().unwrap() {
        Node::Sink(sink) => sink,
        _ => panic!("not a sink"),
    }
}

fn cloud() -> PointCloud {
    PointCloud {
        points: vec![
            LidarPoint {
                x: 1.0,
                y: 0.0,
                z: 0.0,
                intensity: 9.0,
                ring: 2,
            },
            LidarPoint {
                x: 0.0,
                y: 2.0,
                z: 1.0,
                intensity: 3.0,
                ring: 5,
            },
        ],
        // LiDAR mounted 1 m forward, 2 m up, yawed +90 degrees.
        ego_from_lidar: Pose::from_rotation_translation(
            DQuat::from_rotation_z(std::f64::consts::FRAC_PI_2),
            DVec3::new(1.0, 0.0, 2.0),
        ),
        ..Default::default()
    }
}

#[test]
fn ply_sink_writes_sensor_or_ego_coordinates() {
    let dir = tempfile::tempdir().unwrap();
    for (frame, expected) in [
        ("sensor", [(1.0, 0.0, 0.0), (0.0, 2.0, 1.0)]),
        ("ego", [(1.0, 1.0, 2.0), (-1.0, 0.0, 3.0)]),
    ] {
        let mut sink = build(
            "ply_sink",
            serde_json::json!({"out": dir.path(), "name": frame, "frame": frame, "encoding": "ascii"}),
        );
        let inputs =
            Inputs::from_messages(&["cloud"], vec![Some(Message::new(header(3), cloud()))]);
        sink.consume(&inputs).unwrap();
        sink.finish().unwrap();
        let points = read_ply(&dir.path().join(format!("000003/{frame}.ply"))).unwrap();
        for (point, (x, y, z)) in points.iter().zip(expected) {
            assert!(
                (point.x - x).abs() < 1e-6
                    && (point.y - y).abs() < 1e-6
                    && (point.z - z).abs() < 1e-6,
                "{frame}: {point:?}"
            );
        }
        assert_eq!(points[0].intensity, 9.0);
    }
}

#[test]
fn png_sink_writes_one_folder_per_frame_with_suffix() {
    let dir = tempfile::tempdir().unwrap();
    let mut sink = build(
        "png_sink",
        serde_json::json!({"out": dir.path(), "suffix": "_recon"}),
    );
    let image = Arc::new(image::RgbImage::from_pixel(8, 4, image::Rgb([10, 20, 30])));
    let set = ImageSet {
        images: vec![NamedImage {
            name: "CAM_FRONT".into(),
            image,
        }],
    };
    sink.consume(&Inputs::from_messages(
        &["images"],
        vec![Some(Message::new(header(12), set))],
    ))
    .unwrap();
    sink.finish().unwrap();
    let back = image::open(dir.path().join("000012/CAM_FRONT_recon.png"))
        .unwrap()
        .into_rgb8();
    assert_eq!(
        (back.width(), back.height(), back.get_pixel(3, 2).0),
        (8, 4, [10, 20, 30])
    );
}

#[test]
fn unwritable_output_is_a_clear_error_naming_the_path() {
    let dir = tempfile::tempdir().unwrap();
    // A file where the output folder should be.
    let blocked = dir.path().join("blocked");
    std::fs::write(&blocked, b"a file").unwrap();
    let mut sink = build("ply_sink", serde_json::json!({"out": blocked}));
    let inputs = Inputs::from_messages(&["cloud"], vec![Some(Message::new(header(0), cloud()))]);
    let error = sink
        .consume(&inputs)
        .and_then(|_| sink.finish())
        .unwrap_err()
        .to_string();
    assert!(error.contains("blocked"), "{error}");
}

#[test]
fn bad_parameters_are_refused() {
    let mut registry = Registry::new();
    bevworld_sinks::register(&mut registry);
    let ply = registry.get("ply_sink").unwrap();
    let error = ply
        .build(&serde_json::json!({"out": "x", "encoding": "binary_big_endian"}))
        .err()
        .unwrap();
    assert_eq!(error.field.as_deref(), Some("encoding"));
    assert!(error.accepted.unwrap().contains("ascii"));
    let error = ply
        .build(&serde_json::json!({"out": "x", "name": "a/b"}))
        .err()
        .unwrap();
    assert_eq!(error.field.as_deref(), Some("name"));
    let png = registry.get("png_sink").unwrap();
    assert_eq!(
        png.build(&serde_json::json!({}))
            .err()
            .unwrap()
            .field
            .as_deref(),
        Some("out")
    );
}

#[test]
fn a_message_of_the_wrong_type_is_an_error_not_a_panic() {
    let dir = tempfile::tempdir().unwrap();
    let mut sink = build("png_sink", serde_json::json!({"out": dir.path()}));
    let inputs = Inputs::from_messages(&["images"], vec![Some(Message::new(header(0), 42u32))]);
    assert!(
        sink.consume(&inputs)
            .unwrap_err()
            .to_string()
            .contains("not a ImageSet")
    );
}
