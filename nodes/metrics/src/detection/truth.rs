//! The ground truth a detector is scored against, and the devkit's filters on both sides: a
//! box farther from the ego than its class's range is left out (truth and predictions alike),
//! so is a true box with no LiDAR or radar return in it, and so is a bicycle or motorcycle
//! whose centre stands in an annotated bicycle rack.

use std::collections::BTreeMap;

use bevworld_types::{Detection, ObjectBox, SensorFrame, detection_name_of};
use glam::DQuat;

/// A ground-truth box with what the filters read.
#[derive(Clone, Debug, PartialEq)]
pub struct TrueBox {
    /// The box, with score -1 as the devkit writes truth.
    pub detection: Detection,
    /// LiDAR plus radar returns inside it.
    pub num_pts: usize,
}

/// One sample's truth: the ego's position at its LiDAR sweep, and the boxes.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SampleTruth {
    pub ego_translation: [f64; 3],
    pub boxes: Vec<TrueBox>,
    /// The sample's annotated bicycle racks (`static_object.bicycle_rack`): a cycle parked in
    /// one is not scored.
    pub bike_racks: Vec<ObjectBox>,
}

/// The devkit's bike-rack rule: a bicycle or motorcycle whose centre lies in a rack's box.
fn in_a_bike_rack(detection: &Detection, racks: &[ObjectBox]) -> bool {
    matches!(detection.detection_name.as_str(), "bicycle" | "motorcycle")
        && racks
            .iter()
            .any(|rack| rack.contains(glam::DVec3::from_array(detection.translation), 0.0, 0.0))
}

/// Planar distance of a box from the ego, m.
pub fn ego_distance(detection: &Detection, ego: &[f64; 3]) -> f64 {
    (detection.translation[0] - ego[0]).hypot(detection.translation[1] - ego[1])
}

/// The truth and predictions the evaluation scores: each sample's boxes within their class's
/// range, true boxes with at least one return, classes outside `ranges` dropped.
pub fn filter_boxes(
    truth: &BTreeMap<String, SampleTruth>,
    predictions: &BTreeMap<String, Vec<Detection>>,
    ranges: &BTreeMap<String, f64>,
) -> (
    BTreeMap<String, Vec<TrueBox>>,
    BTreeMap<String, Vec<Detection>>,
) {
    let within = |detection: &Detection, sample: &SampleTruth| {
        ranges
            .get(&detection.detection_name)
            .is_some_and(|&range| ego_distance(detection, &sample.ego_translation) < range)
            && !in_a_bike_rack(detection, &sample.bike_racks)
    };
    let mut kept_truth = BTreeMap::new();
    let mut kept_predictions = BTreeMap::new();
    for (sample, sample_truth) in truth {
        kept_truth.insert(
            sample.clone(),
            sample_truth
                .boxes
                .iter()
                .filter(|t| within(&t.detection, sample_truth) && t.num_pts > 0)
                .cloned()
                .collect(),
        );
        kept_predictions.insert(
            sample.clone(),
            predictions
                .get(sample)
                .map(Vec::as_slice)
                .unwrap_or_default()
                .iter()
                .filter(|p| within(p, sample_truth))
                .cloned()
                .collect(),
        );
    }
    (kept_truth, kept_predictions)
}

/// One annotated object as the devkit's ground truth: its challenge class (`None` for a
/// category the challenge does not score), its one attribute or none, and a NaN velocity where
/// the dataset could not tell it (the devkit's `box_velocity` gives NaN; the velocity error
/// then skips it).
pub fn true_box(object: &ObjectBox, sample_token: &str) -> Result<Option<TrueBox>, String> {
    let Some(class) = detection_name_of(&object.category) else {
        return Ok(None);
    };
    let attribute_name = match object.attributes.as_slice() {
        [] => String::new(),
        [one] => one.clone(),
        several => {
            return Err(format!(
                "annotation of instance {} has {} attributes ({}); the devkit allows one",
                object.instance_token,
                several.len(),
                several.join(", ")
            ));
        }
    };
    let rotation = DQuat::from_mat3(&object.global_from_box.matrix3);
    Ok(Some(TrueBox {
        detection: Detection {
            sample_token: sample_token.to_string(),
            translation: object.global_from_box.translation.to_array(),
            size: object.size,
            rotation: [rotation.w, rotation.x, rotation.y, rotation.z],
            velocity: object.velocity.unwrap_or([f64::NAN, f64::NAN]),
            detection_name: class.to_string(),
            detection_score: -1.0,
            attribute_name,
        },
        num_pts: usize::try_from(object.num_pts).unwrap_or(0),
    }))
}

/// A keyframe's truth: its sample token, the ego's position at its sweep, and its scored boxes.
pub fn sample_truth(frame: &SensorFrame) -> Result<(String, SampleTruth), String> {
    let boxes = frame
        .boxes
        .iter()
        .filter_map(|object| true_box(object, &frame.sample_token).transpose())
        .collect::<Result<Vec<_>, _>>()?;
    Ok((
        frame.sample_token.clone(),
        SampleTruth {
            ego_translation: frame.global_from_ego.translation.to_array(),
            boxes,
            bike_racks: frame
                .boxes
                .iter()
                .filter(|object| object.category == "static_object.bicycle_rack")
                .cloned()
                .collect(),
        },
    ))
}
