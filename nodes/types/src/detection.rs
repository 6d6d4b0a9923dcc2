//! 3D detections in the nuScenes detection format: one `Detection` per box, as the devkit's
//! `DetectionBox` holds it, and the submission file (`results_nusc.json`: `meta` plus `results`
//! keyed by sample token) that the official devkit scores. What a detector emits, a sink
//! writes, and `eval detector` reads back and scores.
//!
//! Read strictly: a missing field is named, and a box the devkit would assert on (a non-finite
//! value, a size that is not positive, a class or attribute it does not know, more than 500
//! boxes in one sample) is refused naming the sample and the box.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

/// The ten classes the nuScenes detection challenge scores, in the devkit's order.
pub const DETECTION_NAMES: [&str; 10] = [
    "car",
    "truck",
    "bus",
    "trailer",
    "construction_vehicle",
    "pedestrian",
    "motorcycle",
    "bicycle",
    "traffic_cone",
    "barrier",
];

/// The attributes a detection may carry (or `""` for none), as the devkit lists them.
pub const ATTRIBUTE_NAMES: [&str; 8] = [
    "pedestrian.moving",
    "pedestrian.sitting_lying_down",
    "pedestrian.standing",
    "cycle.with_rider",
    "cycle.without_rider",
    "vehicle.moving",
    "vehicle.parked",
    "vehicle.stopped",
];

/// The most boxes the devkit accepts for one sample.
pub const MAX_BOXES_PER_SAMPLE: usize = 500;

/// One box, in the global frame.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Detection {
    pub sample_token: String,
    /// Centre, m.
    pub translation: [f64; 3],
    /// Width, length, height, m.
    pub size: [f64; 3],
    /// Heading as a quaternion, w x y z.
    pub rotation: [f64; 4],
    /// Planar velocity, m/s.
    pub velocity: [f64; 2],
    /// One of `DETECTION_NAMES`.
    pub detection_name: String,
    /// In [0, 1] for a prediction; -1 for a ground-truth box, as the devkit writes it.
    pub detection_score: f64,
    /// One of `ATTRIBUTE_NAMES`, or `""`.
    pub attribute_name: String,
}

impl Detection {
    /// The heading about the vertical axis, rad: the quaternion's yaw, as the devkit's
    /// `quaternion_yaw` reads it.
    pub fn yaw(&self) -> f64 {
        let [w, x, y, z] = self.rotation;
        let norm = (w * w + x * x + y * y + z * z).sqrt();
        let (w, x, y, z) = (w / norm, x / norm, y / norm, z / norm);
        // The box's x axis, rotated, projected on the ground plane.
        let forward_x = 1.0 - 2.0 * (y * y + z * z);
        let forward_y = 2.0 * (x * y + w * z);
        forward_y.atan2(forward_x)
    }

    /// Why the devkit would refuse this box, if it would.
    pub fn problem(&self) -> Option<String> {
        let finite = self
            .translation
            .iter()
            .chain(&self.size)
            .chain(&self.rotation)
            .chain(&self.velocity)
            .all(|v| v.is_finite());
        if !finite {
            return Some("a non-finite translation, size, rotation or velocity".into());
        }
        if self.size.iter().any(|&s| s <= 0.0) {
            return Some(format!(
                "size {:?}: width, length and height must be > 0",
                self.size
            ));
        }
        if self.rotation.iter().map(|v| v * v).sum::<f64>() < 1e-12 {
            return Some("a zero rotation quaternion".into());
        }
        if !DETECTION_NAMES.contains(&self.detection_name.as_str()) {
            return Some(format!(
                "detection_name '{}' is not one of {}",
                self.detection_name,
                DETECTION_NAMES.join(", ")
            ));
        }
        if !(self.attribute_name.is_empty()
            || ATTRIBUTE_NAMES.contains(&self.attribute_name.as_str()))
        {
            return Some(format!(
                "attribute_name '{}' is not one of {} (or \"\")",
                self.attribute_name,
                ATTRIBUTE_NAMES.join(", ")
            ));
        }
        if !(self.detection_score.is_finite()
            && ((0.0..=1.0).contains(&self.detection_score) || self.detection_score == -1.0))
        {
            return Some(format!(
                "detection_score {} is not in [0, 1]",
                self.detection_score
            ));
        }
        None
    }
}

/// What the submission says it used, as the devkit's `meta` block.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SubmissionMeta {
    pub use_camera: bool,
    pub use_lidar: bool,
    pub use_radar: bool,
    pub use_map: bool,
    pub use_external: bool,
}

/// A `results_nusc.json`: every sample's boxes.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DetectionResults {
    pub meta: SubmissionMeta,
    pub results: BTreeMap<String, Vec<Detection>>,
}

#[derive(Debug, thiserror::Error)]
pub enum DetectionFileError {
    #[error("{path}: {message}")]
    Io { path: PathBuf, message: String },
    #[error("{path}: field `{field}`: {message}")]
    Field {
        path: PathBuf,
        field: String,
        message: String,
    },
    #[error("{path}: sample {sample}, box {index}: {message}")]
    Box {
        path: PathBuf,
        sample: String,
        index: usize,
        message: String,
    },
}

impl DetectionResults {
    /// Every box the devkit would refuse, checked: the first is named.
    pub fn check(&self, path: &Path) -> Result<(), DetectionFileError> {
        for (sample, boxes) in &self.results {
            if boxes.len() > MAX_BOXES_PER_SAMPLE {
                return Err(DetectionFileError::Box {
                    path: path.to_path_buf(),
                    sample: sample.clone(),
                    index: MAX_BOXES_PER_SAMPLE,
                    message: format!(
                        "{} boxes; the devkit scores at most {MAX_BOXES_PER_SAMPLE} per sample",
                        boxes.len()
                    ),
                });
            }
            for (index, detection) in boxes.iter().enumerate() {
                let problem = detection.problem().or_else(|| {
                    (detection.sample_token != *sample).then(|| {
                        format!(
                            "its sample_token '{}' is not the sample it is listed under",
                            detection.sample_token
                        )
                    })
                });
                if let Some(message) = problem {
                    return Err(DetectionFileError::Box {
                        path: path.to_path_buf(),
                        sample: sample.clone(),
                        index,
                        message,
                    });
                }
            }
        }
        Ok(())
    }

    /// Reads and checks a results file.
    pub fn load(path: &Path) -> Result<Self, DetectionFileError> {
        let bytes = std::fs::read(path).map_err(|e| DetectionFileError::Io {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
        let mut reader = serde_json::Deserializer::from_slice(&bytes);
        let results: Self = serde_path_to_error::deserialize(&mut reader).map_err(|error| {
            DetectionFileError::Field {
                path: path.to_path_buf(),
                field: error.path().to_string(),
                message: error.inner().to_string(),
            }
        })?;
        results.check(path)?;
        Ok(results)
    }

    /// Writes the file, checked first, whole or not at all.
    pub fn save(&self, path: &Path) -> Result<(), DetectionFileError> {
        self.check(path)?;
        let io = |message: String| DetectionFileError::Io {
            path: path.to_path_buf(),
            message,
        };
        let text = serde_json::to_string(self).map_err(|e| io(e.to_string()))?;
        bevworld_atomic_file::write(path, text.as_bytes()).map_err(|e| io(e.to_string()))
    }
}

/// The nuScenes category a detection class comes from, as the devkit's
/// `category_to_detection_name` maps them; `None` for a category the challenge does not score.
pub fn detection_name_of(category: &str) -> Option<&'static str> {
    Some(match category {
        "movable_object.barrier" => "barrier",
        "vehicle.bicycle" => "bicycle",
        "vehicle.bus.bendy" | "vehicle.bus.rigid" => "bus",
        "vehicle.car" => "car",
        "vehicle.construction" => "construction_vehicle",
        "vehicle.motorcycle" => "motorcycle",
        "human.pedestrian.adult"
        | "human.pedestrian.child"
        | "human.pedestrian.construction_worker"
        | "human.pedestrian.police_officer" => "pedestrian",
        "movable_object.trafficcone" => "traffic_cone",
        "vehicle.trailer" => "trailer",
        "vehicle.truck" => "truck",
        _ => return None,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn car(sample: &str) -> Detection {
        Detection {
            sample_token: sample.into(),
            translation: [10.0, 2.0, 1.0],
            size: [1.9, 4.5, 1.6],
            rotation: [1.0, 0.0, 0.0, 0.0],
            velocity: [3.0, 0.0],
            detection_name: "car".into(),
            detection_score: 0.8,
            attribute_name: "vehicle.moving".into(),
        }
    }

    #[test]
    fn yaw_is_read_from_the_quaternion() {
        let mut box_ = car("s");
        let half: f64 = 0.5 * std::f64::consts::FRAC_PI_2;
        box_.rotation = [half.cos(), 0.0, 0.0, half.sin()];
        assert!((box_.yaw() - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        box_.rotation = [0.0, 0.0, 0.0, 1.0];
        assert!((box_.yaw().abs() - std::f64::consts::PI).abs() < 1e-12);
    }

    #[test]
    fn the_file_round_trips_and_bad_boxes_are_refused_naming_them() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("results_nusc.json");
        let results = DetectionResults {
            meta: SubmissionMeta {
                use_lidar: true,
                use_camera: true,
                ..Default::default()
            },
            results: BTreeMap::from([("s".to_string(), vec![car("s")])]),
        };
        results.save(&path).unwrap();
        assert_eq!(DetectionResults::load(&path).unwrap(), results);
        for (edit, says) in [
            (
                Box::new(|d: &mut Detection| d.size[1] = 0.0) as Box<dyn Fn(&mut Detection)>,
                "must be > 0",
            ),
            (
                Box::new(|d: &mut Detection| d.size[0] = -1.0),
                "must be > 0",
            ),
            (
                Box::new(|d: &mut Detection| d.translation[2] = f64::NAN),
                "non-finite",
            ),
            (
                Box::new(|d: &mut Detection| d.detection_name = "tram".into()),
                "'tram'",
            ),
            (
                Box::new(|d: &mut Detection| d.attribute_name = "car.flying".into()),
                "'car.flying'",
            ),
            (
                Box::new(|d: &mut Detection| d.detection_score = 1.5),
                "detection_score",
            ),
            (
                Box::new(|d: &mut Detection| d.sample_token = "t".into()),
                "not the sample",
            ),
        ] {
            let mut bad = results.clone();
            edit(&mut bad.results.get_mut("s").unwrap()[0]);
            let error = bad.save(&path).unwrap_err().to_string();
            assert!(
                error.contains("sample s, box 0") && error.contains(says),
                "{error}"
            );
        }
        // A missing field is named, in a file written by hand.
        std::fs::write(
            &path,
            r#"{"meta": {"use_camera": false, "use_lidar": true, "use_radar": false, "use_map": false, "use_external": false},
                "results": {"s": [{"sample_token": "s", "translation": [0, 0, 0], "size": [1, 1, 1], "rotation": [1, 0, 0, 0],
                "detection_name": "car", "detection_score": 0.5, "attribute_name": ""}]}}"#,
        )
        .unwrap();
        let error = DetectionResults::load(&path).unwrap_err().to_string();
        assert!(
            error.contains("results.s[0]") && error.contains("velocity"),
            "{error}"
        );
        let too_many = DetectionResults {
            results: BTreeMap::from([("s".to_string(), vec![car("s"); 501])]),
            ..results
        };
        assert!(
            too_many
                .check(&path)
                .unwrap_err()
                .to_string()
                .contains("at most 500")
        );
    }

    #[test]
    fn categories_map_to_the_challenge_classes() {
        assert_eq!(detection_name_of("vehicle.car"), Some("car"));
        assert_eq!(
            detection_name_of("human.pedestrian.child"),
            Some("pedestrian")
        );
        assert_eq!(detection_name_of("vehicle.bus.bendy"), Some("bus"));
        assert_eq!(detection_name_of("animal"), None);
        assert_eq!(detection_name_of("vehicle.emergency.police"), None);
    }
}
