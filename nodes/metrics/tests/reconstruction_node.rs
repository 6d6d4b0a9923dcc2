//! The `reconstruction_metrics` node on the real nuScenes keyframe: the input scored against
//! itself gives the PSNR cap and zero Chamfer once the returns off the car are left out, as a
//! render leaves them out; a rendered point on the car counts; the agent scores split a
//! synthetic keyframe by its annotated vehicles (the real sample ships none: all static); a bad
//! ROI preset or a rendered image of an unknown camera is a clear error, never a panic.

use std::sync::Arc;

use bevworld_graph::{Header, Inputs, Instant, Message, Node, Outputs, Registry, Task};
use bevworld_metrics::Roi;
use bevworld_metrics::reconstruction_node::score_frame;
use bevworld_sensors::{Dataset, DatasetOptions};
use bevworld_types::{ImageSet, NamedImage, PointClass, SensorFrame};

/// The real nuScenes keyframe (`BEVWORLD_DATA`), when it is there.
fn frame() -> Option<SensorFrame> {
    let root = bevworld_sensors::real_dataset("nuscenes-sample")?;
    Some(
        Dataset::open(&root, &DatasetOptions::default())
            .expect("nuScenes sample")
            .read(0)
            .expect("frame 0"),
    )
}

/// The frame's own images, shrunk to 112 x 64 as a render would be.
fn inputs_as_render(frame: &SensorFrame) -> ImageSet {
    ImageSet {
        images: frame
            .cameras
            .iter()
            .map(|c| NamedImage {
                name: c.channel.name().into(),
                image: Arc::new(image::imageops::resize(
                    c.image.as_ref(),
                    112,
                    64,
                    image::imageops::FilterType::Triangle,
                )),
            })
            .collect(),
    }
}

/// The frame's sweep without its returns off the ego car, as a render casts its rays.
fn scene_only(frame: &SensorFrame) -> bevworld_types::PointCloud {
    bevworld_types::PointCloud {
        points: frame
            .lidar
            .scene_indices()
            .into_iter()
            .map(|i| frame.lidar.points[i])
            .collect(),
        ..(*frame.lidar).clone()
    }
}

fn build(params: serde_json::Value) -> Result<Box<dyn Task>, String> {
    let mut registry = Registry::new();
    bevworld_metrics::register(&mut registry);
    match registry
        .get("reconstruction_metrics")
        .expect("registered")
        .build(&params)
    {
        Ok(node) => match node {
            Node::Task(task) => Ok(task),
            _ => Err("not a task".into()),
        },
        Err(error) => Err(format!(
            "{}: {}",
            error.field.unwrap_or_default(),
            error.message
        )),
    }
}

#[test]
fn the_scene_scored_against_itself_is_perfect_and_points_on_the_car_count() {
    let Some(frame) = frame() else {
        return;
    };
    // A render casts no rays for the 8,526 returns off the car, and the ground truth leaves
    // them out too: the scene's own returns score perfectly.
    let scene_only = scene_only(&frame);
    assert_eq!(scene_only.len(), 34_688 - 8_526);
    let scores = score_frame(
        &frame,
        &inputs_as_render(&frame),
        &scene_only,
        &Roi::FOUR_D_OCC,
    )
    .expect("scores");
    assert_eq!(scores.psnr_db, 100.0, "identical images hit the cap");
    assert!((scores.ssim - 1.0).abs() < 1e-9);
    assert_eq!(scores.chamfer_m2, Some(0.0));
    // The sample ships no annotations: every return is static, and each finds itself.
    assert!(frame.boxes.is_empty());
    let static_sums = scores.agents.class(PointClass::Static);
    assert!(static_sums.points > 20_000);
    assert_eq!(static_sums.within_near, static_sums.points);
    assert_eq!(
        scores.agents.class(PointClass::MovingVehicle).points
            + scores.agents.class(PointClass::ParkedVehicle).points,
        0
    );

    // Points on the car in the rendered cloud count against it: with the whole input as the
    // "render", the ground-truth-to-render half is 0 and the other half is each point's
    // squared distance to the nearest scene return (0 for the scene's own), found here by
    // brute force: CD = 1/2 * sum over the car's points / every point.
    let scores = score_frame(
        &frame,
        &inputs_as_render(&frame),
        &frame.lidar,
        &Roi::FOUR_D_OCC,
    )
    .expect("scores");
    let inside = |p: &[f32; 3]| Roi::FOUR_D_OCC.contains(&p.map(f64::from));
    let scene: Vec<[f32; 3]> = frame
        .lidar
        .scene_ego_points()
        .into_iter()
        .filter(inside)
        .collect();
    let rendered: Vec<[f32; 3]> = frame
        .lidar
        .ego_points()
        .into_iter()
        .filter(inside)
        .collect();
    let kept = frame.lidar.scene_indices();
    let ego = frame.lidar.ego_points();
    let on_the_car: Vec<[f32; 3]> = (0..frame.lidar.len())
        .filter(|i| kept.binary_search(i).is_err())
        .map(|i| ego[i])
        .filter(inside)
        .collect();
    assert_eq!(on_the_car.len(), rendered.len() - scene.len());
    let nearest_squared = |p: &[f32; 3]| {
        scene
            .iter()
            .map(|q| {
                (0..3)
                    .map(|k| (f64::from(p[k]) - f64::from(q[k])).powi(2))
                    .sum::<f64>()
            })
            .fold(f64::INFINITY, f64::min)
    };
    let expected =
        0.5 * on_the_car.iter().map(nearest_squared).sum::<f64>() / rendered.len() as f64;
    assert!(expected > 0.0);
    let chamfer = scores.chamfer_m2.expect("both clouds hold points");
    assert!(
        (chamfer - expected).abs() <= 1e-9 * expected,
        "{chamfer} against {expected}",
    );

    let folder = tempfile::tempdir().expect("temporary folder");
    let (csv, json) = (
        folder.path().join("metrics.csv"),
        folder.path().join("deeper/summary.json"),
    );
    let mut sink = build(serde_json::json!({"csv": csv, "json": json})).expect("node");
    let header = Header {
        seq: 0,
        time_of_validity_us: 0,
        entered_graph: Instant::now(),
    };
    let inputs = Inputs::from_messages(
        &["frame", "images", "lidar"],
        vec![
            Some(Message::new(header, frame.clone())),
            Some(Message::new(header, inputs_as_render(&frame))),
            Some(Message::from_shared(header, Arc::clone(&frame.lidar))),
        ],
    );
    sink.process(&inputs, &mut Outputs::detached(&["table"]))
        .expect("consumed");
    let figures = sink.report();
    assert_eq!(figures.get("frames_scored"), Some(&1.0));
    assert_eq!(figures.get("psnr_db_mean"), Some(&100.0));
    assert_eq!(figures.get("empty_clouds"), Some(&0.0));
    assert_eq!(figures.get("truth_non_finite_points_dropped"), Some(&0.0));

    // An empty render is not a perfect one: reported, counted and kept out of the mean.
    let empty = bevworld_types::PointCloud {
        points: Vec::new(),
        ..(*frame.lidar).clone()
    };
    let scores =
        score_frame(&frame, &inputs_as_render(&frame), &empty, &Roi::FOUR_D_OCC).expect("scores");
    assert_eq!(scores.chamfer_m2, None);
    // The source dropped 7 NaN points from this sweep's truth: the table says so.
    let mut dropped = frame.clone();
    Arc::make_mut(&mut dropped.lidar).dropped_non_finite = 7;
    let inputs = Inputs::from_messages(
        &["frame", "images", "lidar"],
        vec![
            Some(Message::new(header, dropped)),
            Some(Message::new(header, inputs_as_render(&frame))),
            Some(Message::new(header, empty)),
        ],
    );
    sink.process(&inputs, &mut Outputs::detached(&["table"]))
        .expect("consumed");
    let figures = sink.report();
    assert_eq!(figures.get("empty_clouds"), Some(&1.0));
    assert_eq!(figures.get("truth_non_finite_points_dropped"), Some(&7.0));
    let mean = *figures.get("chamfer_m2_mean").expect("the real frame's");
    assert!(
        mean > 0.0,
        "the empty render left out of the mean, not averaged in as 0"
    );

    // Both files name the frame's scene; the summary holds the two frames as one scene.
    sink.finish(&mut Outputs::detached(&["table"]))
        .expect("written");
    let rows = std::fs::read_to_string(&csv).expect("csv");
    let lines: Vec<&str> = rows.lines().collect();
    assert_eq!(lines.len(), 3, "{rows}");
    assert!(lines[0].starts_with("frame_token,scene,psnr_db"));
    assert!(
        lines[1].starts_with(&format!(
            "{},{},100.0000,",
            frame.frame_token, frame.scene_name
        )),
        "{rows}"
    );
    let table: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).expect("json")).expect("parsed");
    assert_eq!(table["frames"], 2);
    assert_eq!(table["empty_clouds"], 1);
    assert_eq!(table["scenes"][0]["scene"], frame.scene_name.as_str());
    assert_eq!(table["scenes"][0]["frames"], 2);
    assert_eq!(table["chamfer_m2"].as_f64(), Some(mean));
}

#[test]
fn a_summary_that_cannot_be_written_is_an_error_naming_its_path() {
    let folder = tempfile::tempdir().expect("temporary folder");
    let blocker = folder.path().join("not-a-folder");
    std::fs::write(&blocker, "a file where a folder should be").expect("written");
    let json = blocker.join("summary.json");
    let mut sink = build(serde_json::json!({"json": json})).expect("node");
    let error = sink
        .finish(&mut Outputs::detached(&["table"]))
        .expect_err("refused")
        .to_string();
    assert!(error.contains("not-a-folder"), "{error}");
}

#[test]
fn bad_params_and_unknown_cameras_are_named() {
    let message = build(serde_json::json!({"roi": "nowhere"}))
        .err()
        .expect("refused");
    assert!(
        message.starts_with("roi") && message.contains("nowhere"),
        "{message}"
    );
    let message = build(serde_json::json!({"colour": true}))
        .err()
        .expect("refused");
    assert!(message.contains("colour"), "{message}");

    let Some(frame) = frame() else {
        return;
    };
    let mut images = inputs_as_render(&frame);
    images.images[0].name = "CAM_ROOF".into();
    let error = score_frame(&frame, &images, &frame.lidar, &Roi::FOUR_D_OCC)
        .expect_err("unknown camera")
        .to_string();
    assert!(
        error.contains("CAM_ROOF") && error.contains(&frame.frame_token),
        "{error}"
    );
    let empty = score_frame(&frame, &ImageSet::default(), &frame.lidar, &Roi::FOUR_D_OCC);
    assert!(
        empty
            .expect_err("no images")
            .to_string()
            .contains("no rendered images")
    );
}

/// A synthetic keyframe, whose boxes the world annotates: its own returns recall every class,
/// the vehicles among them; an empty render recalls none.
#[test]
fn a_reconstruction_is_scored_on_the_annotated_vehicles() {
    let dir = tempfile::tempdir().expect("tempdir");
    let data = dir.path().join("synth");
    let config = bevworld_sensors::synth::SynthConfig {
        seed: 31,
        scenes: 1,
        seconds: 0.5,
        camera_width: 112,
        camera_height: 64,
        ..Default::default()
    };
    bevworld_sensors::synth::generate(&data, &config, |_, _| {}).expect("synthetic scene");
    let frame = Dataset::open(&data, &DatasetOptions::default())
        .expect("scene")
        .read(0)
        .expect("keyframe 0");
    assert!(frame.keyframe && frame.boxes.iter().any(|b| b.is_vehicle()));
    let scene_only = scene_only(&frame);
    let images = inputs_as_render(&frame);
    let scores = score_frame(&frame, &images, &scene_only, &Roi::FOUR_D_OCC).expect("scores");
    let on_vehicles = |agents: &bevworld_metrics::agents::AgentSums| {
        agents.class(PointClass::MovingVehicle).points
            + agents.class(PointClass::ParkedVehicle).points
    };
    let vehicle_points = on_vehicles(&scores.agents);
    assert!(vehicle_points > 100, "{vehicle_points} returns on vehicles");
    for class in PointClass::ALL {
        let sums = scores.agents.class(class);
        assert_eq!(sums.within_near, sums.points, "{class:?}");
        assert_eq!(sums.squared, 0.0, "{class:?}");
    }
    let empty = bevworld_types::PointCloud {
        points: Vec::new(),
        ..(*frame.lidar).clone()
    };
    let scores = score_frame(&frame, &images, &empty, &Roi::FOUR_D_OCC).expect("scores");
    assert_eq!(
        on_vehicles(&scores.agents),
        vehicle_points,
        "the same truth"
    );
    for class in PointClass::ALL {
        assert_eq!(scores.agents.class(class).within_far, 0, "{class:?}");
    }
}
