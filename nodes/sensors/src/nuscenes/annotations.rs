//! The annotated objects of a nuScenes-layout dataset: each keyframe's boxes with their
//! category and velocity, every token resolved when the dataset is opened. The tables are
//! optional as a group (a test split has none); present, they must be whole.

use std::collections::HashMap;
use std::path::Path;

use bevworld_types::{ObjectBox, pose_from_translation_quaternion};

use super::tables::{Attribute, Category, Instance, Sample, SampleAnnotation, read_table};
use crate::error::{Result, SensorError};

/// The devkit's `box_velocity` gives up on neighbours further apart than this, seconds.
const MAX_VELOCITY_GAP_S: f64 = 1.5;

/// Each sample's boxes, by sample token; empty when the dataset has no `sample_annotation`.
pub fn boxes_by_sample(dir: &Path, samples: &[Sample]) -> Result<HashMap<String, Vec<ObjectBox>>> {
    if !dir.join("sample_annotation.json").is_file() {
        return Ok(HashMap::new());
    }
    let (path, annotations) = read_table::<SampleAnnotation>(dir, "sample_annotation")?;
    let (instance_path, instances) = read_table::<Instance>(dir, "instance")?;
    let (category_path, categories) = read_table::<Category>(dir, "category")?;
    let category_of: HashMap<&str, &str> = categories
        .iter()
        .map(|c| (c.token.as_str(), c.name.as_str()))
        .collect();
    let mut category_of_instance: HashMap<&str, &str> = HashMap::new();
    for instance in &instances {
        let name = category_of
            .get(instance.category_token.as_str())
            .ok_or_else(|| {
                SensorError::field(
                    &instance_path,
                    format!("instance {}", instance.token),
                    "category_token",
                    format!(
                        "dangling token '{}' (not in {})",
                        instance.category_token,
                        category_path.display()
                    ),
                )
            })?;
        category_of_instance.insert(instance.token.as_str(), name);
    }
    // Only read when an annotation names an attribute: a set without attributes may lack it.
    let attributes = if annotations.iter().any(|a| !a.attribute_tokens.is_empty()) {
        read_table::<Attribute>(dir, "attribute")?.1
    } else {
        Vec::new()
    };
    let attribute_of: HashMap<&str, &str> = attributes
        .iter()
        .map(|a| (a.token.as_str(), a.name.as_str()))
        .collect();
    let time_of: HashMap<&str, i64> = samples
        .iter()
        .map(|s| (s.token.as_str(), s.timestamp))
        .collect();
    let by_token: HashMap<&str, &SampleAnnotation> =
        annotations.iter().map(|a| (a.token.as_str(), a)).collect();
    let mut boxes: HashMap<String, Vec<ObjectBox>> = HashMap::new();
    for annotation in &annotations {
        let record = format!("sample_annotation {}", annotation.token);
        let dangling = |field: &'static str, token: &str, table: &Path| {
            SensorError::field(
                &path,
                &record,
                field,
                format!("dangling token '{token}' (not in {})", table.display()),
            )
        };
        let time = *time_of
            .get(annotation.sample_token.as_str())
            .ok_or_else(|| {
                dangling(
                    "sample_token",
                    &annotation.sample_token,
                    &dir.join("sample.json"),
                )
            })?;
        let category = category_of_instance
            .get(annotation.instance_token.as_str())
            .ok_or_else(|| {
                dangling("instance_token", &annotation.instance_token, &instance_path)
            })?;
        let attribute_names = annotation
            .attribute_tokens
            .iter()
            .map(|token| {
                attribute_of
                    .get(token.as_str())
                    .map(|name| (*name).to_string())
                    .ok_or_else(|| dangling("attribute_tokens", token, &dir.join("attribute.json")))
            })
            .collect::<Result<Vec<_>>>()?;
        for (field, token) in [("prev", &annotation.prev), ("next", &annotation.next)] {
            if !token.is_empty() && !by_token.contains_key(token.as_str()) {
                return Err(dangling(field, token, &path));
            }
        }
        let global_from_box =
            pose_from_translation_quaternion(annotation.translation, annotation.rotation)
                .ok_or_else(|| {
                    SensorError::field(
                        &path,
                        &record,
                        "rotation",
                        "not a valid rotation quaternion or translation",
                    )
                })?;
        if !annotation.size.iter().all(|s| s.is_finite() && *s > 0.0) {
            return Err(SensorError::field(
                &path,
                &record,
                "size",
                format!(
                    "{:?}: a box needs a finite width, length and height > 0",
                    annotation.size
                ),
            ));
        }
        // The devkit's `box_velocity`: the centre's change between the neighbours (or this
        // annotation and its one neighbour) over their time apart.
        let neighbour = |token: &str| -> Option<(&SampleAnnotation, i64)> {
            let other = by_token.get(token)?;
            Some((*other, *time_of.get(other.sample_token.as_str())?))
        };
        let (first, last) = match (neighbour(&annotation.prev), neighbour(&annotation.next)) {
            (Some(p), Some(n)) => (Some(p), Some(n)),
            (Some(p), None) => (Some(p), Some((annotation, time))),
            (None, Some(n)) => (Some((annotation, time)), Some(n)),
            (None, None) => (None, None),
        };
        // As the devkit has it: each time in seconds before the difference (which rounds the
        // interval to the 0.24 µs an epoch time holds), and twice the gap for a centred one.
        let centred = first.is_some_and(|(a, _)| a.token != annotation.token)
            && last.is_some_and(|(b, _)| b.token != annotation.token);
        let largest_gap = if centred {
            2.0 * MAX_VELOCITY_GAP_S
        } else {
            MAX_VELOCITY_GAP_S
        };
        let velocity = first.zip(last).and_then(|((a, ta), (b, tb))| {
            let dt = tb as f64 * 1e-6 - ta as f64 * 1e-6;
            (dt > 0.0 && dt <= largest_gap).then(|| {
                [
                    (b.translation[0] - a.translation[0]) / dt,
                    (b.translation[1] - a.translation[1]) / dt,
                ]
            })
        });
        boxes
            .entry(annotation.sample_token.clone())
            .or_default()
            .push(ObjectBox {
                instance_token: annotation.instance_token.clone(),
                category: (*category).to_string(),
                global_from_box,
                size: annotation.size,
                velocity: velocity.filter(|v| v.iter().all(|x| x.is_finite())),
                attributes: attribute_names,
                num_pts: annotation.num_lidar_pts + annotation.num_radar_pts,
            });
    }
    Ok(boxes)
}
