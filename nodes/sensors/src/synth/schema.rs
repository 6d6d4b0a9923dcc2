//! What the synthetic world writes beside its sensor data so that the official nuScenes devkit
//! loads it as it loads a real nuScenes folder: the `category`, `attribute` and `visibility`
//! tables with the devkit's names and levels, a `map` whose record names every log and points to
//! a semantic-prior mask, and, per annotation, a visibility graded from the rig.

use std::io::Cursor;

use glam::{DVec2, DVec3};
use serde_json::{Value, json};

use super::geometry::Ray;
use super::render::Snapshot;
use super::rng::token;
use super::world::{RoadSpec, VehicleBody};

/// nuScenes' categories, with their descriptions. `vehicle.car` comes first: its token is the
/// one the world's instances have always named.
pub const CATEGORIES: [(&str, &str); 23] = [
    (
        "vehicle.car",
        "Vehicle designed primarily for personal use, e.g. sedans, hatch-backs, wagons, vans, mini-vans, SUVs and jeeps.",
    ),
    ("human.pedestrian.adult", "Adult subcategory."),
    ("human.pedestrian.child", "Child subcategory."),
    (
        "human.pedestrian.wheelchair",
        "Wheelchairs. If a person is in the wheelchair, include in the annotation.",
    ),
    (
        "human.pedestrian.stroller",
        "Strollers. If a person is in the stroller, include in the annotation.",
    ),
    (
        "human.pedestrian.personal_mobility",
        "A small electric or self-propelled vehicle, e.g. skateboard, segway, or scooters, on which the person typically travels in a upright position.",
    ),
    ("human.pedestrian.police_officer", "Police officer."),
    (
        "human.pedestrian.construction_worker",
        "Construction worker.",
    ),
    ("animal", "All animals, e.g. cats, rats, dogs, deer, birds."),
    (
        "vehicle.motorcycle",
        "Gasoline or electric powered 2-wheeled vehicle designed to move rapidly (at the speed of standard cars) on the road surface.",
    ),
    (
        "vehicle.bicycle",
        "Human or electric powered 2-wheeled vehicle designed to travel at lower speeds either on road surface, sidewalks or bike paths.",
    ),
    (
        "vehicle.bus.bendy",
        "Bendy bus subcategory. Annotate each section of the bendy bus individually.",
    ),
    ("vehicle.bus.rigid", "Rigid bus subcategory."),
    (
        "vehicle.truck",
        "Vehicles primarily designed to haul cargo including pick-ups, lorrys, trucks and semi-tractors.",
    ),
    (
        "vehicle.construction",
        "Vehicles primarily designed for construction. Typically very slow moving or stationary.",
    ),
    ("vehicle.emergency.ambulance", "All types of ambulances."),
    (
        "vehicle.emergency.police",
        "All types of police vehicles including police bicycles and motorcycles.",
    ),
    (
        "vehicle.trailer",
        "Any vehicle trailer, both for trucks, cars and bikes.",
    ),
    (
        "movable_object.barrier",
        "Temporary road barrier placed in the scene in order to redirect traffic.",
    ),
    ("movable_object.trafficcone", "All types of traffic cone."),
    (
        "movable_object.pushable_pullable",
        "Objects that a pedestrian may push or pull.",
    ),
    (
        "movable_object.debris",
        "Movable object that is left on the driveable surface.",
    ),
    (
        "static_object.bicycle_rack",
        "Area or device intended to park or secure the bicycles in a row.",
    ),
];

/// nuScenes' attributes.
pub const ATTRIBUTES: [(&str, &str); 8] = [
    ("vehicle.moving", "Vehicle is moving."),
    (
        "vehicle.stopped",
        "Vehicle, with a driver/rider in/on it, is currently stationary but has an intent to move.",
    ),
    (
        "vehicle.parked",
        "Vehicle is stationary (usually for longer duration) with no immediate intent to move.",
    ),
    (
        "cycle.with_rider",
        "There is a rider on the bicycle or motorcycle.",
    ),
    (
        "cycle.without_rider",
        "There is NO rider on the bicycle or motorcycle.",
    ),
    (
        "pedestrian.sitting_lying_down",
        "The human is sitting or lying down.",
    ),
    ("pedestrian.standing", "The human is standing."),
    ("pedestrian.moving", "The human is moving."),
];

/// nuScenes' visibility levels: the token, its level and its share of the object seen.
pub const VISIBILITY: [(&str, &str, f64); 4] = [
    ("1", "v0-40", 0.0),
    ("2", "v40-60", 0.4),
    ("3", "v60-80", 0.6),
    ("4", "v80-100", 0.8),
];

pub fn category_token(name: &str) -> String {
    let index = CATEGORIES.iter().position(|(n, _)| *n == name).unwrap_or(0);
    token(0, "category", index as u64)
}

pub fn attribute_token(name: &str) -> String {
    let index = ATTRIBUTES.iter().position(|(n, _)| *n == name).unwrap_or(0);
    token(0, "attribute", index as u64)
}

pub fn category_table() -> Vec<Value> {
    CATEGORIES
        .iter()
        .map(|(name, description)| {
            json!({"token": category_token(name), "name": name, "description": description})
        })
        .collect()
}

pub fn attribute_table() -> Vec<Value> {
    ATTRIBUTES
        .iter()
        .map(|(name, description)| {
            json!({"token": attribute_token(name), "name": name, "description": description})
        })
        .collect()
}

pub fn visibility_table() -> Vec<Value> {
    VISIBILITY
        .iter()
        .zip(["0 and 40%", "40 and 60%", "60 and 80%", "80 and 100%"])
        .map(|((token, level, _), range)| {
            json!({"token": token, "level": level, "description": format!("visibility of whole object is between {range}")})
        })
        .collect()
}

/// The map mask's resolution, metres per pixel: the devkit's `MapMask` assumes 0.1.
pub const MAP_RESOLUTION_M: f64 = 0.1;

/// The map record: one semantic prior for the whole town, named by every log.
pub fn map_table(log_tokens: &[String]) -> (Vec<Value>, String) {
    let map_token = token(0, "map", 0);
    let filename = format!("maps/{map_token}.png");
    (
        vec![json!({
            "token": map_token,
            "log_tokens": log_tokens,
            "category": "semantic_prior",
            "filename": filename,
        })],
        filename,
    )
}

/// The semantic prior as the devkit reads it: an 8-bit grey PNG at `MAP_RESOLUTION_M`, 255 on
/// the drivable surface and 0 elsewhere, its bottom-left pixel at the global origin (the devkit
/// maps global (x, y) to pixel (x / 0.1, height − y / 0.1)). The town's margin west and south
/// of the origin falls outside the mask, as nuScenes' masks start at the origin.
pub fn drivable_area_png(roads: &RoadSpec) -> Result<Vec<u8>, String> {
    let (_, max) = roads.extent();
    let width = (max.x / MAP_RESOLUTION_M).ceil() as u32;
    let height = (max.y / MAP_RESOLUTION_M).ceil() as u32;
    let mask = image::GrayImage::from_fn(width, height, |column, row| {
        let x = (f64::from(column) + 0.5) * MAP_RESOLUTION_M;
        let y = (f64::from(height - row) - 0.5) * MAP_RESOLUTION_M;
        image::Luma([if roads.is_drivable(DVec2::new(x, y)) {
            255
        } else {
            0
        }])
    });
    let mut bytes = Vec::new();
    mask.write_to(&mut Cursor::new(&mut bytes), image::ImageFormat::Png)
        .map_err(|e| e.to_string())?;
    Ok(bytes)
}

/// How much of a vehicle the rig sees, as nuScenes' visibility token: points spread over the
/// faces of its box that turn towards `eye` (the LiDAR on the ego's roof), and the share of them
/// a ray from the eye reaches before anything else. (nuScenes grades it by hand in the six
/// images; the rig's cameras sit within a metre of its LiDAR.)
pub fn visibility_token(
    snapshot: &Snapshot,
    eye: DVec3,
    body: &VehicleBody,
    instance: u32,
) -> &'static str {
    let seen = visible_share(snapshot, eye, body, instance);
    VISIBILITY
        .iter()
        .rev()
        .find(|(_, _, from)| seen >= *from)
        .map_or("1", |(token, _, _)| token)
}

/// The share of the sample points of `body`'s box turned to `eye` that `eye` sees.
pub fn visible_share(snapshot: &Snapshot, eye: DVec3, body: &VehicleBody, instance: u32) -> f64 {
    let (sin, cos) = body.yaw.sin_cos();
    let forward = DVec3::new(cos, sin, 0.0);
    let left = DVec3::new(-sin, cos, 0.0);
    let half = DVec3::new(body.size.y * 0.5, body.size.x * 0.5, body.size.z * 0.5);
    let centre = DVec3::new(body.center.x, body.center.y, half.z);
    // Each face: its outward normal, and the two half extents that span it.
    let faces = [
        (forward, left * half.y, DVec3::Z * half.z, half.x),
        (-forward, left * half.y, DVec3::Z * half.z, half.x),
        (left, forward * half.x, DVec3::Z * half.z, half.y),
        (-left, forward * half.x, DVec3::Z * half.z, half.y),
        (DVec3::Z, forward * half.x, left * half.y, half.z),
    ];
    let (mut facing, mut seen) = (0u32, 0u32);
    for (normal, span_u, span_v, offset) in faces {
        let face_centre = centre + normal * offset;
        if normal.dot(eye - face_centre) <= 0.0 {
            continue;
        }
        for u in [-0.7, -0.25, 0.25, 0.7] {
            for v in [-0.6, 0.0, 0.6] {
                // A centimetre out of the face, so the ray does not graze the box itself.
                let point = face_centre + span_u * u + span_v * v + normal * 0.01;
                let to_point = point - eye;
                let distance = to_point.length();
                if distance < 1e-6 {
                    continue;
                }
                facing += 1;
                let ray = Ray {
                    origin: eye,
                    direction: to_point / distance,
                };
                let reached = match snapshot.cast(&ray, distance) {
                    None => true,
                    Some(hit) => hit.instance == instance || hit.t >= distance - 0.05,
                };
                seen += u32::from(reached);
            }
        }
    }
    if facing == 0 {
        0.0
    } else {
        f64::from(seen) / f64::from(facing)
    }
}
