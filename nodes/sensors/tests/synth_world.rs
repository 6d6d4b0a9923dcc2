//! The synthetic world: deterministic output, LiDAR points on the surfaces they hit, annotation
//! boxes consistent with what the cameras see, and ego poses that the recorded controls replay.

use std::collections::BTreeMap;
use std::path::Path;

use bevworld_sensors::nuscenes::tables::{EgoPose, SampleAnnotation, SampleData, read_table};
use bevworld_sensors::nuscenes::{NuScenes, NuScenesOptions};
use bevworld_sensors::synth::geometry::Ray;
use bevworld_sensors::synth::render::{LidarSpec, render_camera, scan_lidar};
use bevworld_sensors::synth::rig::{CAMERAS, ego_from_lidar};
use bevworld_sensors::synth::traffic::BicycleState;
use bevworld_sensors::synth::{SceneWorld, SynthConfig, VERSION, generate};
use glam::{DVec2, DVec3};

fn tiny(seed: u64) -> SynthConfig {
    SynthConfig {
        seed,
        scenes: 1,
        seconds: 1.0,
        camera_width: 96,
        camera_height: 54,
        lidar: LidarSpec::nuscenes_like(2.0),
        agents: 6,
        ..Default::default()
    }
}

fn all_files(root: &Path) -> BTreeMap<String, Vec<u8>> {
    let mut files = BTreeMap::new();
    let mut stack = vec![root.to_path_buf()];
    while let Some(dir) = stack.pop() {
        for entry in std::fs::read_dir(&dir).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                stack.push(path);
            } else {
                files.insert(
                    path.strip_prefix(root).unwrap().display().to_string(),
                    std::fs::read(&path).unwrap(),
                );
            }
        }
    }
    files
}

#[test]
fn same_seed_gives_byte_identical_files_and_seeds_differ() {
    let (a, b, c) = (
        tempfile::tempdir().unwrap(),
        tempfile::tempdir().unwrap(),
        tempfile::tempdir().unwrap(),
    );
    generate(a.path(), &tiny(5), |_, _| {}).unwrap();
    generate(b.path(), &tiny(5), |_, _| {}).unwrap();
    generate(c.path(), &tiny(6), |_, _| {}).unwrap();
    let (fa, fb, fc) = (
        all_files(a.path()),
        all_files(b.path()),
        all_files(c.path()),
    );
    assert!(fa.len() > 80, "{} files", fa.len()); // 12 ticks x 7 sensors + tables
    assert_eq!(fa, fb, "same seed, same bytes");
    assert_ne!(
        fa.get("v1.0-synth/ego_pose.json"),
        fc.get("v1.0-synth/ego_pose.json"),
        "scenes differ by seed"
    );
}

#[test]
fn the_reader_loads_it_with_keyframes_at_2hz_and_sweeps_at_12hz() {
    let dir = tempfile::tempdir().unwrap();
    let summary = generate(
        dir.path(),
        &SynthConfig {
            seconds: 1.5,
            ..tiny(1)
        },
        |_, _| {},
    )
    .unwrap();
    assert_eq!((summary.frames, summary.keyframes), (18, 3));
    let keyframes = NuScenes::open(dir.path(), NuScenesOptions::default()).unwrap();
    assert_eq!(keyframes.version(), VERSION);
    assert_eq!(keyframes.len(), 3);
    let sweeps = NuScenes::open(
        dir.path(),
        NuScenesOptions {
            sweeps: true,
            ..Default::default()
        },
    )
    .unwrap();
    assert_eq!(sweeps.len(), 18);
    let frame = sweeps.read(1).unwrap();
    assert_eq!(frame.cameras.len(), 6);
    assert_eq!(
        (
            frame.cameras[0].image.width(),
            frame.cameras[0].image.height()
        ),
        (96, 54)
    );
    assert!(frame.lidar.len() > 1000);
    let second = sweeps.read(2).unwrap();
    assert_eq!(
        second.time_of_validity_us - frame.time_of_validity_us,
        83_333
    );
    // Actions derived from poses: a forward speed in a town's range.
    let action = frame.action.unwrap();
    assert!(
        action.speed_mps > 0.5 && action.speed_mps < 20.0,
        "{action:?}"
    );
    assert!((action.dt_s - 0.083333).abs() < 1e-6);
}

#[test]
fn every_lidar_point_lies_on_the_surface_an_exact_ray_cast_hits() {
    let world = SceneWorld::new(11, 1.0, 8);
    let t = world.tick_time_us(3);
    let snapshot = world.snapshot(t);
    let global_from_lidar = world.global_from_ego(t) * ego_from_lidar();
    let spec = LidarSpec::nuscenes_like(1.0);
    let (points, _) = scan_lidar(&snapshot, &spec, &global_from_lidar, 0);
    assert!(points.len() > 5000, "{} points", points.len());
    let origin = global_from_lidar.translation;
    let mut hit_solids = 0;
    for p in points.iter().step_by(7) {
        let local = DVec3::new(f64::from(p.x), f64::from(p.y), f64::from(p.z));
        let range = local.length();
        let direction = global_from_lidar.transform_vector3(local / range);
        // Reference: every primitive tested, no grid.
        let hit = snapshot
            .cast_brute_force(&Ray { origin, direction }, 200.0)
            .expect("a return must have a surface");
        assert!(
            (hit.t - range).abs() < 1e-3,
            "range {range} vs analytic {}",
            hit.t
        );
        if hit.material != bevworld_sensors::synth::world::Material::Asphalt {
            hit_solids += 1;
        }
    }
    assert!(hit_solids > 50, "only {hit_solids} points on solids");
}

#[test]
fn noise_and_drop_change_ranges_and_counts() {
    let world = SceneWorld::new(11, 1.0, 4);
    let t = world.tick_time_us(0);
    let snapshot = world.snapshot(t);
    let pose = world.global_from_ego(t) * ego_from_lidar();
    let exact = scan_lidar(&snapshot, &LidarSpec::nuscenes_like(2.0), &pose, 1).0;
    let mut noisy_spec = LidarSpec::nuscenes_like(2.0);
    noisy_spec.range_noise = 0.05;
    noisy_spec.drop_probability = 0.2;
    let noisy = scan_lidar(&snapshot, &noisy_spec, &pose, 1).0;
    let kept = noisy.len() as f64 / exact.len() as f64;
    assert!((kept - 0.8).abs() < 0.03, "kept {kept}");
}

#[test]
fn annotated_boxes_contain_every_pixel_of_their_vehicle() {
    let dir = tempfile::tempdir().unwrap();
    let config = SynthConfig {
        camera_width: 320,
        camera_height: 180,
        ..tiny(3)
    };
    generate(dir.path(), &config, |_, _| {}).unwrap();
    let tables = dir.path().join(VERSION);
    let (_, annotations) = read_table::<SampleAnnotation>(&tables, "sample_annotation").unwrap();
    let world = SceneWorld::new(3, config.seconds, config.agents);
    let dataset = NuScenes::open(dir.path(), NuScenesOptions::default()).unwrap();
    let frame = dataset.read(0).unwrap();
    let parked_from = config.agents as u32 + 1;
    let mut checked_pixels = 0usize;
    for camera in &frame.cameras {
        let mount = CAMERAS
            .iter()
            .find(|m| m.channel == camera.channel)
            .unwrap();
        let global_from_camera = camera.global_from_ego * mount.ego_from_camera();
        let (_, ids) = render_camera(
            &world.snapshot(camera.timestamp_us),
            &camera.intrinsics,
            &global_from_camera,
            250.0,
        );
        let camera_from_global = global_from_camera.inverse();
        for (instance, body, moving) in world.vehicles_at(frame.time_of_validity_us) {
            if moving || instance < parked_from {
                continue; // moving cars move between the LiDAR and camera trigger times
            }
            let Some(annotation) = annotations.iter().find(|a| {
                a.sample_token == frame.sample_token
                    && (DVec2::new(a.translation[0], a.translation[1]) - body.center).length()
                        < 1e-9
            }) else {
                continue;
            };
            // The annotation's 8 corners, projected; every pixel of the car must fall inside.
            let yaw = body.yaw;
            let (w, l, h) = (annotation.size[0], annotation.size[1], annotation.size[2]);
            let mut lo = DVec2::splat(f64::INFINITY);
            let mut hi = DVec2::splat(f64::NEG_INFINITY);
            let mut in_front = true;
            for (sx, sy, sz) in [
                (-1., -1., 0.),
                (1., -1., 0.),
                (-1., 1., 0.),
                (1., 1., 0.),
                (-1., -1., 1.),
                (1., -1., 1.),
                (-1., 1., 1.),
                (1., 1., 1.),
            ] {
                let local = DVec2::new(sx * l / 2.0, sy * w / 2.0);
                let rotated = DVec2::new(
                    local.x * yaw.cos() - local.y * yaw.sin(),
                    local.x * yaw.sin() + local.y * yaw.cos(),
                );
                let corner = DVec3::new(
                    annotation.translation[0] + rotated.x,
                    annotation.translation[1] + rotated.y,
                    sz * h,
                );
                match camera
                    .intrinsics
                    .project(camera_from_global.transform_point3(corner))
                {
                    Some(uv) => {
                        lo = lo.min(uv);
                        hi = hi.max(uv);
                    }
                    None => in_front = false,
                }
            }
            if !in_front {
                continue;
            }
            let width = camera.intrinsics.width as usize;
            for (index, &id) in ids.iter().enumerate() {
                if id != instance {
                    continue;
                }
                let (u, v) = ((index % width) as f64 + 0.5, (index / width) as f64 + 0.5);
                assert!(
                    u >= lo.x - 1.0 && u <= hi.x + 1.0 && v >= lo.y - 1.0 && v <= hi.y + 1.0,
                    "{}: pixel ({u}, {v}) of car {instance} outside its box [{lo}, {hi}]",
                    camera.channel.name()
                );
                checked_pixels += 1;
            }
        }
    }
    assert!(
        checked_pixels > 100,
        "only {checked_pixels} vehicle pixels checked"
    );
}

#[test]
fn recorded_controls_replay_the_ego_poses() {
    let dir = tempfile::tempdir().unwrap();
    generate(
        dir.path(),
        &SynthConfig {
            seconds: 3.0,
            ..tiny(9)
        },
        |_, _| {},
    )
    .unwrap();
    let tables = dir.path().join(VERSION);
    let (_, controls) = read_table::<serde_json::Value>(&tables, "ego_control").unwrap();
    let (_, data) = read_table::<SampleData>(&tables, "sample_data").unwrap();
    let (_, poses) = read_table::<EgoPose>(&tables, "ego_pose").unwrap();
    let lidar_poses: Vec<&EgoPose> = data
        .iter()
        .filter(|d| d.filename.contains("LIDAR_TOP"))
        .map(|d| poses.iter().find(|p| p.token == d.ego_pose_token).unwrap())
        .collect();
    assert_eq!(lidar_poses.len(), controls.len());
    let yaw_of = |p: &EgoPose| {
        let [w, x, y, z] = p.rotation;
        (2.0 * (w * z + x * y)).atan2(1.0 - 2.0 * (y * y + z * z))
    };
    let first = lidar_poses[0];
    let mut state = BicycleState {
        position: DVec2::new(first.translation[0], first.translation[1]),
        yaw: yaw_of(first),
        speed: controls[0]["speed"].as_f64().unwrap(),
    };
    let mut travelled = 0.0;
    for (k, control) in controls.iter().enumerate() {
        let pose = lidar_poses[k];
        let error =
            (state.position - DVec2::new(pose.translation[0], pose.translation[1])).length();
        assert!(error < 1e-6, "tick {k}: replayed position off by {error} m");
        let previous = state.position;
        state = state.advance(
            control["acceleration"].as_f64().unwrap(),
            control["steering"].as_f64().unwrap(),
            1.0 / 12.0,
        );
        travelled += (state.position - previous).length();
    }
    assert!(
        travelled > 5.0,
        "the ego should drive, travelled {travelled} m"
    );
}

/// A config that cannot be generated is refused before anything is written, naming each
/// field: a seed range that would wrap round to 0, a JPEG quality outside 1..=100, too many
/// agents, no scenes, and a non-finite length.
#[test]
fn a_config_that_cannot_be_generated_is_refused_naming_its_fields() {
    let dir = tempfile::tempdir().expect("tempdir");
    let cases: Vec<(SynthConfig, &str)> = vec![
        (
            SynthConfig {
                seed: u64::MAX,
                scenes: 2,
                ..tiny(0)
            },
            "seed: 18446744073709551615 with 2 scenes",
        ),
        (
            SynthConfig {
                image_encoding: bevworld_sensors::synth::ImageEncoding::Jpeg { quality: 0 },
                ..tiny(0)
            },
            "jpeg quality: 0",
        ),
        (
            SynthConfig {
                image_encoding: bevworld_sensors::synth::ImageEncoding::Jpeg { quality: 101 },
                ..tiny(0)
            },
            "jpeg quality: 101",
        ),
        (
            SynthConfig {
                agents: 100_000,
                ..tiny(0)
            },
            "agents: 100000",
        ),
        (
            SynthConfig {
                scenes: 0,
                ..tiny(0)
            },
            "scenes: 0",
        ),
        (
            SynthConfig {
                seconds: f64::NAN,
                ..tiny(0)
            },
            "seconds: NaN",
        ),
    ];
    for (config, expected) in cases {
        let out = dir.path().join("refused");
        let message = match generate(&out, &config, |_, _| {}) {
            Ok(_) => panic!("{expected}: generated"),
            Err(error) => error.to_string(),
        };
        assert!(message.contains(expected), "{message}");
        assert!(!out.exists(), "{expected}: nothing is written");
    }
    // The last seed that does not wrap is accepted.
    let edge = SynthConfig {
        seed: u64::MAX - 1,
        scenes: 2,
        ..tiny(0)
    };
    assert!(edge.problems().is_empty(), "{:?}", edge.problems());
    // A branch needs a sensor frame after it: 4 s at 12 Hz ends at tick 47, 3.917 s.
    let branched = |at_s: f64| SynthConfig {
        seconds: 4.0,
        branch: Some(bevworld_sensors::synth::Branch {
            at_s,
            manoeuvres: vec![
                bevworld_types::Manoeuvre::Keep,
                bevworld_types::Manoeuvre::Stop,
            ],
        }),
        ..tiny(0)
    };
    for at_s in [3.99, 3.95, 47.0 * 0.083_333] {
        let problems = branched(at_s).problems();
        assert!(
            problems
                .iter()
                .any(|p| p.contains("no sensor frame after it")),
            "{at_s}: {problems:?}"
        );
    }
    assert!(branched(3.9).problems().is_empty());
}

#[test]
fn a_branch_drives_its_manoeuvre_from_the_shared_state() {
    use bevworld_types::Manoeuvre;
    use bevworld_types::manoeuvre::{STOP_DECELERATION_MPS2, TURN_RATE_RPS};

    let plain = SceneWorld::new(9740, 4.0, 0);
    let branch_tick = 12; // 1 s at 12 Hz
    for manoeuvre in Manoeuvre::ALL {
        let branched = SceneWorld::new(9740, 4.0, 0).branched(1.0, manoeuvre);
        // The past is the scene's own.
        assert_eq!(
            branched.states[..=branch_tick],
            plain.states[..=branch_tick]
        );
        assert_eq!(
            branched.controls[..branch_tick],
            plain.controls[..branch_tick]
        );
        let start = branched.states[branch_tick];
        let end = branched.states[branched.ticks - 1];
        let seconds = (branched.ticks - 1 - branch_tick) as f64 / 12.0;
        let turned = end.yaw - start.yaw;
        match manoeuvre {
            Manoeuvre::Left | Manoeuvre::Right => {
                let sign = if manoeuvre == Manoeuvre::Left {
                    1.0
                } else {
                    -1.0
                };
                // The steering is set for the yaw rate at each tick's speed.
                assert!(
                    (turned - sign * TURN_RATE_RPS * seconds).abs() < 0.05,
                    "{manoeuvre:?}: {turned}"
                );
                assert!((end.speed - start.speed).abs() < 1e-9);
            }
            Manoeuvre::Stop => {
                assert_eq!(
                    end.speed, 0.0,
                    "stopped {seconds} s after braking at {STOP_DECELERATION_MPS2} m/s² from {}",
                    start.speed
                );
                assert!(turned.abs() < 1e-9);
            }
            Manoeuvre::Faster => assert!(end.speed > start.speed + 1.4 * seconds),
            Manoeuvre::Slower => assert!(end.speed < start.speed),
            Manoeuvre::Keep => assert!((end.speed - start.speed).abs() < 1e-9),
        }
        assert!(
            branched.controls[branch_tick..]
                .iter()
                .all(|c| c.manoeuvre == format!("branch_{}", manoeuvre.name()))
        );
    }
}

/// The reader gives each keyframe its annotated boxes: vehicles with the category of their
/// instance, and a velocity from their neighbours that agrees with the world's own motion.
#[test]
fn keyframes_carry_their_boxes_with_category_and_velocity() {
    let dir = tempfile::tempdir().unwrap();
    let config = SynthConfig {
        seconds: 3.0,
        ..tiny(5)
    };
    generate(dir.path(), &config, |_, _| {}).unwrap();
    let reader = NuScenes::open(
        dir.path(),
        NuScenesOptions {
            sweeps: true,
            skip_images: true,
            ..Default::default()
        },
    )
    .unwrap();
    let (_, annotations) =
        read_table::<SampleAnnotation>(&dir.path().join(VERSION), "sample_annotation").unwrap();
    let written_moving = |annotation: &SampleAnnotation| {
        annotation.attribute_tokens
            == [bevworld_sensors::synth::schema::attribute_token(
                "vehicle.moving",
            )]
    };
    let mut keyframes_with_boxes = 0;
    let (mut moving, mut standing) = (0, 0);
    for index in 0..reader.len() {
        let frame = reader.read(index).unwrap();
        let annotated: Vec<&SampleAnnotation> = annotations
            .iter()
            .filter(|a| a.sample_token == frame.sample_token)
            .collect();
        // Sweeps share their keyframe's sample token but carry no boxes of their own.
        let keyframe = frame.index_in_scene.is_multiple_of(6);
        if !keyframe {
            assert!(frame.boxes.is_empty(), "sweep {index}");
            continue;
        }
        assert_eq!(frame.boxes.len(), annotated.len(), "keyframe {index}");
        keyframes_with_boxes += usize::from(!frame.boxes.is_empty());
        for (object, annotation) in frame.boxes.iter().zip(&annotated) {
            assert_eq!(object.category, "vehicle.car");
            assert_eq!(object.instance_token, annotation.instance_token);
            // The attribute by name, and the returns as the table counts them.
            let attribute = if written_moving(annotation) {
                "vehicle.moving"
            } else {
                "vehicle.parked"
            };
            assert_eq!(object.attributes, [attribute]);
            assert_eq!(
                object.num_pts,
                annotation.num_lidar_pts + annotation.num_radar_pts
            );
            let written_moving = written_moving(annotation);
            // An agent annotated at one keyframe only has no velocity; every other one's speed
            // says whether the world drove it.
            if object.velocity.is_some() {
                assert_eq!(
                    object.is_moving(),
                    written_moving,
                    "{} at {:.2} m/s",
                    object.instance_token,
                    object.speed_mps()
                );
                if object.is_moving() {
                    moving += 1;
                } else {
                    standing += 1;
                }
            }
        }
    }
    assert!(keyframes_with_boxes >= 5, "{keyframes_with_boxes}");
    assert!(
        moving > 0 && standing > 0,
        "{moving} moving, {standing} standing"
    );
}

/// Annotations whose tokens dangle, or whose box is impossible, are refused naming the table,
/// the record and the field.
#[test]
fn broken_annotations_are_refused_naming_table_record_and_field() {
    let edit = |table: &str, field: &str, value: serde_json::Value| {
        let dir = tempfile::tempdir().unwrap();
        generate(dir.path(), &tiny(6), |_, _| {}).unwrap();
        let path = dir.path().join(VERSION).join(format!("{table}.json"));
        let mut rows: serde_json::Value =
            serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap();
        rows[0][field] = value;
        std::fs::write(&path, serde_json::to_vec(&rows).unwrap()).unwrap();
        NuScenes::open(dir.path(), NuScenesOptions::default())
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default()
    };
    for (table, field, value, says) in [
        (
            "sample_annotation",
            "instance_token",
            serde_json::json!("nobody"),
            "dangling token 'nobody'",
        ),
        (
            "sample_annotation",
            "sample_token",
            serde_json::json!("never"),
            "dangling token 'never'",
        ),
        (
            "sample_annotation",
            "next",
            serde_json::json!("gone"),
            "dangling token 'gone'",
        ),
        (
            "sample_annotation",
            "size",
            serde_json::json!([0.0, 4.0, 1.5]),
            "width, length and height > 0",
        ),
        (
            "sample_annotation",
            "rotation",
            serde_json::json!([0.0, 0.0, 0.0, 0.0]),
            "rotation",
        ),
        (
            "instance",
            "category_token",
            serde_json::json!("nothing"),
            "dangling token 'nothing'",
        ),
        (
            "sample_annotation",
            "attribute_tokens",
            serde_json::json!(["unheard-of"]),
            "dangling token 'unheard-of'",
        ),
    ] {
        let message = edit(table, field, value);
        assert!(
            message.contains(&format!("{table}.json"))
                && message.contains(field)
                && message.contains(says),
            "{table}.{field}: {message}"
        );
    }
}

/// Every token the tables reference resolves, as the nuScenes devkit's reverse index needs
/// (it loads these tables and fails on the first that does not), the map names every log and
/// its mask is where it says, and each box's `num_lidar_pts` is what the devkit's
/// `points_in_box` finds in it.
#[test]
fn the_tables_hold_together_as_the_nuscenes_schema_requires() {
    use serde_json::Value;
    use std::collections::HashSet;
    let dir = tempfile::tempdir().unwrap();
    let config = SynthConfig {
        scenes: 2,
        seconds: 1.5,
        ..tiny(8)
    };
    generate(dir.path(), &config, |_, _| {}).unwrap();
    let tables = dir.path().join(VERSION);
    let table = |name: &str| -> Vec<Value> {
        serde_json::from_slice(&std::fs::read(tables.join(format!("{name}.json"))).unwrap())
            .unwrap()
    };
    let tokens = |name: &str| -> HashSet<String> {
        table(name)
            .iter()
            .map(|r| r["token"].as_str().unwrap().to_string())
            .collect()
    };
    let resolves = |rows: &[Value], field: &str, into: &HashSet<String>, may_be_empty: bool| {
        for row in rows {
            let value = row[field]
                .as_str()
                .unwrap_or_else(|| panic!("{field} in {row}"));
            assert!(
                (may_be_empty && value.is_empty()) || into.contains(value),
                "{field} '{value}' does not resolve"
            );
        }
    };
    let annotations = table("sample_annotation");
    assert!(!annotations.is_empty());
    let (samples, instances) = (tokens("sample"), tokens("instance"));
    let (categories, attributes) = (tokens("category"), tokens("attribute"));
    let (visibility, annotation_tokens) = (tokens("visibility"), tokens("sample_annotation"));
    resolves(&annotations, "sample_token", &samples, false);
    resolves(&annotations, "instance_token", &instances, false);
    resolves(&annotations, "visibility_token", &visibility, false);
    resolves(&annotations, "prev", &annotation_tokens, true);
    resolves(&annotations, "next", &annotation_tokens, true);
    for row in &annotations {
        let attribute = row["attribute_tokens"].as_array().unwrap();
        assert_eq!(attribute.len(), 1);
        assert!(attributes.contains(attribute[0].as_str().unwrap()));
    }
    let instance_rows = table("instance");
    resolves(&instance_rows, "category_token", &categories, false);
    resolves(
        &instance_rows,
        "first_annotation_token",
        &annotation_tokens,
        false,
    );
    resolves(
        &instance_rows,
        "last_annotation_token",
        &annotation_tokens,
        false,
    );
    // The devkit's names: categories, attributes and the four visibility levels.
    let names = |name: &str| -> HashSet<String> {
        table(name)
            .iter()
            .map(|r| r["name"].as_str().unwrap().to_string())
            .collect()
    };
    assert!(names("category").contains("vehicle.car"));
    assert!(names("category").contains("human.pedestrian.adult"));
    assert!(names("attribute").contains("vehicle.parked"));
    assert_eq!(
        visibility,
        ["1", "2", "3", "4"].iter().map(|s| s.to_string()).collect()
    );
    // The map names every log, and its mask is a PNG at 0.1 m per pixel.
    let maps = table("map");
    assert_eq!(maps.len(), 1);
    let logged: HashSet<String> = maps[0]["log_tokens"]
        .as_array()
        .unwrap()
        .iter()
        .map(|t| t.as_str().unwrap().to_string())
        .collect();
    assert_eq!(logged, tokens("log"));
    let mask = image::open(dir.path().join(maps[0]["filename"].as_str().unwrap()))
        .unwrap()
        .into_luma8();
    assert_eq!(
        (mask.width(), mask.height()),
        (5100, 5100),
        "510 m at 0.1 m"
    );
    // The road along x at y = 0 (pixel row height − 1) is drivable; a block's centre is not.
    assert_eq!(mask.get_pixel(1000, mask.height() - 1).0, [255]);
    assert_eq!(mask.get_pixel(300, mask.height() - 301).0, [0]);
    // num_lidar_pts, counted as the devkit counts (corner projections, bounds included).
    let dataset = NuScenes::open(
        dir.path(),
        NuScenesOptions {
            skip_images: true,
            ..Default::default()
        },
    )
    .unwrap();
    let mut compared = 0;
    for index in 0..dataset.len() {
        let frame = dataset.read(index).unwrap();
        let global_from_lidar = frame.lidar.global_from_ego * frame.lidar.ego_from_lidar;
        let points: Vec<DVec3> = frame
            .lidar
            .points
            .iter()
            .map(|p| {
                global_from_lidar.transform_point3(DVec3::new(p.x.into(), p.y.into(), p.z.into()))
            })
            .collect();
        for row in annotations
            .iter()
            .filter(|a| a["sample_token"] == frame.sample_token.as_str())
        {
            let translation: Vec<f64> = row["translation"]
                .as_array()
                .unwrap()
                .iter()
                .map(|v| v.as_f64().unwrap())
                .collect();
            let size: Vec<f64> = row["size"]
                .as_array()
                .unwrap()
                .iter()
                .map(|v| v.as_f64().unwrap())
                .collect();
            let q: Vec<f64> = row["rotation"]
                .as_array()
                .unwrap()
                .iter()
                .map(|v| v.as_f64().unwrap())
                .collect();
            let rotation = glam::DQuat::from_xyzw(q[1], q[2], q[3], q[0]);
            let centre = DVec3::new(translation[0], translation[1], translation[2]);
            // The devkit: corners 0 (front-left-top), 1, 3 and 4 span the box; a point is in
            // when its projections on the three edges lie within them.
            let corner = |x: f64, y: f64, z: f64| {
                centre
                    + rotation * DVec3::new(x * size[1] / 2.0, y * size[0] / 2.0, z * size[2] / 2.0)
            };
            let (p1, p2, p4, p5) = (
                corner(1.0, 1.0, 1.0),
                corner(1.0, -1.0, 1.0),
                corner(-1.0, 1.0, 1.0),
                corner(1.0, 1.0, -1.0),
            );
            let (i, j, k) = (p2 - p1, p4 - p1, p5 - p1);
            let inside = points
                .iter()
                .filter(|p| {
                    let v = **p - p1;
                    let within = |axis: DVec3| {
                        let d = v.dot(axis);
                        0.0 <= d && d <= axis.dot(axis)
                    };
                    within(i) && within(j) && within(k)
                })
                .count() as i64;
            assert_eq!(inside, row["num_lidar_pts"].as_i64().unwrap(), "{row}");
            compared += 1;
        }
    }
    assert!(compared > 10, "{compared}");
}

/// A vehicle the rig sees whole is graded v80-100; one behind a wall, v0-40.
#[test]
fn visibility_grades_what_the_rig_sees_of_a_vehicle() {
    use bevworld_sensors::synth::geometry::Shape;
    use bevworld_sensors::synth::render::Snapshot;
    use bevworld_sensors::synth::schema::{visibility_token, visible_share};
    use bevworld_sensors::synth::world::{Material, RoadSpec, Solid, VehicleBody};
    let car = VehicleBody {
        center: DVec2::new(20.0, 0.0),
        yaw: 0.0,
        size: DVec3::new(1.9, 4.5, 1.6),
        colour: [200, 30, 30],
    };
    let eye = DVec3::new(0.0, 0.0, 1.8);
    let open = Snapshot::new(RoadSpec::default(), car.solids(7).to_vec());
    assert!(visible_share(&open, eye, &car, 7) > 0.95);
    assert_eq!(visibility_token(&open, eye, &car, 7), "4");
    let wall = Solid {
        shape: Shape::Box {
            center: DVec2::new(10.0, 0.0),
            half: DVec2::new(0.2, 5.0),
            yaw: 0.0,
            z_min: 0.0,
            z_max: 4.0,
        },
        material: Material::Kerb,
        instance: 0,
    };
    let mut solids = car.solids(7).to_vec();
    solids.push(wall);
    let hidden = Snapshot::new(RoadSpec::default(), solids);
    assert!(visible_share(&hidden, eye, &car, 7) < 0.05);
    assert_eq!(visibility_token(&hidden, eye, &car, 7), "1");
}

/// Pedestrians and cyclists: annotated under their own categories and attributes, listed as
/// instances of those categories, hit by the LiDAR, and seen by the cameras.
#[test]
fn pedestrians_and_cyclists_are_annotated_hit_and_seen() {
    use bevworld_sensors::nuscenes::tables::Instance;
    let dir = tempfile::tempdir().unwrap();
    let config = SynthConfig {
        seconds: 2.0,
        pedestrians: 30,
        cyclists: 10,
        ..tiny(12)
    };
    generate(dir.path(), &config, |_, _| {}).unwrap();
    let tables = dir.path().join(VERSION);
    let (_, annotations) = read_table::<SampleAnnotation>(&tables, "sample_annotation").unwrap();
    let (_, instances) = read_table::<Instance>(&tables, "instance").unwrap();
    let category_of: BTreeMap<&str, &str> = instances
        .iter()
        .map(|i| (i.token.as_str(), i.category_token.as_str()))
        .collect();
    let token = bevworld_sensors::synth::schema::category_token;
    let attribute = bevworld_sensors::synth::schema::attribute_token;
    let mut seen: BTreeMap<&str, (usize, i64)> = BTreeMap::new();
    for annotation in &annotations {
        let category = category_of[annotation.instance_token.as_str()];
        let (name, allowed): (&str, &[&str]) = if category == token("human.pedestrian.adult") {
            ("pedestrian", &["pedestrian.moving", "pedestrian.standing"])
        } else if category == token("vehicle.bicycle") {
            ("bicycle", &["cycle.with_rider"])
        } else {
            assert_eq!(category, token("vehicle.car"));
            ("car", &["vehicle.moving", "vehicle.parked"])
        };
        assert!(
            allowed
                .iter()
                .any(|a| annotation.attribute_tokens == [attribute(a)]),
            "{name}: {:?}",
            annotation.attribute_tokens
        );
        let entry = seen.entry(name).or_default();
        entry.0 += 1;
        entry.1 = entry.1.max(annotation.num_lidar_pts);
    }
    for name in ["pedestrian", "bicycle", "car"] {
        let (count, most_points) = seen.get(name).copied().unwrap_or_default();
        assert!(count > 0 && most_points > 0, "{name}: {seen:?}");
    }
    // A pedestrian box is person-sized, a cyclist's bicycle-long.
    for annotation in &annotations {
        let category = category_of[annotation.instance_token.as_str()];
        if category == token("human.pedestrian.adult") {
            assert!(
                annotation.size[2] > 1.5 && annotation.size[1] < 0.9,
                "{:?}",
                annotation.size
            );
        } else if category == token("vehicle.bicycle") {
            assert!(
                annotation.size[1] > 1.6 && annotation.size[0] < 0.9,
                "{:?}",
                annotation.size
            );
        }
    }
    // People come from streams of their own: the cars are where they were without them.
    let plain = tempfile::tempdir().unwrap();
    generate(
        plain.path(),
        &SynthConfig {
            seconds: 2.0,
            ..tiny(12)
        },
        |_, _| {},
    )
    .unwrap();
    let (_, without) =
        read_table::<SampleAnnotation>(&plain.path().join(VERSION), "sample_annotation").unwrap();
    let car = token("vehicle.car");
    let cars = |rows: &[SampleAnnotation]| -> Vec<(String, [f64; 3], [f64; 3])> {
        rows.iter()
            .filter(|a| {
                category_of
                    .get(a.instance_token.as_str())
                    .is_some_and(|c| *c == car)
            })
            .map(|a| (a.instance_token.clone(), a.translation, a.size))
            .collect()
    };
    let with_people: Vec<_> = cars(&annotations);
    assert!(!with_people.is_empty());
    assert_eq!(with_people, cars(&without));
}
