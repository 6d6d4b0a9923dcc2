//! Writes synthetic scenes in the nuScenes layout (`v1.0-synth/*.json`, `samples/`, `sweeps/`)
//! with the same table fields, so the nuScenes reader loads them like any nuScenes split.

use std::collections::BTreeMap;
use std::io::Cursor;
use std::path::{Path, PathBuf};
use std::time::Instant;

use glam::DQuat;
use serde_json::json;

use bevworld_types::{Manoeuvre, Pose};

use super::render::{LidarSpec, render_camera, scan_lidar};
use super::rig::{CAMERAS, LIDAR_ROTATION, LIDAR_TRANSLATION, ego_from_lidar};
use super::rng::token;
use super::scene::{KEYFRAME_EVERY, SceneWorld};
use crate::error::{Result, SensorError};
use crate::lidar_file::{LidarLayout, encode_points};
use crate::nuscenes::tables::{
    CalibratedSensor, EgoPose, Log, Sample, SampleAnnotation, SampleData, Scene, Sensor,
};

pub const VERSION: &str = "v1.0-synth";

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ImageEncoding {
    /// Lossless (the default): reconstruction metrics measure the model, not the codec.
    Png,
    Jpeg {
        quality: u8,
    },
}

#[derive(Clone, Debug)]
pub struct SynthConfig {
    /// Scene k uses seed `seed + k`.
    pub seed: u64,
    pub scenes: usize,
    pub seconds: f64,
    pub camera_width: u32,
    pub camera_height: u32,
    pub lidar: LidarSpec,
    pub agents: usize,
    /// Pedestrians on the sidewalks and cyclists on the roads (`people.rs`); none by default,
    /// which leaves every scene as it was before they existed.
    pub pedestrians: usize,
    pub cyclists: usize,
    pub image_encoding: ImageEncoding,
    /// Camera far plane, m.
    pub far: f64,
    /// Instead of each scene, one scene per manoeuvre, branched at this time.
    pub branch: Option<Branch>,
}

/// Branches of every scene: up to `at_s` seconds the ego drives its script; from there on,
/// in each branch, it drives one manoeuvre through the bicycle model. In a training config:
/// `branch: {at_s: 2.0, manoeuvres: [keep, left, right, faster, slower]}`.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Branch {
    pub at_s: f64,
    pub manoeuvres: Vec<Manoeuvre>,
}

impl Default for SynthConfig {
    fn default() -> Self {
        Self {
            seed: 0,
            scenes: 1,
            seconds: 4.0,
            camera_width: 400,
            camera_height: 224,
            lidar: LidarSpec::nuscenes_like(0.4),
            agents: 14,
            pedestrians: 0,
            cyclists: 0,
            image_encoding: ImageEncoding::Png,
            far: 250.0,
            branch: None,
        }
    }
}

/// The most moving vehicles a scene may hold: traffic is simulated pairwise, so thousands
/// would run for minutes per frame, and a town block has no room for them.
pub const MAX_AGENTS: usize = 200;

impl SynthConfig {
    /// What is wrong with this config, one line per field, each naming the field, its value
    /// and what is accepted. Empty when it can be generated.
    pub fn problems(&self) -> Vec<String> {
        let mut problems = Vec::new();
        if self.scenes == 0 {
            problems.push("scenes: 0 (accepted: 1 or more)".to_string());
        }
        // Scene k uses seed `seed + k`: the last seed must not wrap round to 0.
        let last_scene = self.scenes.saturating_sub(1) as u64;
        if self.seed.checked_add(last_scene).is_none() {
            problems.push(format!(
                "seed: {} with {} scenes: scene seeds would pass {} and wrap round to 0 \
                 (accepted: seed + scenes - 1 <= {})",
                self.seed,
                self.scenes,
                u64::MAX,
                u64::MAX
            ));
        }
        if !(self.seconds.is_finite() && self.seconds > 0.0 && self.seconds <= 3600.0) {
            problems.push(format!(
                "seconds: {} (accepted: more than 0, at most 3600)",
                self.seconds
            ));
        }
        if self.camera_width == 0 || self.camera_height == 0 {
            problems.push(format!(
                "camera size: {}x{} (accepted: both at least 1)",
                self.camera_width, self.camera_height
            ));
        }
        if self.agents > MAX_AGENTS {
            problems.push(format!(
                "agents: {} (accepted: 0 to {MAX_AGENTS})",
                self.agents
            ));
        }
        for (name, count) in [
            ("pedestrians", self.pedestrians),
            ("cyclists", self.cyclists),
        ] {
            if count > MAX_AGENTS {
                problems.push(format!("{name}: {count} (accepted: 0 to {MAX_AGENTS})"));
            }
        }
        if let ImageEncoding::Jpeg { quality } = self.image_encoding
            && !(1..=100).contains(&quality)
        {
            problems.push(format!("jpeg quality: {quality} (accepted: 1 to 100)"));
        }
        if let Some(branch) = &self.branch {
            // The branches differ from the branch on; a branch with no sensor frame after it
            // would be written as its own scene, byte for byte the same as `keep`'s.
            let ticks = ((self.seconds * super::scene::RATE_HZ).round() as usize).max(1);
            let last_frame_s = (ticks - 1) as f64 * super::scene::TICK_US as f64 * 1e-6;
            if !(branch.at_s.is_finite() && branch.at_s > 0.0 && branch.at_s < self.seconds) {
                problems.push(format!(
                    "branch at: {} s (accepted: after 0 and before the scene's end, {} s)",
                    branch.at_s, self.seconds
                ));
            } else if self.seconds.is_finite() && branch.at_s >= last_frame_s {
                problems.push(format!(
                    "branch at: {} s leaves no sensor frame after it: the last frame of a {} s scene is at {last_frame_s:.3} s, so every branch would be the same scene, byte for byte (accepted: before {last_frame_s:.3} s, or a longer scene)",
                    branch.at_s, self.seconds
                ));
            }
            if branch.manoeuvres.is_empty() {
                problems.push("manoeuvres: none (accepted: one or more of keep, left, right, faster, slower, stop)".into());
            }
            let mut seen = Vec::new();
            for m in &branch.manoeuvres {
                if seen.contains(m) {
                    problems.push(format!("manoeuvres: {} named twice", m.name()));
                }
                seen.push(*m);
            }
        }
        problems
    }

    /// The names of the scenes it writes, in order.
    pub fn scene_names(&self) -> Vec<String> {
        self.scene_variants()
            .into_iter()
            .map(|(seed, branch)| scene_variant_name(seed, branch.map(|(_, m)| m)))
            .collect()
    }

    /// The scenes to write: each seed, or each seed's branches, in order.
    pub fn scene_variants(&self) -> Vec<(u64, Option<(f64, Manoeuvre)>)> {
        let seeds = (0..self.scenes as u64).map(|k| self.seed.saturating_add(k));
        match &self.branch {
            None => seeds.map(|seed| (seed, None)).collect(),
            Some(branch) => seeds
                .flat_map(|seed| {
                    branch
                        .manoeuvres
                        .iter()
                        .map(move |m| (seed, Some((branch.at_s, *m))))
                })
                .collect(),
        }
    }
}

#[derive(Clone, Debug, Default)]
pub struct SynthSummary {
    pub scenes: usize,
    pub frames: usize,
    pub keyframes: usize,
    pub lidar_points: usize,
    pub seconds: f64,
}

impl SynthSummary {
    pub fn frames_per_second(&self) -> f64 {
        if self.seconds > 0.0 {
            self.frames as f64 / self.seconds
        } else {
            0.0
        }
    }
}

#[derive(Default)]
struct Tables {
    scene: Vec<Scene>,
    sample: Vec<Sample>,
    sample_data: Vec<SampleData>,
    calibrated_sensor: Vec<CalibratedSensor>,
    sensor: Vec<Sensor>,
    ego_pose: Vec<EgoPose>,
    log: Vec<Log>,
    sample_annotation: Vec<SampleAnnotation>,
    instance: Vec<serde_json::Value>,
    ego_control: Vec<serde_json::Value>,
}

fn write_file(path: &Path, bytes: &[u8]) -> Result<()> {
    if let Some(parent) = path.parent() {
        std::fs::create_dir_all(parent).map_err(|e| SensorError::io(parent, e))?;
    }
    bevworld_graph::io::write_atomic_now(path, bytes).map_err(|e| SensorError::io(path, e))
}

fn rotation_wxyz(pose: &Pose) -> [f64; 4] {
    let q = DQuat::from_mat3(&pose.matrix3);
    [q.w, q.x, q.y, q.z]
}

/// How much an annotated box is grown on every side beyond the body it annotates, m.
pub const BOX_PAD_M: f64 = 0.02;

/// The sweep's points inside a box, counted as the devkit's `points_in_box` counts them: in the
/// box's own frame, within its half extents, bounds included.
fn points_in_box(
    points: &[bevworld_types::LidarPoint],
    global_from_lidar: &Pose,
    global_from_box: &Pose,
    size: [f64; 3],
) -> i64 {
    let box_from_lidar = global_from_box.inverse() * *global_from_lidar;
    let [width, length, height] = size;
    points
        .iter()
        .filter(|p| {
            let q = box_from_lidar.transform_point3(glam::DVec3::new(
                f64::from(p.x),
                f64::from(p.y),
                f64::from(p.z),
            ));
            q.x.abs() <= 0.5 * length && q.y.abs() <= 0.5 * width && q.z.abs() <= 0.5 * height
        })
        .count() as i64
}

/// The token key of a branch of the scene made from `seed`: its own, so that no table row of
/// one branch is mistaken for another's.
fn branch_key(seed: u64, manoeuvre: Manoeuvre) -> u64 {
    let index = Manoeuvre::ALL
        .iter()
        .position(|m| *m == manoeuvre)
        .unwrap_or(0) as u64;
    seed ^ ((index + 1) << 56) ^ 0xB4A2_C000_0000_0000
}

/// The name of the scene made from `seed` (its `scene.json` name and log file).
pub fn scene_name(seed: u64) -> String {
    format!("synth-{seed:06}")
}

/// The name of the scene made from `seed`, or of its branch under `manoeuvre`
/// (`<scene>-<manoeuvre>`, which `eval control` groups by).
pub fn scene_variant_name(seed: u64, manoeuvre: Option<Manoeuvre>) -> String {
    match manoeuvre {
        None => scene_name(seed),
        Some(m) => format!("{}-{}", scene_name(seed), m.name()),
    }
}

/// Generates the dataset under `out`. `progress(frames_done, frames_total)` is called per frame.
pub fn generate(
    out: &Path,
    config: &SynthConfig,
    mut progress: impl FnMut(usize, usize),
) -> Result<SynthSummary> {
    let problems = config.problems();
    if !problems.is_empty() {
        return Err(SensorError::Other(format!(
            "synthetic dataset for {}: {}",
            out.display(),
            problems.join("; ")
        )));
    }
    let started = Instant::now();
    let mut writer = Writer::new(out, config);
    let ticks_per_scene = ((config.seconds * super::scene::RATE_HZ).round() as usize).max(1);
    let total = ticks_per_scene * config.scene_variants().len();
    for (seed, branch) in config.scene_variants() {
        let mut scene = writer.begin_scene(seed, branch);
        for tick in 0..scene.world.ticks {
            writer.write_tick(&mut scene, tick)?;
            progress(writer.summary.frames, total);
        }
    }
    writer.finish(started)
}

/// The dataset being written: its tables, filled scene by scene, tick by tick, and written
/// at the end.
struct Writer<'a> {
    out: &'a Path,
    config: &'a SynthConfig,
    tables: Tables,
    /// The six cameras' channels, then `LIDAR_TOP`: the sensor table's order.
    channels: Vec<String>,
    /// Each instance's category and annotations, in time order, to link as prev/next and
    /// list as instances at the end.
    annotation_chain: BTreeMap<String, (&'static str, Vec<usize>)>,
    summary: SynthSummary,
}

/// One scene (or branch of a scene) being written: its world, and the tokens its rows share.
struct SceneInProgress {
    seed: u64,
    /// The key its tokens are made from: the seed, or the branch's own.
    key: u64,
    name: String,
    world: SceneWorld,
    calib_tokens: Vec<String>,
    keyframe_ticks: Vec<usize>,
    sample_tokens: Vec<String>,
    /// Per channel, the last `sample_data` row written, to link the next to.
    previous_data: Vec<Option<usize>>,
}

impl<'a> Writer<'a> {
    fn new(out: &'a Path, config: &'a SynthConfig) -> Self {
        let mut tables = Tables::default();
        let channels: Vec<String> = CAMERAS
            .iter()
            .map(|c| c.channel.name().to_string())
            .chain(["LIDAR_TOP".to_string()])
            .collect();
        for (index, channel) in channels.iter().enumerate() {
            tables.sensor.push(Sensor {
                token: token(0, "sensor", index as u64),
                channel: channel.clone(),
                modality: if channel == "LIDAR_TOP" {
                    "lidar".into()
                } else {
                    "camera".into()
                },
            });
        }
        Self {
            out,
            config,
            tables,
            channels,
            annotation_chain: BTreeMap::new(),
            summary: SynthSummary {
                scenes: config.scene_variants().len(),
                ..Default::default()
            },
        }
    }

    /// The scene's world and its log, calibration, sample, scene and control rows.
    fn begin_scene(&mut self, seed: u64, branch: Option<(f64, Manoeuvre)>) -> SceneInProgress {
        let config = self.config;
        // A branch shares the world, the traffic, the LiDAR noise and the drive up to the
        // branch with its scene, but not its tokens, so that the tables keep scenes apart.
        let world = SceneWorld::new(seed, config.seconds, config.agents)
            .with_people(config.pedestrians, config.cyclists);
        let (key, name, world) = match branch {
            None => (seed, scene_name(seed), world),
            Some((at_s, manoeuvre)) => (
                branch_key(seed, manoeuvre),
                scene_variant_name(seed, Some(manoeuvre)),
                world.branched(at_s, manoeuvre),
            ),
        };
        let log_token = token(key, "log", 0);
        self.tables.log.push(Log {
            token: log_token.clone(),
            logfile: name.clone(),
            vehicle: "synth".into(),
            date_captured: "2026-01-01".into(),
            location: "synth-city".into(),
        });
        let calib_tokens = self.push_calibration(key);
        let keyframe_ticks: Vec<usize> = (0..world.ticks)
            .filter(|k| k % KEYFRAME_EVERY == 0)
            .collect();
        let sample_tokens: Vec<String> = keyframe_ticks
            .iter()
            .map(|&k| token(key, "sample", k as u64))
            .collect();
        let scene_token = token(key, "scene", 0);
        for (i, &tick) in keyframe_ticks.iter().enumerate() {
            self.tables.sample.push(Sample {
                token: sample_tokens[i].clone(),
                timestamp: world.tick_time_us(tick),
                scene_token: scene_token.clone(),
                prev: if i > 0 {
                    sample_tokens[i - 1].clone()
                } else {
                    String::new()
                },
                next: sample_tokens.get(i + 1).cloned().unwrap_or_default(),
            });
        }
        self.tables.scene.push(Scene {
            token: scene_token.clone(),
            log_token,
            nbr_samples: keyframe_ticks.len(),
            name: name.clone(),
            description: format!(
                "synthetic town drive, seed {seed}, turns {:?}{}",
                world.script.turns,
                branch.map_or(String::new(), |(at_s, m)| format!(
                    ", branched at {at_s} s: {}",
                    m.name()
                ))
            ),
            first_sample_token: sample_tokens.first().cloned().unwrap_or_default(),
            last_sample_token: sample_tokens.last().cloned().unwrap_or_default(),
        });
        for control in &world.controls {
            self.tables.ego_control.push(json!({
                "scene_token": scene_token,
                "timestamp": control.timestamp,
                "speed": control.speed,
                "acceleration": control.acceleration,
                "steering": control.steering,
                "manoeuvre": control.manoeuvre,
            }));
        }
        SceneInProgress {
            seed,
            key,
            name,
            world,
            calib_tokens,
            keyframe_ticks,
            sample_tokens,
            previous_data: vec![None; self.channels.len()],
        }
    }

    /// One calibration per sensor per scene, as nuScenes has one per log; their tokens.
    fn push_calibration(&mut self, key: u64) -> Vec<String> {
        let config = self.config;
        let calib_tokens: Vec<String> = (0..self.channels.len())
            .map(|i| token(key, "calibrated_sensor", i as u64))
            .collect();
        for (i, mount) in CAMERAS.iter().enumerate() {
            let k = mount.intrinsics(config.camera_width, config.camera_height);
            self.tables.calibrated_sensor.push(CalibratedSensor {
                token: calib_tokens[i].clone(),
                sensor_token: self.tables.sensor[i].token.clone(),
                translation: mount.translation,
                rotation: mount.rotation,
                camera_intrinsic: vec![
                    vec![k.fx, 0.0, k.cx],
                    vec![0.0, k.fy, k.cy],
                    vec![0.0, 0.0, 1.0],
                ],
            });
        }
        self.tables.calibrated_sensor.push(CalibratedSensor {
            token: calib_tokens[6].clone(),
            sensor_token: self.tables.sensor[6].token.clone(),
            translation: LIDAR_TRANSLATION,
            rotation: LIDAR_ROTATION,
            camera_intrinsic: Vec::new(),
        });
        calib_tokens
    }

    /// One sensor tick: six camera images, each at its own trigger time, the LiDAR sweep, and
    /// on a keyframe the annotations of the vehicles around the ego.
    fn write_tick(&mut self, scene: &mut SceneInProgress, tick: usize) -> Result<()> {
        let config = self.config;
        let keyframe = tick.is_multiple_of(KEYFRAME_EVERY);
        let nearest_key =
            ((tick + KEYFRAME_EVERY / 2) / KEYFRAME_EVERY).min(scene.keyframe_ticks.len() - 1);
        let sample_token = scene.sample_tokens[nearest_key].clone();
        let folder = if keyframe { "samples" } else { "sweeps" };
        let lidar_time = scene.world.tick_time_us(tick);
        let name = &scene.name;

        for (i, mount) in CAMERAS.iter().enumerate() {
            let time = lidar_time + mount.offset_us;
            let global_from_ego = scene.world.global_from_ego(time);
            let global_from_camera = global_from_ego * mount.ego_from_camera();
            let snapshot = scene.world.snapshot(time);
            let intrinsics = mount.intrinsics(config.camera_width, config.camera_height);
            let (image, _) = render_camera(&snapshot, &intrinsics, &global_from_camera, config.far);
            let (bytes, extension) = encode_image(&image, config.image_encoding)?;
            let file = format!(
                "{folder}/{}/{name}__{}__{time}.{extension}",
                mount.channel.name(),
                mount.channel.name()
            );
            write_file(&self.out.join(&file), &bytes)?;
            push_sample_data(
                &mut self.tables,
                &mut scene.previous_data[i],
                scene.key,
                &sample_token,
                &scene.calib_tokens[i],
                time,
                &global_from_ego,
                keyframe,
                &file,
                extension,
                config.camera_width,
                config.camera_height,
            );
        }

        let global_from_ego = scene.world.global_from_ego(lidar_time);
        let global_from_lidar = global_from_ego * ego_from_lidar();
        let snapshot = scene.world.snapshot(lidar_time);
        let noise_seed = scene.seed.wrapping_mul(1_000_003).wrapping_add(tick as u64);
        let (points, _ids) = scan_lidar(&snapshot, &config.lidar, &global_from_lidar, noise_seed);
        self.summary.lidar_points += points.len();
        let file = format!("{folder}/LIDAR_TOP/{name}__LIDAR_TOP__{lidar_time}.pcd.bin");
        write_file(
            &self.out.join(&file),
            &encode_points(&points, LidarLayout::NuScenes),
        )?;
        push_sample_data(
            &mut self.tables,
            &mut scene.previous_data[6],
            scene.key,
            &sample_token,
            &scene.calib_tokens[6],
            lidar_time,
            &global_from_ego,
            keyframe,
            &file,
            "pcd",
            0,
            0,
        );

        if keyframe {
            self.summary.keyframes += 1;
            let sweep = Sweep {
                time_us: lidar_time,
                points: &points,
                global_from_lidar,
                snapshot: &snapshot,
            };
            self.annotate(scene, &scene.sample_tokens[tick / KEYFRAME_EVERY], &sweep);
        }
        self.summary.frames += 1;
        Ok(())
    }

    /// The keyframe's annotations: every road user between 3 and 60 m of the ego, its box, its
    /// category and attribute, its LiDAR count and its visibility.
    fn annotate(&mut self, scene: &SceneInProgress, sample_token: &str, sweep: &Sweep) {
        let ego = scene.world.ego_position(sweep.time_us);
        let vehicles =
            scene
                .world
                .vehicles_at(sweep.time_us)
                .into_iter()
                .map(|(instance, body, moving)| {
                    let attribute = if moving {
                        "vehicle.moving"
                    } else {
                        "vehicle.parked"
                    };
                    (instance, body, "vehicle.car", attribute)
                });
        let people =
            scene
                .world
                .people_at(sweep.time_us)
                .into_iter()
                .map(|(instance, person, body)| {
                    (instance, body, person.category(), person.attribute())
                });
        let road_users: Vec<_> = vehicles.chain(people).collect();
        for (instance, body, category, attribute) in road_users {
            if (body.center - ego).length() > 60.0 || (body.center - ego).length() < 3.0 {
                continue;
            }
            let instance_token = token(scene.key, "instance", u64::from(instance));
            let index = self.tables.sample_annotation.len();
            // The box is the body's, grown by `BOX_PAD_M` on every side: the returns lie on
            // the body's faces, and a box drawn exactly through them holds only the ones
            // rounding puts inside. Its count is what the devkit's `points_in_box` finds in it.
            let size = [
                body.size.x + 2.0 * BOX_PAD_M,
                body.size.y + 2.0 * BOX_PAD_M,
                body.size.z + 2.0 * BOX_PAD_M,
            ];
            let global_from_box = Pose::from_rotation_translation(
                DQuat::from_rotation_z(body.yaw),
                glam::DVec3::new(body.center.x, body.center.y, body.size.z * 0.5),
            );
            let num_lidar_pts = points_in_box(
                sweep.points,
                &sweep.global_from_lidar,
                &global_from_box,
                size,
            );
            let visibility = super::schema::visibility_token(
                sweep.snapshot,
                sweep.global_from_lidar.translation,
                &body,
                instance,
            );
            self.tables.sample_annotation.push(SampleAnnotation {
                token: token(
                    scene.key,
                    "sample_annotation",
                    index as u64 * 7919 + u64::from(instance),
                ),
                sample_token: sample_token.to_string(),
                instance_token: instance_token.clone(),
                visibility_token: visibility.into(),
                attribute_tokens: vec![super::schema::attribute_token(attribute)],
                translation: [body.center.x, body.center.y, body.size.z * 0.5],
                size,
                rotation: {
                    let q = DQuat::from_rotation_z(body.yaw);
                    [q.w, q.x, q.y, q.z]
                },
                prev: String::new(),
                next: String::new(),
                num_lidar_pts,
                num_radar_pts: 0,
            });
            self.annotation_chain
                .entry(instance_token)
                .or_insert_with(|| (category, Vec::new()))
                .1
                .push(index);
        }
    }

    /// Links each instance's annotations, lists the instances, and writes every table and the
    /// map's mask.
    fn finish(mut self, started: Instant) -> Result<SynthSummary> {
        let tables = &mut self.tables;
        for (instance_token, (category, indices)) in &self.annotation_chain {
            let category = super::schema::category_token(category);
            for w in indices.windows(2) {
                let next = tables.sample_annotation[w[1]].token.clone();
                let prev = tables.sample_annotation[w[0]].token.clone();
                tables.sample_annotation[w[0]].next = next;
                tables.sample_annotation[w[1]].prev = prev;
            }
            tables.instance.push(json!({
                "token": instance_token,
                "category_token": category,
                "nbr_annotations": indices.len(),
                "first_annotation_token": tables.sample_annotation[indices[0]].token,
                "last_annotation_token": tables.sample_annotation[*indices.last().unwrap_or(&indices[0])].token,
            }));
        }
        let out = self.out;
        let dir = out.join(VERSION);
        let write_table = |name: &str, rows: &dyn erased::Rows| -> Result<()> {
            write_file(&dir.join(format!("{name}.json")), &rows.to_json())
        };
        write_table("scene", &tables.scene)?;
        write_table("sample", &tables.sample)?;
        write_table("sample_data", &tables.sample_data)?;
        write_table("calibrated_sensor", &tables.calibrated_sensor)?;
        write_table("sensor", &tables.sensor)?;
        write_table("ego_pose", &tables.ego_pose)?;
        write_table("log", &tables.log)?;
        write_table("sample_annotation", &tables.sample_annotation)?;
        write_table("instance", &tables.instance)?;
        write_table("ego_control", &tables.ego_control)?;
        write_table("category", &super::schema::category_table())?;
        write_table("attribute", &super::schema::attribute_table())?;
        write_table("visibility", &super::schema::visibility_table())?;
        let log_tokens: Vec<String> = tables.log.iter().map(|l| l.token.clone()).collect();
        let (map, map_file) = super::schema::map_table(&log_tokens);
        write_table("map", &map)?;
        let mask = super::schema::drivable_area_png(&super::world::RoadSpec::default())
            .map_err(|e| SensorError::Other(format!("the map mask: {e}")))?;
        write_file(&out.join(map_file), &mask)?;
        self.summary.seconds = started.elapsed().as_secs_f64();
        Ok(self.summary)
    }
}

/// A keyframe's sweep, as the annotations read it.
struct Sweep<'p> {
    time_us: i64,
    points: &'p [bevworld_types::LidarPoint],
    global_from_lidar: Pose,
    snapshot: &'p super::render::Snapshot,
}

mod erased {
    use serde::Serialize;

    /// A table of any row type, as pretty JSON (stable key order, so output is byte-identical).
    pub trait Rows {
        fn to_json(&self) -> Vec<u8>;
    }

    impl<T: Serialize> Rows for Vec<T> {
        fn to_json(&self) -> Vec<u8> {
            serde_json::to_vec_pretty(self).unwrap_or_default()
        }
    }
}

#[allow(clippy::too_many_arguments)]
fn push_sample_data(
    tables: &mut Tables,
    previous: &mut Option<usize>,
    seed: u64,
    sample_token: &str,
    calib_token: &str,
    timestamp: i64,
    global_from_ego: &Pose,
    keyframe: bool,
    file: &str,
    fileformat: &str,
    width: u32,
    height: u32,
) {
    let index = tables.sample_data.len();
    let data_token = token(seed, "sample_data", index as u64);
    tables.ego_pose.push(EgoPose {
        token: data_token.clone(),
        timestamp,
        rotation: rotation_wxyz(global_from_ego),
        translation: global_from_ego.translation.to_array(),
    });
    let prev = previous
        .map(|p| tables.sample_data[p].token.clone())
        .unwrap_or_default();
    if let Some(p) = *previous {
        tables.sample_data[p].next = data_token.clone();
    }
    tables.sample_data.push(SampleData {
        token: data_token.clone(),
        sample_token: sample_token.to_string(),
        ego_pose_token: data_token,
        calibrated_sensor_token: calib_token.to_string(),
        timestamp,
        fileformat: fileformat.to_string(),
        is_key_frame: keyframe,
        height,
        width,
        filename: file.to_string(),
        prev,
        next: String::new(),
    });
    *previous = Some(index);
}

fn encode_image(
    image: &image::RgbImage,
    encoding: ImageEncoding,
) -> Result<(Vec<u8>, &'static str)> {
    let mut bytes = Vec::new();
    match encoding {
        ImageEncoding::Png => {
            image
                .write_to(&mut Cursor::new(&mut bytes), image::ImageFormat::Png)
                .map_err(|e| SensorError::Other(format!("PNG encoding: {e}")))?;
            Ok((bytes, "png"))
        }
        ImageEncoding::Jpeg { quality } => {
            let encoder = image::codecs::jpeg::JpegEncoder::new_with_quality(
                &mut bytes,
                quality.clamp(1, 100),
            );
            image
                .write_with_encoder(encoder)
                .map_err(|e| SensorError::Other(format!("JPEG encoding: {e}")))?;
            Ok((bytes, "jpg"))
        }
    }
}

/// Where a dataset root's table folder is.
pub fn tables_dir(out: &Path) -> PathBuf {
    out.join(VERSION)
}
